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
#include "losses.h"

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

std::vector<at::Tensor> ssim_forward(at::Tensor a, at::Tensor b, int64_t window, double sigma) {
    TORCH_CHECK(a.device().is_cpu() && b.device().is_cpu(), "ssim: CPU tensors");
    TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes(), "ssim: two (H, W, C) images of one size, got ", a.sizes(),
                " and ", b.sizes());
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2), HW = H * W;
    // planar: x, y, x^2, y^2, xy of every channel; then their blurs
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    const std::vector<at::Tensor> planes = {x, y, x.mul(x), y.mul(y), x.mul(y)};
    auto maps = at::cat(planes).contiguous();
    auto derivs = at::empty({3, C, H, W}, a.options());  // d SSIM / d mu_x, d E[x^2], d E[xy]
    double total = 0;
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_forward", [&] {
        scalar_t* m = maps.data_ptr<scalar_t>();
        blur(m, 5 * C, H, W, gaussian_taps<scalar_t>(window, sigma));
        total = ssim_map(m, C * HW, derivs.data_ptr<scalar_t>());
    });
    return {at::scalar_tensor(total / (double)(C * HW), a.options()), derivs};
}

at::Tensor ssim_backward(at::Tensor a, at::Tensor b, at::Tensor derivs, int64_t window, double sigma,
                            double grad_out) {
    TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes() && derivs.size(0) == 3 && derivs.numel() == 3 * a.numel(),
                "ssim backward: images (H, W, C) and derivatives (3, C, H, W) of one size");
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2), HW = H * W;
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    auto blurred = derivs.clone();
    auto grad = at::empty({C, H, W}, a.options());
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_backward", [&] {
        scalar_t* m = blurred.data_ptr<scalar_t>();
        blur(m, 3 * C, H, W, gaussian_taps<scalar_t>(window, sigma));
        ssim_grad(m, x.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), C * HW, (scalar_t)(grad_out / (double)(C * HW)),
                  grad.data_ptr<scalar_t>());
    });
    return grad.permute({1, 2, 0}).contiguous();
}

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

template <typename T>
void depth_normal_impl(const T* depth, const T* rays, int64_t H, int64_t W, int64_t k, T* n) {
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
void depth_normal_backward_impl(const T* depth, const T* rays, int64_t H, int64_t W, int64_t k, const T* gn, T* g_dx,
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

}  // namespace

namespace {

void check_depth_rays(const at::Tensor& depth, const at::Tensor& rays, int64_t span) {
    TORCH_CHECK(depth.device().is_cpu() && rays.device().is_cpu(), "depth_to_normal: CPU tensors");
    TORCH_CHECK(depth.dim() == 2 && rays.dim() == 3 && rays.size(0) == depth.size(0) &&
                    rays.size(1) == depth.size(1) && rays.size(2) == 3,
                "depth_to_normal: depth (H, W) and rays (H, W, 3) of one size, got ", depth.sizes(), " and ",
                rays.sizes());
    TORCH_CHECK(span >= 1, "depth_to_normal: span >= 1, got ", span);
}

}  // namespace

at::Tensor depth_normal_forward(at::Tensor depth, at::Tensor rays, int64_t span) {
    check_depth_rays(depth, rays, span);
    depth = depth.contiguous(), rays = rays.to(depth.scalar_type()).contiguous();
    auto normal = at::empty({depth.size(0), depth.size(1), 3}, depth.options());
    AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "eve3d_depth_normal_forward", [&] {
        depth_normal_impl(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), depth.size(0), depth.size(1), span,
                          normal.data_ptr<scalar_t>());
    });
    return normal;
}

at::Tensor depth_normal_backward(at::Tensor depth, at::Tensor rays, int64_t span, at::Tensor grad_normal) {
    check_depth_rays(depth, rays, span);
    TORCH_CHECK(grad_normal.sizes() == rays.sizes(), "depth_to_normal: gradient of shape ", grad_normal.sizes());
    depth = depth.contiguous(), rays = rays.to(depth.scalar_type()).contiguous();
    grad_normal = grad_normal.contiguous();
    auto g_dx = at::empty_like(grad_normal), g_dy = at::empty_like(grad_normal);
    auto g_depth = at::empty_like(depth);
    AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "eve3d_depth_normal_backward", [&] {
        depth_normal_backward_impl(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), depth.size(0),
                                   depth.size(1), span, grad_normal.data_ptr<scalar_t>(), g_dx.data_ptr<scalar_t>(),
                                   g_dy.data_ptr<scalar_t>(), g_depth.data_ptr<scalar_t>());
    });
    return g_depth;
}
