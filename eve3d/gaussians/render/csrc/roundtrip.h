// PGSR's multi-view round trip and NCC (roundtrip.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include "aten.h"

#include <vector>

std::vector<at::Tensor> roundtrip_forward(at::Tensor depth_ref, at::Tensor depth_nbrs, at::Tensor R,
                                             at::Tensor t, at::Tensor nbr_intrinsics, double fx, double fy,
                                             double cx, double cy);

std::vector<at::Tensor> roundtrip_backward(at::Tensor depth_ref, at::Tensor depth_nbrs, at::Tensor R,
                                              at::Tensor t, at::Tensor nbr_intrinsics, double fx, double fy,
                                              double cx, double cy, at::Tensor grad_phi);

std::vector<at::Tensor> ncc_forward(at::Tensor ref_grey, at::Tensor nbr_greys, at::Tensor centres,
                                       at::Tensor normal, at::Tensor distance, at::Tensor R, at::Tensor t,
                                       at::Tensor nbr_intrinsics, double fx, double fy, double cx, double cy,
                                       int64_t patch, double step);

std::vector<at::Tensor> ncc_backward(at::Tensor ref_grey, at::Tensor nbr_greys, at::Tensor centres,
                                        at::Tensor normal, at::Tensor distance, at::Tensor R,
                                        at::Tensor t, at::Tensor nbr_intrinsics, double fx, double fy,
                                        double cx, double cy, int64_t patch, double step, at::Tensor grad_loss);
