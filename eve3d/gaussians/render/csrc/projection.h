// Fused projection (projection.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include "aten.h"

#include <vector>

std::vector<at::Tensor> project_forward(at::Tensor means, at::Tensor quats, at::Tensor scales,
                                           at::Tensor opacities, at::Tensor R, at::Tensor t, double fx,
                                           double fy, double cx, double cy, int64_t width, int64_t height,
                                           double near, double far, bool antialiased);

std::vector<at::Tensor> project_backward(at::Tensor means, at::Tensor quats, at::Tensor scales,
                                            at::Tensor opacities, at::Tensor R, at::Tensor t, double fx,
                                            double fy, double cx, double cy, int64_t width, int64_t height,
                                            double near, bool antialiased, at::Tensor grad_means2d,
                                            at::Tensor grad_conics, at::Tensor grad_depths,
                                            at::Tensor grad_compensation, at::Tensor grad_normals,
                                            at::Tensor grad_distances, at::Tensor grad_opacities);
