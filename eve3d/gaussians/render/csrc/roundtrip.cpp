// PGSR's multi-view round trip on the CPU, forward and analytic backward, for K neighbours
// of one reference view: each reference pixel is back-projected with its depth, projected
// into neighbour k, given that neighbour's depth there (bilinear, border-clamped as
// torch.nn.functional.grid_sample(align_corners=False, padding_mode="border")), back-projected
// and projected into the reference again; phi is the pixel distance of the round trip.
// The formulas and rules are those of eve3d.gaussians.losses.forward_backward_error (the reference the
// tests compare with); fusing them replaces some forty image-sized tensor operations, each
// with its autograd node, by one pass over the pixels.
#include "kernels.h"

#include <algorithm>
#include <cmath>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

constexpr double Z_EPS = 1e-8;  // |z| below this is replaced by 1e-8 (as the PyTorch code)

using eve3d::NccArgs;
using eve3d::Pose;

template <typename T>
inline T safe_z(T z) {
    return std::abs(z) > (T)Z_EPS ? z : (T)Z_EPS;
}

// Bilinear lookup with grid_sample's border rule: the coordinate is clamped into the image
// (and then carries no gradient); taps beyond the last row or column weigh 0.
template <typename T>
struct Bilinear {
    int64_t x0, y0;
    T tx, ty, gx_mult, gy_mult;  // gradient multipliers of the clamp (0 where clamped)
};

template <typename T>
inline Bilinear<T> bilinear(T u, T v, int64_t w, int64_t h) {
    Bilinear<T> b;
    T ix = u - (T)0.5, iy = v - (T)0.5;
    b.gx_mult = (ix > 0 && ix < (T)(w - 1)) ? 1 : 0;
    b.gy_mult = (iy > 0 && iy < (T)(h - 1)) ? 1 : 0;
    ix = ix <= 0 ? 0 : (ix >= (T)(w - 1) ? (T)(w - 1) : ix);
    iy = iy <= 0 ? 0 : (iy >= (T)(h - 1) ? (T)(h - 1) : iy);
    b.x0 = (int64_t)std::floor(ix);
    b.y0 = (int64_t)std::floor(iy);
    b.tx = ix - (T)b.x0;
    b.ty = iy - (T)b.y0;
    return b;
}

template <typename T>
inline T tap(const T* map, int64_t x, int64_t y, int64_t w, int64_t h) {
    return (x < w && y < h) ? map[y * w + x] : (T)0;
}

// The bilinear value at (u, v) and, when asked, its derivatives along u and v (0 where the
// coordinate was clamped).
template <typename T>
inline T sample(const T* map, T u, T v, int64_t w, int64_t h, T* du = nullptr, T* dv = nullptr) {
    const auto b = bilinear(u, v, w, h);
    const T v00 = tap(map, b.x0, b.y0, w, h), v10 = tap(map, b.x0 + 1, b.y0, w, h);
    const T v01 = tap(map, b.x0, b.y0 + 1, w, h), v11 = tap(map, b.x0 + 1, b.y0 + 1, w, h);
    if (du) *du = b.gx_mult * ((1 - b.ty) * (v10 - v00) + b.ty * (v11 - v01));
    if (dv) *dv = b.gy_mult * ((1 - b.tx) * (v01 - v00) + b.tx * (v11 - v10));
    return (1 - b.tx) * (1 - b.ty) * v00 + b.tx * (1 - b.ty) * v10 + (1 - b.tx) * b.ty * v01 + b.tx * b.ty * v11;
}

// Everything the forward computes for one (neighbour, pixel), kept for the backward.
template <typename T>
struct Trip {
    T X[3], Y[3], uvn[2], dn, rn[3], Z[3], e[2], phi;
    bool defined;
};

template <typename T>
inline Trip<T> trip(const T* dref, const T* dnbr, const Pose<T>& P, T fx, T fy, T cx, T cy, int64_t W,
                    int64_t H, int64_t w, int64_t h, int64_t p) {
    Trip<T> s;
    const T u = (T)(p % W) + (T)0.5, v = (T)(p / W) + (T)0.5;
    const T d = dref[p];
    const T r[3] = {(u - cx) / fx, (v - cy) / fy, (T)1};
    for (int i = 0; i < 3; ++i) s.X[i] = r[i] * d;
    for (int i = 0; i < 3; ++i)
        s.Y[i] = P.R[3 * i] * s.X[0] + P.R[3 * i + 1] * s.X[1] + P.R[3 * i + 2] * s.X[2] + P.t[i];
    const T zn = safe_z(s.Y[2]);
    s.uvn[0] = P.fx * s.Y[0] / zn + P.cx;
    s.uvn[1] = P.fy * s.Y[1] / zn + P.cy;
    s.dn = sample(dnbr, s.uvn[0], s.uvn[1], w, h);
    s.rn[0] = (s.uvn[0] - P.cx) / P.fx;
    s.rn[1] = (s.uvn[1] - P.cy) / P.fy;
    s.rn[2] = 1;
    T q[3];
    for (int i = 0; i < 3; ++i) q[i] = s.rn[i] * s.dn - P.t[i];
    for (int i = 0; i < 3; ++i) s.Z[i] = P.R[i] * q[0] + P.R[3 + i] * q[1] + P.R[6 + i] * q[2];  // R^T q
    const T zr = safe_z(s.Z[2]);
    s.e[0] = fx * s.Z[0] / zr + cx - u;
    s.e[1] = fy * s.Z[1] / zr + cy - v;
    s.phi = std::sqrt(s.e[0] * s.e[0] + s.e[1] * s.e[1]);
    const bool inside = s.uvn[0] >= 0 && s.uvn[0] < (T)w && s.uvn[1] >= 0 && s.uvn[1] < (T)h;
    s.defined = d > 0 && s.Y[2] > 0 && s.dn > 0 && s.Z[2] > 0 && inside;
    return s;
}

// d phi / d (reference depth, neighbour depth taps), chained with the incoming gradient.
// ---- NCC of patches warped by the plane-induced homography (eve3d.gaussians.losses.ncc_loss) ----------

constexpr double NCC_EPS = 1e-8;     // var + 1e-8 under the square root; var > 1e-8 to be defined
constexpr double DIST_FLOOR = 1e-6;  // the plane distance is clamped below at this

// One reference pixel against one neighbour: the patch, its warp and the NCC statistics.
template <typename T>
struct Patch {
    T H[9], dd, a[64], b[64], hom[64][3], ws[64], cov, va, vb, S, ncc;
    bool defined;
};

template <typename T>
void ncc_patch(const T* ref, int64_t W, int64_t Hh, const T* nbr, int64_t w, int64_t h, const T* centre,
               const T* n, T d, const Pose<T>& Q, T fx, T fy, T cx, T cy, int64_t patch, T step, Patch<T>& s) {
    const int64_t P = patch * patch;
    s.dd = d > (T)DIST_FLOOR ? d : (T)DIST_FLOOR;
    T A[9], KA[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) A[3 * i + j] = Q.R[3 * i + j] - Q.t[i] * n[j] / s.dd;
    for (int j = 0; j < 3; ++j) {  // K_n A
        KA[j] = Q.fx * A[j] + Q.cx * A[6 + j];
        KA[3 + j] = Q.fy * A[3 + j] + Q.cy * A[6 + j];
        KA[6 + j] = A[6 + j];
    }
    for (int i = 0; i < 3; ++i) {  // (K_n A) K_r^-1
        s.H[3 * i] = KA[3 * i] / fx;
        s.H[3 * i + 1] = KA[3 * i + 1] / fy;
        s.H[3 * i + 2] = KA[3 * i + 2] - KA[3 * i] * cx / fx - KA[3 * i + 1] * cy / fy;
    }
    const T half = (T)(patch - 1) / 2 * step;
    T mean_a = 0, mean_b = 0;
    bool inside = true;
    for (int64_t q = 0; q < P; ++q) {
        const T u = centre[0] + (-half + step * (T)(q % patch)), v = centre[1] + (-half + step * (T)(q / patch));
        for (int i = 0; i < 3; ++i) s.hom[q][i] = s.H[3 * i] * u + s.H[3 * i + 1] * v + s.H[3 * i + 2];
        s.ws[q] = safe_z(s.hom[q][2]);
        const T un = s.hom[q][0] / s.ws[q], vn = s.hom[q][1] / s.ws[q];
        inside = inside && un >= 0 && un < (T)w && vn >= 0 && vn < (T)h && s.hom[q][2] > 0;
        s.a[q] = sample(ref, u, v, W, Hh);
        s.b[q] = sample(nbr, un, vn, w, h);
        mean_a += s.a[q];
        mean_b += s.b[q];
    }
    mean_a /= (T)P;
    mean_b /= (T)P;
    s.cov = s.va = s.vb = 0;
    for (int64_t q = 0; q < P; ++q) {
        s.a[q] -= mean_a;
        s.b[q] -= mean_b;
        s.cov += s.a[q] * s.b[q];
        s.va += s.a[q] * s.a[q];
        s.vb += s.b[q] * s.b[q];
    }
    s.cov /= (T)P;
    s.va /= (T)P;
    s.vb /= (T)P;
    s.S = std::sqrt(s.va * s.vb + (T)NCC_EPS);
    s.ncc = s.cov / s.S;
    s.defined = inside && d > 0 && s.va * s.vb > (T)NCC_EPS;
}


}  // namespace

namespace eve3d {

template <typename T>
std::vector<Pose<T>> poses(const T* r, const T* tt, const T* in, int64_t K) {
    std::vector<Pose<T>> out(K);
    for (int64_t k = 0; k < K; ++k) {
        for (int i = 0; i < 9; ++i) out[k].R[i] = r[9 * k + i];
        for (int i = 0; i < 3; ++i) out[k].t[i] = tt[3 * k + i];
        out[k].fx = in[4 * k], out[k].fy = in[4 * k + 1], out[k].cx = in[4 * k + 2], out[k].cy = in[4 * k + 3];
    }
    return out;
}

template <typename T>
void roundtrip_forward(const T* dref, const T* dnbr, const std::vector<Pose<T>>& P, T fx, T fy, T cx, T cy, int64_t W,
                  int64_t H, int64_t w, int64_t h, T* phi, bool* defined) {
    const int64_t K = P.size(), n = W * H;
#pragma omp parallel for schedule(static)
    for (int64_t kp = 0; kp < K * n; ++kp) {
        const int64_t k = kp / n, p = kp % n;
        const auto s = trip(dref, dnbr + k * w * h, P[k], fx, fy, cx, cy, W, H, w, h, p);
        phi[kp] = s.phi;
        defined[kp] = s.defined;
    }
}

// d phi / d (reference depth, neighbour depth taps), chained with the incoming gradient.
template <typename T>
void roundtrip_backward(const T* dref, const T* dnbr, const std::vector<Pose<T>>& P, T fx, T fy, T cx, T cy,
                   int64_t W, int64_t H, int64_t w, int64_t h, const T* gphi, T* gref, T* gnbr_all) {
    const int64_t K = P.size(), n = W * H, m = w * h;
#pragma omp parallel
    {
#ifdef _OPENMP
        T* gnbr = gnbr_all + (int64_t)omp_get_thread_num() * K * m;
#else
        T* gnbr = gnbr_all;
#endif
#pragma omp for schedule(static)
        for (int64_t p = 0; p < n; ++p) {
            T g_d = 0;
            for (int64_t k = 0; k < K; ++k) {
                const T g = gphi[k * n + p];
                if (g == 0) continue;
                const T* map = dnbr + k * m;
                const Pose<T>& Q = P[k];
                const auto s = trip(dref, map, Q, fx, fy, cx, cy, W, H, w, h, p);
                if (!(s.phi > 0)) continue;  // torch's norm: gradient 0 at 0
                // phi = |e|, e = project_ref(Z) - pixel
                const T ge[2] = {g * s.e[0] / s.phi, g * s.e[1] / s.phi};
                T gZ[3] = {0, 0, 0};
                if (std::abs(s.Z[2]) > (T)Z_EPS) {
                    const T z = s.Z[2];
                    gZ[0] = ge[0] * fx / z;
                    gZ[1] = ge[1] * fy / z;
                    gZ[2] = -(ge[0] * fx * s.Z[0] + ge[1] * fy * s.Z[1]) / (z * z);
                } else {
                    gZ[0] = ge[0] * fx / (T)Z_EPS;
                    gZ[1] = ge[1] * fy / (T)Z_EPS;
                }
                // Z = R^T q, q = rn * dn - t  ->  g_q = R g_Z
                T gq[3];
                for (int i = 0; i < 3; ++i) gq[i] = Q.R[3 * i] * gZ[0] + Q.R[3 * i + 1] * gZ[1] + Q.R[3 * i + 2] * gZ[2];
                const T g_dn = gq[0] * s.rn[0] + gq[1] * s.rn[1] + gq[2] * s.rn[2];
                T g_uvn[2] = {gq[0] * s.dn / Q.fx, gq[1] * s.dn / Q.fy};
                // dn = bilinear(map, uvn): to the four taps, and to the lookup position
                const auto b = bilinear(s.uvn[0], s.uvn[1], w, h);
                const T wts[4] = {(1 - b.tx) * (1 - b.ty), b.tx * (1 - b.ty), (1 - b.tx) * b.ty, b.tx * b.ty};
                const int64_t xs[4] = {b.x0, b.x0 + 1, b.x0, b.x0 + 1}, ys[4] = {b.y0, b.y0, b.y0 + 1, b.y0 + 1};
                for (int q = 0; q < 4; ++q)
                    if (xs[q] < w && ys[q] < h) gnbr[k * m + ys[q] * w + xs[q]] += g_dn * wts[q];
                T du, dv;
                sample(map, s.uvn[0], s.uvn[1], w, h, &du, &dv);
                g_uvn[0] += g_dn * du;
                g_uvn[1] += g_dn * dv;
                // uvn = f * Y_xy / zn + c
                T gY[3] = {0, 0, 0};
                const bool z_ok = std::abs(s.Y[2]) > (T)Z_EPS;
                const T zn = z_ok ? s.Y[2] : (T)Z_EPS;
                gY[0] = g_uvn[0] * Q.fx / zn;
                gY[1] = g_uvn[1] * Q.fy / zn;
                if (z_ok) gY[2] = -(g_uvn[0] * Q.fx * s.Y[0] + g_uvn[1] * Q.fy * s.Y[1]) / (zn * zn);
                // Y = R X + t, X = r * d  ->  g_X = R^T g_Y, g_d = g_X . r
                const T u = (T)(p % W) + (T)0.5, v = (T)(p / W) + (T)0.5;
                const T r[3] = {(u - cx) / fx, (v - cy) / fy, (T)1};
                for (int i = 0; i < 3; ++i)
                    g_d += r[i] * (Q.R[i] * gY[0] + Q.R[3 + i] * gY[1] + Q.R[6 + i] * gY[2]);
            }
            gref[p] = g_d;
        }
    }
}

template <typename T>
void ncc_forward(const NccArgs<T>& g, const std::vector<Pose<T>>& P, T* loss, bool* defined) {
#pragma omp parallel for schedule(static)
    for (int64_t e = 0; e < g.K * g.M; ++e) {
        const int64_t k = e / g.M;
        Patch<T> s;
        ncc_patch(g.ref, g.W, g.H, g.nbr + k * g.w * g.h, g.w, g.h, g.centres + 2 * e, g.normal + 3 * e,
                  g.distance[e], P[k], g.fx, g.fy, g.cx, g.cy, g.patch, g.step, s);
        loss[e] = 1 - std::min(std::max(s.ncc, (T)-1), (T)1);
        defined[e] = s.defined;
    }
}

template <typename T>
void ncc_backward(const NccArgs<T>& g, const std::vector<Pose<T>>& P, const T* gloss, T* gn, T* gd) {
    const int64_t Pn = g.patch * g.patch;
#pragma omp parallel for schedule(static)
    for (int64_t e = 0; e < g.K * g.M; ++e) {
        gn[3 * e] = gn[3 * e + 1] = gn[3 * e + 2] = gd[e] = 0;
        const int64_t k = e / g.M;
        const T* nbr = g.nbr + k * g.w * g.h;
        const T* n = g.normal + 3 * e;
        Patch<T> s;
        ncc_patch(g.ref, g.W, g.H, nbr, g.w, g.h, g.centres + 2 * e, n, g.distance[e], P[k], g.fx, g.fy, g.cx,
                  g.cy, g.patch, g.step, s);
        if (gloss[e] == 0 || s.ncc < -1 || s.ncc > 1) continue;  // clamp(-1, 1): flat outside
        const T g_ncc = -gloss[e];
        // ncc = cov / sqrt(va vb + eps): d/d b_q (means removed, so the mean's own term vanishes)
        const T c_a = g_ncc / ((T)Pn * s.S), c_b = -g_ncc * s.cov * s.va / ((T)Pn * s.S * s.S * s.S);
        T gH[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
        const T half = (T)(g.patch - 1) / 2 * g.step;
        for (int64_t q = 0; q < Pn; ++q) {
            const T g_b = c_a * s.a[q] + c_b * s.b[q];
            const T u = g.centres[2 * e] + (-half + g.step * (T)(q % g.patch));
            const T v = g.centres[2 * e + 1] + (-half + g.step * (T)(q / g.patch));
            const T* hq = s.hom[q];
            T du, dv;
            sample(nbr, hq[0] / s.ws[q], hq[1] / s.ws[q], g.w, g.h, &du, &dv);
            const T gu = g_b * du, gv = g_b * dv;
            T gh[3] = {gu / s.ws[q], gv / s.ws[q], 0};
            if (std::abs(hq[2]) > (T)Z_EPS) gh[2] = -(gu * hq[0] + gv * hq[1]) / (s.ws[q] * s.ws[q]);
            const T x[3] = {u, v, 1};
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) gH[3 * i + j] += gh[i] * x[j];
        }
        // H = K_n A K_r^-1  ->  g_A = K_n^T g_H K_r^-T
        T gHK[9];  // g_H K_r^-T
        for (int i = 0; i < 3; ++i) {
            gHK[3 * i] = gH[3 * i] / g.fx - gH[3 * i + 2] * g.cx / g.fx;
            gHK[3 * i + 1] = gH[3 * i + 1] / g.fy - gH[3 * i + 2] * g.cy / g.fy;
            gHK[3 * i + 2] = gH[3 * i + 2];
        }
        const Pose<T>& Q = P[k];
        T gA[9];
        for (int j = 0; j < 3; ++j) {
            gA[j] = Q.fx * gHK[j];
            gA[3 + j] = Q.fy * gHK[3 + j];
            gA[6 + j] = Q.cx * gHK[j] + Q.cy * gHK[3 + j] + gHK[6 + j];
        }
        // A = R - t n^T / dd
        T g_dd = 0;
        for (int j = 0; j < 3; ++j) {
            T tg = 0;
            for (int i = 0; i < 3; ++i) tg += gA[3 * i + j] * Q.t[i];
            gn[3 * e + j] = -tg / s.dd;
            g_dd += tg * n[j] / (s.dd * s.dd);
        }
        gd[e] = g.distance[e] >= (T)DIST_FLOOR ? g_dd : 0;
    }
}

#define EVE3D_ROUNDTRIP(T)                                                                                   \
    template std::vector<Pose<T>> poses<T>(const T*, const T*, const T*, int64_t);                         \
    template void roundtrip_forward<T>(const T*, const T*, const std::vector<Pose<T>>&, T, T, T, T, int64_t, \
                                       int64_t, int64_t, int64_t, T*, bool*);                               \
    template void roundtrip_backward<T>(const T*, const T*, const std::vector<Pose<T>>&, T, T, T, T, int64_t, \
                                        int64_t, int64_t, int64_t, const T*, T*, T*);                       \
    template void ncc_forward<T>(const NccArgs<T>&, const std::vector<Pose<T>>&, T*, bool*);               \
    template void ncc_backward<T>(const NccArgs<T>&, const std::vector<Pose<T>>&, const T*, T*, T*);
EVE3D_ROUNDTRIP(float)
EVE3D_ROUNDTRIP(double)

}  // namespace eve3d
