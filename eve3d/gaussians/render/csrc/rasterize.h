// Tile-based compositing (rasterize.cpp), registered as torch operators in ops.cpp.
#pragma once

#include "aten.h"

#include <vector>

// Image (H*W, C), final transmittance (H*W), per-pixel count of list entries consumed (H*W,
// int32), tile offsets, tile ids and the number of pairs composited.
std::vector<at::Tensor> forward(at::Tensor means2d, at::Tensor conics, at::Tensor opac, at::Tensor feats,
                                at::Tensor boxes, at::Tensor visible, int64_t width, int64_t height);

// Gradients for means2d (V, 2), conics (V, 3), opacities (V), features (V, C) and the per-pixel
// absolute means2d gradients summed per Gaussian (V, 2).
std::vector<at::Tensor> backward(at::Tensor means2d, at::Tensor conics, at::Tensor opac, at::Tensor feats,
                                 at::Tensor offsets, at::Tensor ids, at::Tensor final_t, at::Tensor consumed,
                                 at::Tensor grad_image, at::Tensor grad_alpha, int64_t width, int64_t height);

// The Gaussians with a positive radius, sorted stably by depth, and their pixel boxes (V, 4).
std::vector<at::Tensor> front_to_back(at::Tensor radii, at::Tensor depths, at::Tensor means2d, int64_t width,
                                      int64_t height);
