// Image losses of eve3d.gaussians.losses on the CPU, forward and analytic backward.
//
// SSIM with 3DGS's Gaussian window and zero padding (ssim): the five blurred maps are two
// separable passes over all planes at once; the forward also leaves, per pixel, the
// derivatives of SSIM with respect to the blurred maps that depend on the first image (mu_x,
// E[x^2], E[xy]), so the backward is three blurs (the blur's adjoint: a symmetric kernel with
// zero padding is its own) and a combination. Replaces some thirty tensor operations and a
// grouped 11x11 convolution.
//
// The normal of a depth map (depth_to_normal): the back-projected points' central
// differences over +-span pixels, their cross product, normalised; zero on the border.
#include "kernels.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace {

constexpr double C1 = 0.01 * 0.01, C2 = 0.03 * 0.03;

template <typename T>
std::vector<T> gaussian_taps(int64_t window, double sigma) {
    std::vector<double> g(window);
    double sum = 0;
    for (int64_t k = 0; k < window; ++k) {
        const double x = k - (window - 1) / 2.0;
        sum += g[k] = std::exp(-x * x / (2 * sigma * sigma));
    }
    std::vector<T> out(window);
    for (int64_t k = 0; k < window; ++k) out[k] = (T)(g[k] / sum);
    return out;
}

// Blur `planes` (n, H, W) in place: rows, then columns, zero outside the image.
template <typename T>
void blur(T* planes, int64_t n, int64_t H, int64_t W, const std::vector<T>& g) {
    const int64_t r = (int64_t)g.size() / 2;
    std::vector<T> rows(n * H * W);
#pragma omp parallel
    {
        std::vector<T> pad(W + 2 * r, 0);
#pragma omp for schedule(static)
        for (int64_t row = 0; row < n * H; ++row) {
            const T* in = planes + row * W;
            T* out = rows.data() + row * W;
            std::copy(in, in + W, pad.begin() + r);
            std::fill(out, out + W, (T)0);
            for (int64_t k = 0; k < (int64_t)g.size(); ++k) {
                const T gk = g[k];
                const T* src = pad.data() + k;
#pragma omp simd
                for (int64_t x = 0; x < W; ++x) out[x] += gk * src[x];
            }
        }
#pragma omp for schedule(static)
        for (int64_t row = 0; row < n * H; ++row) {
            const int64_t p = row / H, y = row % H;
            T* out = planes + row * W;
            std::fill(out, out + W, (T)0);
            for (int64_t k = std::max((int64_t)0, r - y); k < std::min((int64_t)g.size(), H + r - y); ++k) {
                const T gk = g[k];
                const T* src = rows.data() + (p * H + y + k - r) * W;
#pragma omp simd
                for (int64_t x = 0; x < W; ++x) out[x] += gk * src[x];
            }
        }
    }
}

// SSIM per pixel from the blurred maps (5 blocks of N: mu_x, mu_y, E[x^2], E[y^2], E[xy]);
// writes its derivatives for mu_x, E[x^2], E[xy] (3 blocks of N) and returns the sum.
template <typename T>
double ssim_map(const T* m, int64_t N, T* d) {
    const T *mx = m, *my = m + N, *sxx = m + 2 * N, *syy = m + 3 * N, *sxy = m + 4 * N;
    T *d_mu = d, *d_xx = d + N, *d_xy = d + 2 * N;
    const T c1 = (T)C1, c2 = (T)C2;
    double total = 0;
#pragma omp parallel for reduction(+ : total) schedule(static)
    for (int64_t i = 0; i < N; ++i) {
        const T ux = mx[i], uy = my[i];
        const T a1 = 2 * ux * uy + c1, a2 = 2 * (sxy[i] - ux * uy) + c2;
        const T b1 = ux * ux + uy * uy + c1, b2 = (sxx[i] - ux * ux) + (syy[i] - uy * uy) + c2;
        const T den = b1 * b2, s = a1 * a2 / den;
        total += s;
        d_mu[i] = 2 * uy * (a2 - a1) / den - s * (2 * ux / b1 - 2 * ux / b2);
        d_xx[i] = -s / b2;
        d_xy[i] = 2 * a1 / den;
    }
    return total;
}

// The gradient for x from the blurred derivatives (3 blocks of N).
template <typename T>
void ssim_grad(const T* m, const T* x, const T* y, int64_t N, T scale, T* g) {
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < N; ++i) g[i] = scale * (m[i] + 2 * x[i] * m[N + i] + y[i] * m[2 * N + i]);
}

}  // namespace

namespace eve3d {

template <typename T>
double ssim_forward(T* maps, int64_t C, int64_t H, int64_t W, int64_t window, double sigma, T* derivs) {
    blur(maps, 5 * C, H, W, gaussian_taps<T>(window, sigma));
    return ssim_map(maps, C * H * W, derivs);
}

template <typename T>
void ssim_backward(T* blurred, const T* x, const T* y, int64_t C, int64_t H, int64_t W, int64_t window, double sigma,
                   double grad_out, T* grad) {
    blur(blurred, 3 * C, H, W, gaussian_taps<T>(window, sigma));
    ssim_grad(blurred, x, y, C * H * W, (T)(grad_out / (double)(C * H * W)), grad);
}

template double ssim_forward<float>(float*, int64_t, int64_t, int64_t, int64_t, double, float*);
template double ssim_forward<double>(double*, int64_t, int64_t, int64_t, int64_t, double, double*);
template void ssim_backward<float>(float*, const float*, const float*, int64_t, int64_t, int64_t, int64_t, double,
                                   double, float*);
template void ssim_backward<double>(double*, const double*, const double*, int64_t, int64_t, int64_t, int64_t,
                                    double, double, double*);

}  // namespace eve3d

namespace {

// Central differences of the points p = rays * depth at interior pixel (y, x).
template <typename T>
inline void differences(const T* depth, const T* rays, int64_t W, int64_t y, int64_t x, int64_t k, T dx[3], T dy[3]) {
    const int64_t r = y * W + x + k, l = y * W + x - k, d = (y + k) * W + x, u = (y - k) * W + x;
    for (int c = 0; c < 3; ++c) {
        dx[c] = rays[3 * r + c] * depth[r] - rays[3 * l + c] * depth[l];
        dy[c] = rays[3 * d + c] * depth[d] - rays[3 * u + c] * depth[u];
    }
}

template <typename T>
inline void cross(const T a[3], const T b[3], T out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

constexpr double NORMALIZE_EPS = 1e-12;  // torch.nn.functional.normalize's

}  // namespace

namespace eve3d {

template <typename T>
void depth_normal_forward(const T* depth, const T* rays, int64_t H, int64_t W, int64_t k, T* n) {
#pragma omp parallel for schedule(static)
    for (int64_t y = 0; y < H; ++y)
        for (int64_t x = 0; x < W; ++x) {
            T* out = n + 3 * (y * W + x);
            if (y < k || y >= H - k || x < k || x >= W - k) {
                out[0] = out[1] = out[2] = 0;
                continue;
            }
            T dx[3], dy[3], c[3];
            differences(depth, rays, W, y, x, k, dx, dy);
            cross(dy, dx, c);  // y down x x right faces -z, the camera
            const T len = std::max(std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), (T)NORMALIZE_EPS);
            for (int i = 0; i < 3; ++i) out[i] = c[i] / len;
        }
}

// g_dx, g_dy (H, W, 3): the gradients of the interior pixels' differences; then each depth
// gathers them from the four pixels whose differences it enters.
template <typename T>
void depth_normal_backward(const T* depth, const T* rays, int64_t H, int64_t W, int64_t k, const T* gn, T* g_dx,
                                T* g_dy, T* g_depth) {
#pragma omp parallel for schedule(static)
    for (int64_t y = 0; y < H; ++y)
        for (int64_t x = 0; x < W; ++x) {
            const int64_t p = y * W + x;
            for (int i = 0; i < 3; ++i) g_dx[3 * p + i] = g_dy[3 * p + i] = 0;
            if (y < k || y >= H - k || x < k || x >= W - k) continue;
            T dx[3], dy[3], c[3], gc[3];
            differences(depth, rays, W, y, x, k, dx, dy);
            cross(dy, dx, c);
            const T norm = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
            const T* g = gn + 3 * p;
            if (norm > (T)NORMALIZE_EPS) {  // n = c / |c|: (I - n n^T) g / |c|
                const T dot = (c[0] * g[0] + c[1] * g[1] + c[2] * g[2]) / norm;
                for (int i = 0; i < 3; ++i) gc[i] = (g[i] - c[i] / norm * dot) / norm;
            } else {  // n = c / eps
                for (int i = 0; i < 3; ++i) gc[i] = g[i] / (T)NORMALIZE_EPS;
            }
            cross(dx, gc, g_dy + 3 * p);  // c = dy x dx: g_dy = dx x g_c, g_dx = g_c x dy
            cross(gc, dy, g_dx + 3 * p);
        }
#pragma omp parallel for schedule(static)
    for (int64_t y = 0; y < H; ++y)
        for (int64_t x = 0; x < W; ++x) {
            const int64_t p = y * W + x;
            T gp[3] = {0, 0, 0};
            if (x - k >= 0) for (int i = 0; i < 3; ++i) gp[i] += g_dx[3 * (p - k) + i];  // p is (x - k)'s right tap
            if (x + k < W) for (int i = 0; i < 3; ++i) gp[i] -= g_dx[3 * (p + k) + i];
            if (y - k >= 0) for (int i = 0; i < 3; ++i) gp[i] += g_dy[3 * (p - k * W) + i];
            if (y + k < H) for (int i = 0; i < 3; ++i) gp[i] -= g_dy[3 * (p + k * W) + i];
            g_depth[p] = rays[3 * p] * gp[0] + rays[3 * p + 1] * gp[1] + rays[3 * p + 2] * gp[2];
        }
}

template void depth_normal_forward<float>(const float*, const float*, int64_t, int64_t, int64_t, float*);
template void depth_normal_forward<double>(const double*, const double*, int64_t, int64_t, int64_t, double*);
template void depth_normal_backward<float>(const float*, const float*, int64_t, int64_t, int64_t, const float*,
                                           float*, float*, float*);
template void depth_normal_backward<double>(const double*, const double*, int64_t, int64_t, int64_t, const double*,
                                            double*, double*, double*);

}  // namespace eve3d
