// SSIM with 3DGS's Gaussian window and zero padding (eve3d.losses.ssim), forward and analytic
// backward for the first image. The five blurred maps are two separable passes over all
// planes at once; the forward also leaves, per pixel, the derivatives of SSIM with respect to
// the blurred maps that depend on the first image (mu_x, E[x^2], E[xy]), so the backward is
// three blurs (the blur's adjoint: a symmetric kernel with zero padding is its own) and a
// combination. Replaces some thirty tensor operations and a grouped 11x11 convolution.
#include "ssim.h"

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

std::vector<torch::Tensor> ssim_forward(torch::Tensor a, torch::Tensor b, int64_t window, double sigma) {
    TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes(), "ssim: two (H, W, C) images of one size");
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2), HW = H * W;
    // planar: x, y, x^2, y^2, xy of every channel; then their blurs
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    auto maps = torch::cat({x, y, x * x, y * y, x * y}).contiguous();
    auto derivs = torch::empty({3, C, H, W}, a.options());  // d SSIM / d mu_x, d E[x^2], d E[xy]
    double total = 0;
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_forward", [&] {
        scalar_t* m = maps.data_ptr<scalar_t>();
        blur(m, 5 * C, H, W, gaussian_taps<scalar_t>(window, sigma));
        total = ssim_map(m, C * HW, derivs.data_ptr<scalar_t>());
    });
    return {torch::tensor(total / (double)(C * HW), a.options()), derivs};
}

torch::Tensor ssim_backward(torch::Tensor a, torch::Tensor b, torch::Tensor derivs, int64_t window, double sigma,
                            double grad_out) {
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2), HW = H * W;
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    auto blurred = derivs.clone();
    auto grad = torch::empty({C, H, W}, a.options());
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_backward", [&] {
        scalar_t* m = blurred.data_ptr<scalar_t>();
        blur(m, 3 * C, H, W, gaussian_taps<scalar_t>(window, sigma));
        ssim_grad(m, x.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), C * HW, (scalar_t)(grad_out / (double)(C * HW)),
                  grad.data_ptr<scalar_t>());
    });
    return grad.permute({1, 2, 0}).contiguous();
}
