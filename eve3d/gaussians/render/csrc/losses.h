// Image losses (losses.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include "aten.h"

#include <vector>

// Mean SSIM of two (H, W, C) images, and the per-pixel derivatives (3, C, H, W) the backward needs.
std::vector<at::Tensor> ssim_forward(at::Tensor a, at::Tensor b, int64_t window, double sigma);

// d(grad_out * SSIM) / d a, (H, W, C).
at::Tensor ssim_backward(at::Tensor a, at::Tensor b, at::Tensor derivs, int64_t window, double sigma,
                            double grad_out);

// Unit normals (H, W, 3) of a depth map (H, W) from its back-projected points (rays (H, W, 3)).
at::Tensor depth_normal_forward(at::Tensor depth, at::Tensor rays, int64_t span);

// d(<grad_normal, normal>) / d depth, (H, W).
at::Tensor depth_normal_backward(at::Tensor depth, at::Tensor rays, int64_t span, at::Tensor grad_normal);
