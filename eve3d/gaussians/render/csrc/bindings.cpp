// The torch operators torch.ops.eve3d.* (ops.h), registered through torch/library.h rather
// than bound with pybind11 (torch/python.h, whose headers took five times as long to compile).
#include <torch/library.h>

#include "ops.h"

using namespace eve3d_ops;

TORCH_LIBRARY(eve3d, m) {
    m.def("forward", &forward);                              // tile-based compositing
    m.def("backward", &backward);
    m.def("front_to_back", &front_to_back);                  // visible Gaussians by depth, their pixel boxes
    m.def("project_forward", &project_forward);              // fused EWA projection and PGSR planes
    m.def("project_backward", &project_backward);
    m.def("roundtrip_forward", &roundtrip_forward);          // PGSR's multi-view round trip, K neighbours
    m.def("roundtrip_backward", &roundtrip_backward);
    m.def("ncc_forward", &ncc_forward);                      // 1 - NCC of homography-warped patches
    m.def("ncc_backward", &ncc_backward);
    m.def("ssim_forward", &ssim_forward);                    // mean SSIM, Gaussian window, zero padding
    m.def("ssim_backward", &ssim_backward);
    m.def("depth_normal_forward", &depth_normal_forward);    // normals of a depth map
    m.def("depth_normal_backward", &depth_normal_backward);
}
