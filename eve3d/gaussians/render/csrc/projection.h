// Fused projection (projection.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include <torch/types.h>  // tensors only: torch/extension.h took 51 s to compile, this 17 s

#include <vector>

std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor opacities, torch::Tensor R, torch::Tensor t, double fx,
                                           double fy, double cx, double cy, int64_t width, int64_t height,
                                           double near, double far, bool antialiased);

std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor opacities, torch::Tensor R, torch::Tensor t, double fx,
                                            double fy, double cx, double cy, int64_t width, int64_t height,
                                            double near, bool antialiased, torch::Tensor grad_means2d,
                                            torch::Tensor grad_conics, torch::Tensor grad_depths,
                                            torch::Tensor grad_compensation, torch::Tensor grad_normals,
                                            torch::Tensor grad_distances, torch::Tensor grad_opacities);
