// The CPU kernels on plain arrays (rasterize.cpp, projection.cpp, roundtrip.cpp, losses.cpp),
// instantiated for float and double. They include no ATen, so that each file compiles in
// seconds; ops.cpp checks the tensors, allocates the outputs and registers the torch operators.
#pragma once

#include <cstdint>
#include <vector>

namespace eve3d {

int max_threads();

// --- rasterize.cpp: tile-based compositing ---------------------------------------------------

// Per-tile lists (CSR) of the visible Gaussians (boxes (n, 4) inclusive pixel boxes in depth
// order, visible (n,) their indices among all): counts (tiles + 1) offsets and ids.
void bin_tiles(const int64_t* boxes, const int64_t* visible, int64_t n, int64_t width, int64_t height,
               std::vector<int64_t>& offsets, std::vector<int64_t>& ids);

// Composites the tiles' lists front to back: image (H*W, C), final transmittance (H*W) and
// the per-pixel count of entries consumed; returns the pairs composited.
template <typename T>
int64_t composite_forward(const T* means2d, const T* conics, const T* opac, const T* feats, int64_t C, int64_t V,
                          const int64_t* offsets, const int64_t* ids, int64_t tiles, int64_t width, int64_t height,
                          T* image, T* final_t, int32_t* consumed);

// Per-thread gradient rows (max_threads(), V, 8 + C): means2d, conics, opacity, features, |means2d|.
template <typename T>
void composite_backward(const T* means2d, const T* conics, const T* opac, const T* feats, int64_t C, int64_t V,
                        const int64_t* offsets, const int64_t* ids, int64_t tiles, int64_t width, int64_t height,
                        const T* final_t, const int32_t* consumed, const T* grad_image, const T* grad_alpha,
                        T* buffers);

// The Gaussians with a positive radius (radii (n, 2)), sorted stably by depth, and their
// inclusive pixel boxes (V, 4) x0, y0, x1, y1.
template <typename T>
void front_to_back(const int32_t* radii, const T* depths, const T* means2d, int64_t n, int64_t width, int64_t height,
                   std::vector<int64_t>& visible, std::vector<int64_t>& boxes);

// --- projection.cpp: fused EWA projection and PGSR planes --------------------------------------

template <typename T>
struct Cam {
    T R[9], t[3];
    T fx, fy, cx, cy;
    T lo_x, hi_x, lo_y, hi_y;  // the tangent clamp on x/z and y/z
    T near, far, width, height;
};

template <typename T>
Cam<T> make_cam(const T* R, const T* t, double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                double near, double far);

template <typename T>
void project_forward(int64_t n, const T* means, const T* quats, const T* scales, const T* opac, const Cam<T>& C,
                     bool antialiased, T* means2d, T* conics, T* depths, int32_t* radii, T* comp, T* normals,
                     T* distances, T* opac_out);

template <typename T>
void project_backward(int64_t n, const T* means, const T* quats, const T* scales, const T* opac, const Cam<T>& C,
                      bool antialiased, const T* gm2, const T* gcon, const T* gdep, const T* gcomp, const T* gnorm,
                      const T* gdist, const T* gop, T* g_means, T* g_quats, T* g_scales, T* g_opac);

// --- roundtrip.cpp: PGSR's multi-view round trip and NCC -----------------------------------------

template <typename T>
struct Pose {  // reference camera -> neighbour camera, and the neighbour's intrinsics
    T R[9], t[3], fx, fy, cx, cy;
};

// K poses from R (K, 3, 3), t (K, 3) and intrinsics (K, 4) fx, fy, cx, cy.
template <typename T>
std::vector<Pose<T>> poses(const T* R, const T* t, const T* intrinsics, int64_t K);

template <typename T>
void roundtrip_forward(const T* dref, const T* dnbr, const std::vector<Pose<T>>& P, T fx, T fy, T cx, T cy,
                       int64_t W, int64_t H, int64_t w, int64_t h, T* phi, bool* defined);

template <typename T>
void roundtrip_backward(const T* dref, const T* dnbr, const std::vector<Pose<T>>& P, T fx, T fy, T cx, T cy,
                        int64_t W, int64_t H, int64_t w, int64_t h, const T* gphi, T* gref, T* gnbr_all);

template <typename T>
struct NccArgs {
    const T *ref, *nbr, *centres, *normal, *distance;
    int64_t W, H, w, h, K, M, patch;
    T fx, fy, cx, cy, step;
};

template <typename T>
void ncc_forward(const NccArgs<T>& g, const std::vector<Pose<T>>& P, T* loss, bool* defined);

template <typename T>
void ncc_backward(const NccArgs<T>& g, const std::vector<Pose<T>>& P, const T* gloss, T* gn, T* gd);

// --- losses.cpp: SSIM and the normals of a depth map ----------------------------------------------

// maps (5, C, H, W): x, y, x², y², xy, blurred in place; derivs (3, C, H, W); returns the SSIM sum.
template <typename T>
double ssim_forward(T* maps, int64_t C, int64_t H, int64_t W, int64_t window, double sigma, T* derivs);

// blurred (3, C, H, W): the forward's derivatives, blurred in place; grad (C, H, W).
template <typename T>
void ssim_backward(T* blurred, const T* x, const T* y, int64_t C, int64_t H, int64_t W, int64_t window, double sigma,
                   double grad_out, T* grad);

template <typename T>
void depth_normal_forward(const T* depth, const T* rays, int64_t H, int64_t W, int64_t span, T* normal);

template <typename T>
void depth_normal_backward(const T* depth, const T* rays, int64_t H, int64_t W, int64_t span, const T* grad_normal,
                           T* g_dx, T* g_dy, T* g_depth);

}  // namespace eve3d
