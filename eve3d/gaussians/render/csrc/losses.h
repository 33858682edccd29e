// Image losses (losses.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include <torch/types.h>  // tensors only: torch/extension.h took 51 s to compile, this 17 s

#include <vector>

// Mean SSIM of two (H, W, C) images, and the per-pixel derivatives (3, C, H, W) the backward needs.
std::vector<torch::Tensor> ssim_forward(torch::Tensor a, torch::Tensor b, int64_t window, double sigma);

// d(grad_out * SSIM) / d a, (H, W, C).
torch::Tensor ssim_backward(torch::Tensor a, torch::Tensor b, torch::Tensor derivs, int64_t window, double sigma,
                            double grad_out);

// Unit normals (H, W, 3) of a depth map (H, W) from its back-projected points (rays (H, W, 3)).
torch::Tensor depth_normal_forward(torch::Tensor depth, torch::Tensor rays, int64_t span);

// d(<grad_normal, normal>) / d depth, (H, W).
torch::Tensor depth_normal_backward(torch::Tensor depth, torch::Tensor rays, int64_t span, torch::Tensor grad_normal);
