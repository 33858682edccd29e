// The torch operators' C++ side (ops.cpp), registered in bindings.cpp: see each one's comment there.
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace eve3d_ops {

using at::Tensor;

std::vector<Tensor> forward(Tensor means2d, Tensor conics, Tensor opac, Tensor feats, Tensor boxes, Tensor visible,
                            int64_t width, int64_t height);
std::vector<Tensor> backward(Tensor means2d, Tensor conics, Tensor opac, Tensor feats, Tensor offsets, Tensor ids,
                             Tensor final_t, Tensor consumed, Tensor grad_image, Tensor grad_alpha, int64_t width,
                             int64_t height);
std::vector<Tensor> front_to_back(Tensor radii, Tensor depths, Tensor means2d, int64_t width, int64_t height);
std::vector<Tensor> project_forward(Tensor means, Tensor quats, Tensor scales, Tensor opacities, Tensor R, Tensor t,
                                    double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                                    double near, double far, bool antialiased);
std::vector<Tensor> project_backward(Tensor means, Tensor quats, Tensor scales, Tensor opacities, Tensor R, Tensor t,
                                     double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                                     double near, bool antialiased, Tensor grad_means2d, Tensor grad_conics,
                                     Tensor grad_depths, Tensor grad_compensation, Tensor grad_normals,
                                     Tensor grad_distances, Tensor grad_opacities);
std::vector<Tensor> roundtrip_forward(Tensor depth_ref, Tensor depth_nbrs, Tensor R, Tensor t, Tensor nbr_intrinsics,
                                      double fx, double fy, double cx, double cy);
std::vector<Tensor> roundtrip_backward(Tensor depth_ref, Tensor depth_nbrs, Tensor R, Tensor t, Tensor nbr_intrinsics,
                                       double fx, double fy, double cx, double cy, Tensor grad_phi);
std::vector<Tensor> ncc_forward(Tensor ref_grey, Tensor nbr_greys, Tensor centres, Tensor normal, Tensor distance,
                                Tensor R, Tensor t, Tensor nbr_intrinsics, double fx, double fy, double cx, double cy,
                                int64_t patch, double step);
std::vector<Tensor> ncc_backward(Tensor ref_grey, Tensor nbr_greys, Tensor centres, Tensor normal, Tensor distance,
                                 Tensor R, Tensor t, Tensor nbr_intrinsics, double fx, double fy, double cx,
                                 double cy,
                                 int64_t patch, double step, Tensor grad_loss);
std::vector<Tensor> ssim_forward(Tensor a, Tensor b, int64_t window, double sigma);
Tensor ssim_backward(Tensor a, Tensor b, Tensor derivs, int64_t window, double sigma, double grad_out);
Tensor depth_normal_forward(Tensor depth, Tensor rays, int64_t span);
Tensor depth_normal_backward(Tensor depth, Tensor rays, int64_t span, Tensor grad_normal);

}  // namespace eve3d_ops
