// Fused EWA projection of 3D Gaussians and their PGSR planes on the CPU: forward and an
// analytic backward, one Gaussian per OpenMP iteration. The formulas, clamps, culling rule
// and choices (shortest axis, facing sign) are those of eve3d/gaussians/render/projection.py, which
// stays the reference the tests compare with. Python scalars are rounded to scalar_t where
// PyTorch rounds them, so the two agree to the order of operations.
#include "kernels.h"

#include <algorithm>
#include <cmath>

namespace {

constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double EPS2D = 0.3;
constexpr double COMPENSATION_FLOOR = 1e-12;
constexpr double NORMALIZE_EPS = 1e-12;  // torch.nn.functional.normalize's
constexpr double EXTENT_MAX = 3.33;

using eve3d::Cam;

// One Gaussian's forward quantities; the backward recomputes them rather than storing them.
template <typename T>
struct Splat {
    T qn[4], qnorm;         // normalised quaternion, norm of the input
    T P[9], M[9], S[9];     // R·Rw (camera-space axes), P·diag(scales), camera covariance M·Mᵀ
    T mc[3];                // camera-space centre
    int k;                  // shortest axis
    T sign;                 // −1 where that axis faces away from the camera
    T zs, clx, cly, tx, ty; // z clamped at near, clamped tangents x/z, y/z, and ×zs
    bool z_ok, in_x, in_y;  // where those clamps pass the gradient
    T J00, J02, J11, J12;   // the projection's Jacobian [[J00, 0, J02], [0, J11, J12]]
    T A0[3], A1[3];         // rows of J·S
    T a, b, c, det, D, det_raw, ratio, comp, u, v;
};

template <typename T>
inline void project_one(const T* m, const T* q, const T* s, const Cam<T>& C, Splat<T>& p) {
    p.qnorm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    const T d = std::max(p.qnorm, (T)NORMALIZE_EPS);
    for (int i = 0; i < 4; ++i) p.qn[i] = q[i] / d;
    const T w = p.qn[0], x = p.qn[1], y = p.qn[2], z = p.qn[3];
    const T Rw[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            p.P[3 * r + c] = C.R[3 * r] * Rw[c] + C.R[3 * r + 1] * Rw[3 + c] + C.R[3 * r + 2] * Rw[6 + c];
            p.M[3 * r + c] = p.P[3 * r + c] * s[c];
        }
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            p.S[3 * r + c] = p.M[3 * r] * p.M[3 * c] + p.M[3 * r + 1] * p.M[3 * c + 1] + p.M[3 * r + 2] * p.M[3 * c + 2];
    for (int r = 0; r < 3; ++r)
        p.mc[r] = C.R[3 * r] * m[0] + C.R[3 * r + 1] * m[1] + C.R[3 * r + 2] * m[2] + C.t[r];

    p.k = 0;  // the first smallest, as argmin
    for (int j = 1; j < 3; ++j)
        if (s[j] < s[p.k]) p.k = j;
    const T facing = p.P[p.k] * p.mc[0] + p.P[3 + p.k] * p.mc[1] + p.P[6 + p.k] * p.mc[2];
    p.sign = facing > 0 ? -1 : 1;

    p.z_ok = p.mc[2] > C.near;
    p.zs = p.z_ok ? p.mc[2] : C.near;
    const T ux = p.mc[0] / p.zs, uy = p.mc[1] / p.zs;
    p.in_x = ux >= C.lo_x && ux <= C.hi_x;  // clamp passes the gradient inclusively
    p.in_y = uy >= C.lo_y && uy <= C.hi_y;
    p.clx = std::min(std::max(ux, C.lo_x), C.hi_x);
    p.cly = std::min(std::max(uy, C.lo_y), C.hi_y);
    p.tx = p.zs * p.clx, p.ty = p.zs * p.cly;
    const T z2 = p.zs * p.zs;
    p.J00 = C.fx / p.zs, p.J02 = -C.fx * p.tx / z2, p.J11 = C.fy / p.zs, p.J12 = -C.fy * p.ty / z2;
    for (int j = 0; j < 3; ++j) {
        p.A0[j] = p.J00 * p.S[j] + p.J02 * p.S[6 + j];
        p.A1[j] = p.J11 * p.S[3 + j] + p.J12 * p.S[6 + j];
    }
    p.a = (p.A0[0] * p.J00 + p.A0[2] * p.J02) + (T)EPS2D;
    p.b = p.A0[1] * p.J11 + p.A0[2] * p.J12;
    p.c = (p.A1[1] * p.J11 + p.A1[2] * p.J12) + (T)EPS2D;
    p.det = p.a * p.c - p.b * p.b;
    p.D = p.det > 0 ? p.det : 1;
    p.det_raw = (p.a - (T)EPS2D) * (p.c - (T)EPS2D) - p.b * p.b;
    p.ratio = p.det_raw / p.D;
    p.comp = std::sqrt(std::max(p.ratio, (T)COMPENSATION_FLOOR));
    p.u = C.fx * p.mc[0] / p.zs + C.cx;
    p.v = C.fy * p.mc[1] / p.zs + C.cy;
}

// Bounding-box half extents, 0 for a culled Gaussian (projection.py's `keep`).
template <typename T>
inline void radii_one(const Splat<T>& p, T opacity, const Cam<T>& C, int32_t* radii) {
    const T o = std::max(opacity, (T)ALPHA_MIN);
    const T extend = std::min(std::sqrt((T)2 * std::log(o / (T)ALPHA_MIN)), (T)EXTENT_MAX);
    const T rx = std::ceil(extend * std::sqrt(std::max(p.a, (T)0)));
    const T ry = std::ceil(extend * std::sqrt(std::max(p.c, (T)0)));
    const bool keep = p.mc[2] >= C.near && p.mc[2] <= C.far && p.det > 0 && opacity >= (T)ALPHA_MIN &&
                      (rx > 0 || ry > 0) && p.u + rx > 0 && p.u - rx < C.width && p.v + ry > 0 &&
                      p.v - ry < C.height;
    radii[0] = keep ? (int32_t)rx : 0;
    radii[1] = keep ? (int32_t)ry : 0;
}

// Incoming gradients of one Gaussian's outputs.
template <typename T>
struct Grads {
    const T *means2d, *conics, *normals;
    T depth, comp, distance, opacity;

    bool zero() const {
        return means2d[0] == 0 && means2d[1] == 0 && conics[0] == 0 && conics[1] == 0 && conics[2] == 0 &&
               normals[0] == 0 && normals[1] == 0 && normals[2] == 0 && depth == 0 && comp == 0 &&
               distance == 0 && opacity == 0;
    }
};

template <typename T>
inline void backward_one(const Splat<T>& p, const T* s, T opacity, const Cam<T>& C, bool antialiased,
                         const Grads<T>& g, T* g_mean, T* g_quat, T* g_scale, T* g_opac) {
    T g_comp = g.comp;
    if (antialiased) {
        *g_opac = g.opacity * p.comp;
        g_comp += g.opacity * opacity;
    } else {
        *g_opac = g.opacity;
    }
    T g_mc[3] = {0, 0, g.depth};
    T gP[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    // plane: n = sign·P[:, k], distance = −n·mc
    for (int r = 0; r < 3; ++r) {
        g_mc[r] -= g.distance * p.sign * p.P[3 * r + p.k];
        gP[3 * r + p.k] += p.sign * (g.normals[r] - g.distance * p.mc[r]);
    }
    // means2d = f·(x, y)/zs + c
    T g_x = g.means2d[0] * C.fx / p.zs, g_y = g.means2d[1] * C.fy / p.zs;
    const T z2 = p.zs * p.zs;
    T g_zs = -(g.means2d[0] * C.fx * p.mc[0] + g.means2d[1] * C.fy * p.mc[1]) / z2;
    // conics = (c, −b, a)/D
    T g_a = g.conics[2] / p.D, g_b = -g.conics[1] / p.D, g_c = g.conics[0] / p.D;
    T g_D = -(g.conics[0] * p.c - g.conics[1] * p.b + g.conics[2] * p.a) / (p.D * p.D);
    // compensation = √max(det_raw/D, floor)
    if (p.ratio >= (T)COMPENSATION_FLOOR) {
        const T g_ratio = g_comp / (2 * p.comp);
        const T g_raw = g_ratio / p.D;
        g_D -= g_ratio * p.det_raw / (p.D * p.D);
        g_a += g_raw * (p.c - (T)EPS2D);
        g_c += g_raw * (p.a - (T)EPS2D);
        g_b -= 2 * p.b * g_raw;
    }
    if (p.det > 0) {  // D = det
        g_a += g_D * p.c;
        g_c += g_D * p.a;
        g_b -= 2 * p.b * g_D;
    }
    // 2D covariance J·S·Jᵀ: with Gs = G + Gᵀ = [[2g_a, g_b], [g_b, 2g_c]] (b is entry (0, 1)),
    // ∂L/∂J = Gs·J·S and ∂L/∂M = Jᵀ·Gs·J·M.
    const T Gs00 = 2 * g_a, Gs01 = g_b, Gs11 = 2 * g_c;
    const T gJ00 = Gs00 * p.A0[0] + Gs01 * p.A1[0], gJ02 = Gs00 * p.A0[2] + Gs01 * p.A1[2];
    const T gJ11 = Gs01 * p.A0[1] + Gs11 * p.A1[1], gJ12 = Gs01 * p.A0[2] + Gs11 * p.A1[2];
    const T J[2][3] = {{p.J00, 0, p.J02}, {0, p.J11, p.J12}};
    const T Gs[2][2] = {{Gs00, Gs01}, {Gs01, Gs11}};
    T H[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            T h = 0;
            for (int r = 0; r < 2; ++r)
                for (int c = 0; c < 2; ++c) h += J[r][i] * Gs[r][c] * J[c][j];
            H[3 * i + j] = h;
        }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            const T gM = H[3 * i] * p.M[j] + H[3 * i + 1] * p.M[3 + j] + H[3 * i + 2] * p.M[6 + j];
            gP[3 * i + j] += gM * s[j];
        }
    for (int j = 0; j < 3; ++j) {
        T gs = 0;
        for (int i = 0; i < 3; ++i) {
            const T gM = H[3 * i] * p.M[j] + H[3 * i + 1] * p.M[3 + j] + H[3 * i + 2] * p.M[6 + j];
            gs += gM * p.P[3 * i + j];
        }
        g_scale[j] = gs;
    }
    // Jacobian entries f/zs and −f·t/zs²
    g_zs += -(gJ00 * C.fx + gJ11 * C.fy) / z2 + 2 * (gJ02 * C.fx * p.tx + gJ12 * C.fy * p.ty) / (z2 * p.zs);
    const T g_tx = -gJ02 * C.fx / z2, g_ty = -gJ12 * C.fy / z2;
    // t = zs·clamp(x/zs)
    g_zs += g_tx * p.clx + g_ty * p.cly;
    if (p.in_x) {
        g_x += g_tx;
        g_zs -= g_tx * p.mc[0] / p.zs;
    }
    if (p.in_y) {
        g_y += g_ty;
        g_zs -= g_ty * p.mc[1] / p.zs;
    }
    g_mc[0] += g_x, g_mc[1] += g_y;
    if (p.z_ok) g_mc[2] += g_zs;
    // mc = R·m + t, P = R·Rw
    T G[9];
    for (int j = 0; j < 3; ++j) {
        g_mean[j] = C.R[j] * g_mc[0] + C.R[3 + j] * g_mc[1] + C.R[6 + j] * g_mc[2];
        for (int c = 0; c < 3; ++c) G[3 * j + c] = C.R[j] * gP[c] + C.R[3 + j] * gP[3 + c] + C.R[6 + j] * gP[6 + c];
    }
    // Rw(qn), then qn = q/max(|q|, eps)
    const T w = p.qn[0], x = p.qn[1], y = p.qn[2], z = p.qn[3];
    const T gq[4] = {
        2 * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]),
        2 * (y * G[1] + z * G[2] + y * G[3] - 2 * x * G[4] - w * G[5] + z * G[6] + w * G[7] - 2 * x * G[8]),
        2 * (-2 * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6] + z * G[7] - 2 * y * G[8]),
        2 * (-2 * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2 * z * G[4] + y * G[5] + x * G[6] + y * G[7])};
    const T d = std::max(p.qnorm, (T)NORMALIZE_EPS);
    const T dot = p.qnorm >= (T)NORMALIZE_EPS ? gq[0] * w + gq[1] * x + gq[2] * y + gq[3] * z : 0;
    for (int i = 0; i < 4; ++i) g_quat[i] = (gq[i] - dot * p.qn[i]) / d;
}

}  // namespace

namespace eve3d {

template <typename T>
Cam<T> make_cam(const T* R, const T* t, double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                double near, double far) {
    Cam<T> c;
    std::copy(R, R + 9, c.R);
    std::copy(t, t + 3, c.t);
    c.fx = (T)fx, c.fy = (T)fy, c.cx = (T)cx, c.cy = (T)cy;
    // 30 % of the half field of view beyond the image, computed in double as Python does.
    const double margin_x = 0.3 * 0.5 * width / fx, margin_y = 0.3 * 0.5 * height / fy;
    c.lo_x = (T)(-(cx / fx + margin_x)), c.hi_x = (T)((width - cx) / fx + margin_x);
    c.lo_y = (T)(-(cy / fy + margin_y)), c.hi_y = (T)((height - cy) / fy + margin_y);
    c.near = (T)near, c.far = (T)far, c.width = (T)width, c.height = (T)height;
    return c;
}

template <typename T>
void project_forward(int64_t n, const T* means, const T* quats, const T* scales, const T* opac, const Cam<T>& C,
                  bool antialiased, T* means2d, T* conics, T* depths, int32_t* radii, T* comp, T* normals,
                  T* distances, T* opac_out) {
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        Splat<T> p;
        project_one(means + 3 * i, quats + 4 * i, scales + 3 * i, C, p);
        radii_one(p, opac[i], C, radii + 2 * i);
        means2d[2 * i] = p.u, means2d[2 * i + 1] = p.v;
        conics[3 * i] = p.c / p.D, conics[3 * i + 1] = -p.b / p.D, conics[3 * i + 2] = p.a / p.D;
        depths[i] = p.mc[2];
        comp[i] = p.comp;
        T dist = 0;
        for (int r = 0; r < 3; ++r) {
            normals[3 * i + r] = p.sign * p.P[3 * r + p.k];
            dist += normals[3 * i + r] * p.mc[r];
        }
        distances[i] = -dist;
        opac_out[i] = antialiased ? opac[i] * p.comp : opac[i];
    }
}

template <typename T>
void project_backward(int64_t n, const T* means, const T* quats, const T* scales, const T* opac, const Cam<T>& C,
                   bool antialiased, const T* gm2, const T* gcon, const T* gdep, const T* gcomp, const T* gnorm,
                   const T* gdist, const T* gop, T* g_means, T* g_quats, T* g_scales, T* g_opac) {
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const Grads<T> g{gm2 + 2 * i, gcon + 3 * i, gnorm + 3 * i, gdep[i], gcomp[i], gdist[i], gop[i]};
        if (g.zero()) {  // culled or unseen: nothing to chain (and no 0·∞ from degenerate ones)
            std::fill(g_means + 3 * i, g_means + 3 * i + 3, (T)0);
            std::fill(g_quats + 4 * i, g_quats + 4 * i + 4, (T)0);
            std::fill(g_scales + 3 * i, g_scales + 3 * i + 3, (T)0);
            g_opac[i] = 0;
            continue;
        }
        Splat<T> p;
        project_one(means + 3 * i, quats + 4 * i, scales + 3 * i, C, p);
        backward_one(p, scales + 3 * i, opac[i], C, antialiased, g, g_means + 3 * i, g_quats + 4 * i,
                     g_scales + 3 * i, g_opac + i);
    }
}

template Cam<float> make_cam<float>(const float*, const float*, double, double, double, double, int64_t, int64_t,
                                    double, double);
template Cam<double> make_cam<double>(const double*, const double*, double, double, double, double, int64_t,
                                      int64_t, double, double);
template void project_forward<float>(int64_t, const float*, const float*, const float*, const float*,
                                     const Cam<float>&, bool, float*, float*, float*, int32_t*, float*, float*,
                                     float*, float*);
template void project_forward<double>(int64_t, const double*, const double*, const double*, const double*,
                                      const Cam<double>&, bool, double*, double*, double*, int32_t*, double*,
                                      double*, double*, double*);
template void project_backward<float>(int64_t, const float*, const float*, const float*, const float*,
                                      const Cam<float>&, bool, const float*, const float*, const float*,
                                      const float*, const float*, const float*, const float*, float*, float*,
                                      float*, float*);
template void project_backward<double>(int64_t, const double*, const double*, const double*, const double*,
                                       const Cam<double>&, bool, const double*, const double*, const double*,
                                       const double*, const double*, const double*, const double*, double*,
                                       double*, double*, double*);

}  // namespace eve3d
