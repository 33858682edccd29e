// PGSR's multi-view round trip and NCC (roundtrip.cpp), bound to Python in rasterize.cpp's module.
#pragma once

#include <torch/types.h>  // tensors only: torch/extension.h took 51 s to compile, this 17 s

#include <vector>

std::vector<torch::Tensor> roundtrip_forward(torch::Tensor depth_ref, torch::Tensor depth_nbrs, torch::Tensor R,
                                             torch::Tensor t, torch::Tensor nbr_intrinsics, double fx, double fy,
                                             double cx, double cy);

std::vector<torch::Tensor> roundtrip_backward(torch::Tensor depth_ref, torch::Tensor depth_nbrs, torch::Tensor R,
                                              torch::Tensor t, torch::Tensor nbr_intrinsics, double fx, double fy,
                                              double cx, double cy, torch::Tensor grad_phi);

std::vector<torch::Tensor> ncc_forward(torch::Tensor ref_grey, torch::Tensor nbr_greys, torch::Tensor centres,
                                       torch::Tensor normal, torch::Tensor distance, torch::Tensor R, torch::Tensor t,
                                       torch::Tensor nbr_intrinsics, double fx, double fy, double cx, double cy,
                                       int64_t patch, double step);

std::vector<torch::Tensor> ncc_backward(torch::Tensor ref_grey, torch::Tensor nbr_greys, torch::Tensor centres,
                                        torch::Tensor normal, torch::Tensor distance, torch::Tensor R,
                                        torch::Tensor t, torch::Tensor nbr_intrinsics, double fx, double fy,
                                        double cx, double cy, int64_t patch, double step, torch::Tensor grad_loss);
