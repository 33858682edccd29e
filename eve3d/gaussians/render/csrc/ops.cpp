// The CPU kernels (kernels.h) behind the torch operators (ops.h, registered in bindings.cpp):
// each checks its tensors, allocates its outputs and dispatches on float / double. It includes
// ATen's per-operator headers, not all of ATen (torch/types.h): the headers were most of the
// build (docs/development.md, "Set-up").
#include <ATen/Dispatch.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/cat.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>
#include <ATen/ops/from_blob.h>
#include <ATen/ops/ones.h>
#include <ATen/ops/scalar_tensor.h>
#include <ATen/ops/zeros.h>
#include <ATen/ops/zeros_like.h>
#include "kernels.h"
#include "ops.h"

#include <vector>

namespace eve3d_ops {

using at::Tensor;

Tensor long_tensor(std::vector<int64_t>& values, std::vector<int64_t> shape) {
    return at::from_blob(values.data(), shape, at::kLong).clone();
}

// --- compositing -------------------------------------------------------------------------------

// Image (H*W, C), final transmittance (H*W), per-pixel count of list entries consumed (H*W,
// int32), tile offsets, tile ids and the number of pairs composited.
std::vector<Tensor> forward(Tensor means2d, Tensor conics, Tensor opac, Tensor feats, Tensor boxes, Tensor visible,
                            int64_t width, int64_t height) {
    boxes = boxes.contiguous(), visible = visible.contiguous();
    std::vector<int64_t> offsets, ids;
    eve3d::bin_tiles(boxes.data_ptr<int64_t>(), visible.data_ptr<int64_t>(), boxes.size(0), width, height, offsets,
                     ids);
    const Tensor bins[2] = {long_tensor(offsets, {(int64_t)offsets.size()}), long_tensor(ids, {(int64_t)ids.size()})};
    auto image = at::zeros({height * width, feats.size(1)}, feats.options());
    auto final_t = at::ones({height * width}, feats.options());
    auto consumed = at::zeros({height * width}, at::kInt);
    int64_t n_pairs = 0;
    AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "eve3d_rasterize_forward", [&] {
        n_pairs = eve3d::composite_forward<scalar_t>(
            means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
            feats.data_ptr<scalar_t>(), feats.size(1), feats.size(0), bins[0].data_ptr<int64_t>(),
            bins[1].data_ptr<int64_t>(), bins[0].size(0) - 1, width, height, image.data_ptr<scalar_t>(),
            final_t.data_ptr<scalar_t>(), consumed.data_ptr<int32_t>());
    });
    return {image, final_t, consumed, bins[0], bins[1], at::scalar_tensor(n_pairs, at::kLong)};
}

// Gradients for means2d (V, 2), conics (V, 3), opacities (V), features (V, C) and the
// per-pixel absolute means2d gradients summed per Gaussian (V, 2).
std::vector<Tensor> backward(Tensor means2d, Tensor conics, Tensor opac, Tensor feats, Tensor offsets, Tensor ids,
                             Tensor final_t, Tensor consumed, Tensor grad_image, Tensor grad_alpha, int64_t width,
                             int64_t height) {
    const int64_t C = feats.size(1), V = feats.size(0);
    auto buffers = at::zeros({eve3d::max_threads(), V, 8 + C}, feats.options());
    AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "eve3d_rasterize_backward", [&] {
        eve3d::composite_backward<scalar_t>(
            means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
            feats.data_ptr<scalar_t>(), C, V, offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(),
            offsets.size(0) - 1, width, height, final_t.data_ptr<scalar_t>(), consumed.data_ptr<int32_t>(),
            grad_image.data_ptr<scalar_t>(), grad_alpha.data_ptr<scalar_t>(), buffers.data_ptr<scalar_t>());
    });
    auto total = buffers.sum(0);
    return {total.slice(1, 0, 2), total.slice(1, 2, 5), total.select(1, 5), total.slice(1, 6, 6 + C),
            total.slice(1, 6 + C, 8 + C)};
}

// eve3d.gaussians.render.projection.front_to_back in C++: the Gaussians with a positive radius,
// sorted stably by depth, and their inclusive pixel boxes (V, 4), with the same float operations.
std::vector<Tensor> front_to_back(Tensor radii, Tensor depths, Tensor means2d, int64_t width, int64_t height) {
    radii = radii.to(at::kInt).contiguous();
    means2d = means2d.contiguous();
    depths = depths.to(means2d.scalar_type()).contiguous();
    std::vector<int64_t> visible, boxes;
    AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "eve3d_front_to_back", [&] {
        eve3d::front_to_back<scalar_t>(radii.data_ptr<int32_t>(), depths.data_ptr<scalar_t>(),
                                       means2d.data_ptr<scalar_t>(), radii.size(0), width, height, visible, boxes);
    });
    const int64_t v = visible.size();
    return {long_tensor(visible, {v}), long_tensor(boxes, {v, 4})};
}

// --- projection ----------------------------------------------------------------------------------

void check_projection(const Tensor& means, const Tensor& quats, const Tensor& scales, const Tensor& opacities,
                      const Tensor& R, const Tensor& t) {
    const int64_t n = means.size(0);
    TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "means must be (N, 3)");
    TORCH_CHECK(quats.dim() == 2 && quats.size(0) == n && quats.size(1) == 4, "quats must be (N, 4)");
    TORCH_CHECK(scales.dim() == 2 && scales.size(0) == n && scales.size(1) == 3, "scales must be (N, 3)");
    TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "opacities must be (N,)");
    TORCH_CHECK(R.numel() == 9 && t.numel() == 3, "R must be (3, 3) and t (3,)");
    for (const auto* x : {&quats, &scales, &opacities, &R, &t})
        TORCH_CHECK(x->scalar_type() == means.scalar_type(), "all inputs must have the dtype of means");
}

template <typename T>
eve3d::Cam<T> camera(const Tensor& R, const Tensor& t, double fx, double fy, double cx, double cy, int64_t width,
                     int64_t height, double near, double far) {
    const auto Rc = R.contiguous(), tc = t.contiguous();
    return eve3d::make_cam<T>(Rc.data_ptr<T>(), tc.data_ptr<T>(), fx, fy, cx, cy, width, height, near, far);
}

// means2d (N, 2), conics (N, 3), depths (N,), radii (N, 2) int32, compensation (N,),
// camera-space normals (N, 3), plane distances (N,) and the opacities the rasteriser uses
// (× compensation when antialiased) (N,).
std::vector<Tensor> project_forward(Tensor means, Tensor quats, Tensor scales, Tensor opacities, Tensor R, Tensor t,
                                    double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                                    double near, double far, bool antialiased) {
    check_projection(means, quats, scales, opacities, R, t);
    means = means.contiguous(), quats = quats.contiguous(), scales = scales.contiguous();
    opacities = opacities.contiguous();
    const int64_t n = means.size(0);
    const auto opts = means.options();
    auto means2d = at::empty({n, 2}, opts), conics = at::empty({n, 3}, opts);
    auto depths = at::empty({n}, opts), comp = at::empty({n}, opts);
    auto normals = at::empty({n, 3}, opts), distances = at::empty({n}, opts);
    auto opac_out = at::empty({n}, opts);
    auto radii = at::empty({n, 2}, opts.dtype(at::kInt));
    AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "eve3d_project_forward", [&] {
        eve3d::project_forward<scalar_t>(
            n, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
            opacities.data_ptr<scalar_t>(), camera<scalar_t>(R, t, fx, fy, cx, cy, width, height, near, far),
            antialiased, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), depths.data_ptr<scalar_t>(),
            radii.data_ptr<int32_t>(), comp.data_ptr<scalar_t>(), normals.data_ptr<scalar_t>(),
            distances.data_ptr<scalar_t>(), opac_out.data_ptr<scalar_t>());
    });
    return {means2d, conics, depths, radii, comp, normals, distances, opac_out};
}

// Gradients of means (N, 3), quats (N, 4), scales (N, 3) and opacities (N,) from those of
// project_forward's differentiable outputs.
std::vector<Tensor> project_backward(Tensor means, Tensor quats, Tensor scales, Tensor opacities, Tensor R, Tensor t,
                                     double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                                     double near, bool antialiased, Tensor grad_means2d, Tensor grad_conics,
                                     Tensor grad_depths, Tensor grad_compensation, Tensor grad_normals,
                                     Tensor grad_distances, Tensor grad_opacities) {
    check_projection(means, quats, scales, opacities, R, t);
    means = means.contiguous(), quats = quats.contiguous(), scales = scales.contiguous();
    opacities = opacities.contiguous();
    const int64_t n = means.size(0);
    // Incoming gradients are often slices of a wider one (the features' columns).
    std::vector<Tensor> grads;
    for (const auto& g : {grad_means2d, grad_conics, grad_depths, grad_compensation, grad_normals, grad_distances,
                          grad_opacities}) {
        TORCH_CHECK(g.scalar_type() == means.scalar_type() && g.size(0) == n, "gradient of the wrong dtype or size");
        grads.push_back(g.contiguous());
    }
    auto g_means = at::empty_like(means), g_quats = at::empty_like(quats);
    auto g_scales = at::empty_like(scales), g_opac = at::empty_like(opacities);
    AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "eve3d_project_backward", [&] {
        eve3d::project_backward<scalar_t>(
            n, means.data_ptr<scalar_t>(), quats.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
            opacities.data_ptr<scalar_t>(), camera<scalar_t>(R, t, fx, fy, cx, cy, width, height, near, 0.0),
            antialiased, grads[0].data_ptr<scalar_t>(), grads[1].data_ptr<scalar_t>(), grads[2].data_ptr<scalar_t>(),
            grads[3].data_ptr<scalar_t>(), grads[4].data_ptr<scalar_t>(), grads[5].data_ptr<scalar_t>(),
            grads[6].data_ptr<scalar_t>(), g_means.data_ptr<scalar_t>(), g_quats.data_ptr<scalar_t>(),
            g_scales.data_ptr<scalar_t>(), g_opac.data_ptr<scalar_t>());
    });
    return {g_means, g_quats, g_scales, g_opac};
}

// --- the multi-view round trip and NCC ----------------------------------------------------------------

template <typename T>
std::vector<eve3d::Pose<T>> poses(const Tensor& R, const Tensor& t, const Tensor& intrinsics) {
    const auto Rc = R.contiguous(), tc = t.contiguous(), ic = intrinsics.contiguous();
    return eve3d::poses<T>(Rc.data_ptr<T>(), tc.data_ptr<T>(), ic.data_ptr<T>(), R.size(0));
}

// phi (K, H, W), the pixel distance of each reference pixel's round trip through neighbour k,
// and where it is defined.
std::vector<Tensor> roundtrip_forward(Tensor depth_ref, Tensor depth_nbrs, Tensor R, Tensor t, Tensor nbr_intrinsics,
                                      double fx, double fy, double cx, double cy) {
    depth_ref = depth_ref.contiguous();
    depth_nbrs = depth_nbrs.contiguous();
    const int64_t K = depth_nbrs.size(0), H = depth_ref.size(0), W = depth_ref.size(1);
    auto phi = at::empty({K, H, W}, depth_ref.options());
    auto defined = at::empty({K, H, W}, depth_ref.options().dtype(at::kBool));
    AT_DISPATCH_FLOATING_TYPES(depth_ref.scalar_type(), "eve3d_roundtrip_forward", [&] {
        eve3d::roundtrip_forward<scalar_t>(depth_ref.data_ptr<scalar_t>(), depth_nbrs.data_ptr<scalar_t>(),
                                           poses<scalar_t>(R, t, nbr_intrinsics), fx, fy, cx, cy, W, H,
                                           depth_nbrs.size(2), depth_nbrs.size(1), phi.data_ptr<scalar_t>(),
                                           defined.data_ptr<bool>());
    });
    return {phi, defined};
}

// Gradients of the reference depth (H, W) and of the neighbours' depths (K, h, w).
std::vector<Tensor> roundtrip_backward(Tensor depth_ref, Tensor depth_nbrs, Tensor R, Tensor t, Tensor nbr_intrinsics,
                                       double fx, double fy, double cx, double cy, Tensor grad_phi) {
    depth_ref = depth_ref.contiguous();
    depth_nbrs = depth_nbrs.contiguous();
    grad_phi = grad_phi.contiguous();
    const int64_t K = depth_nbrs.size(0), H = depth_ref.size(0), W = depth_ref.size(1);
    auto grad_ref = at::zeros_like(depth_ref);
    auto buffers = at::zeros({eve3d::max_threads(), K, depth_nbrs.size(1), depth_nbrs.size(2)}, depth_nbrs.options());
    AT_DISPATCH_FLOATING_TYPES(depth_ref.scalar_type(), "eve3d_roundtrip_backward", [&] {
        eve3d::roundtrip_backward<scalar_t>(depth_ref.data_ptr<scalar_t>(), depth_nbrs.data_ptr<scalar_t>(),
                                            poses<scalar_t>(R, t, nbr_intrinsics), fx, fy, cx, cy, W, H,
                                            depth_nbrs.size(2), depth_nbrs.size(1), grad_phi.data_ptr<scalar_t>(),
                                            grad_ref.data_ptr<scalar_t>(), buffers.data_ptr<scalar_t>());
    });
    return {grad_ref, buffers.sum(0)};
}

template <typename T>
eve3d::NccArgs<T> ncc_args(const Tensor& ref_grey, const Tensor& nbr_greys, const Tensor& centres,
                           const Tensor& normal, const Tensor& distance, double fx, double fy, double cx, double cy,
                           int64_t patch, double step) {
    eve3d::NccArgs<T> g;
    g.ref = ref_grey.data_ptr<T>(), g.nbr = nbr_greys.data_ptr<T>(), g.centres = centres.data_ptr<T>();
    g.normal = normal.data_ptr<T>(), g.distance = distance.data_ptr<T>();
    g.H = ref_grey.size(0), g.W = ref_grey.size(1), g.h = nbr_greys.size(1), g.w = nbr_greys.size(2);
    g.K = centres.size(0), g.M = centres.size(1), g.patch = patch;
    g.fx = fx, g.fy = fy, g.cx = cx, g.cy = cy, g.step = step;
    return g;
}

void check_patch(int64_t patch) {
    TORCH_CHECK(patch >= 1 && patch * patch <= 64, "NCC patch of ", patch, "x", patch, ": at most 8x8 here");
}

// 1 - NCC (K, M) and where it is defined, for the patches around ``centres`` (K, M, 2; u, v)
// of the reference grey image (H, W), warped into neighbour k's grey image (K, h, w) by the
// planes (normal (K, M, 3), distance (K, M)) through the relative poses R, t and intrinsics.
std::vector<Tensor> ncc_forward(Tensor ref_grey, Tensor nbr_greys, Tensor centres, Tensor normal, Tensor distance,
                                Tensor R, Tensor t, Tensor nbr_intrinsics, double fx, double fy, double cx, double cy,
                                int64_t patch, double step) {
    check_patch(patch);
    ref_grey = ref_grey.contiguous(), nbr_greys = nbr_greys.contiguous(), centres = centres.contiguous();
    normal = normal.contiguous(), distance = distance.contiguous();
    auto loss = at::empty({centres.size(0), centres.size(1)}, distance.options());
    auto defined = at::empty({centres.size(0), centres.size(1)}, distance.options().dtype(at::kBool));
    AT_DISPATCH_FLOATING_TYPES(distance.scalar_type(), "eve3d_ncc_forward", [&] {
        eve3d::ncc_forward<scalar_t>(
            ncc_args<scalar_t>(ref_grey, nbr_greys, centres, normal, distance, fx, fy, cx, cy, patch, step),
            poses<scalar_t>(R, t, nbr_intrinsics), loss.data_ptr<scalar_t>(), defined.data_ptr<bool>());
    });
    return {loss, defined};
}

// Gradients of the loss for the planes: normal (K, M, 3) and distance (K, M).
std::vector<Tensor> ncc_backward(Tensor ref_grey, Tensor nbr_greys, Tensor centres, Tensor normal, Tensor distance,
                                 Tensor R, Tensor t, Tensor nbr_intrinsics, double fx, double fy, double cx,
                                 double cy, int64_t patch, double step, Tensor grad_loss) {
    check_patch(patch);
    ref_grey = ref_grey.contiguous(), nbr_greys = nbr_greys.contiguous(), centres = centres.contiguous();
    normal = normal.contiguous(), distance = distance.contiguous(), grad_loss = grad_loss.contiguous();
    auto g_normal = at::empty_like(normal), g_distance = at::empty_like(distance);
    AT_DISPATCH_FLOATING_TYPES(distance.scalar_type(), "eve3d_ncc_backward", [&] {
        eve3d::ncc_backward<scalar_t>(
            ncc_args<scalar_t>(ref_grey, nbr_greys, centres, normal, distance, fx, fy, cx, cy, patch, step),
            poses<scalar_t>(R, t, nbr_intrinsics), grad_loss.data_ptr<scalar_t>(), g_normal.data_ptr<scalar_t>(),
            g_distance.data_ptr<scalar_t>());
    });
    return {g_normal, g_distance};
}

// --- image losses ----------------------------------------------------------------------------------

// Mean SSIM of two (H, W, C) images, and the per-pixel derivatives (3, C, H, W) the backward needs.
std::vector<Tensor> ssim_forward(Tensor a, Tensor b, int64_t window, double sigma) {
    TORCH_CHECK(a.device().is_cpu() && b.device().is_cpu(), "ssim: CPU tensors");
    TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes(), "ssim: two (H, W, C) images of one size, got ", a.sizes(),
                " and ", b.sizes());
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2);
    // planar: x, y, x^2, y^2, xy of every channel; then their blurs
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    const std::vector<Tensor> planes = {x, y, x.mul(x), y.mul(y), x.mul(y)};
    auto maps = at::cat(planes).contiguous();
    auto derivs = at::empty({3, C, H, W}, a.options());  // d SSIM / d mu_x, d E[x^2], d E[xy]
    double total = 0;
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_forward", [&] {
        total = eve3d::ssim_forward<scalar_t>(maps.data_ptr<scalar_t>(), C, H, W, window, sigma,
                                              derivs.data_ptr<scalar_t>());
    });
    return {at::scalar_tensor(total / (double)(C * H * W), a.options()), derivs};
}

// d(grad_out * SSIM) / d a, (H, W, C).
Tensor ssim_backward(Tensor a, Tensor b, Tensor derivs, int64_t window, double sigma, double grad_out) {
    TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes() && derivs.size(0) == 3 && derivs.numel() == 3 * a.numel(),
                "ssim backward: images (H, W, C) and derivatives (3, C, H, W) of one size");
    const int64_t H = a.size(0), W = a.size(1), C = a.size(2);
    auto x = a.permute({2, 0, 1}).contiguous(), y = b.permute({2, 0, 1}).contiguous().to(a.scalar_type());
    auto blurred = derivs.clone();
    auto grad = at::empty({C, H, W}, a.options());
    AT_DISPATCH_FLOATING_TYPES(a.scalar_type(), "eve3d_ssim_backward", [&] {
        eve3d::ssim_backward<scalar_t>(blurred.data_ptr<scalar_t>(), x.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), C,
                                       H, W, window, sigma, grad_out, grad.data_ptr<scalar_t>());
    });
    return grad.permute({1, 2, 0}).contiguous();
}

void check_depth_rays(const Tensor& depth, const Tensor& rays, int64_t span) {
    TORCH_CHECK(depth.device().is_cpu() && rays.device().is_cpu(), "depth_to_normal: CPU tensors");
    TORCH_CHECK(depth.dim() == 2 && rays.dim() == 3 && rays.size(0) == depth.size(0) &&
                    rays.size(1) == depth.size(1) && rays.size(2) == 3,
                "depth_to_normal: depth (H, W) and rays (H, W, 3) of one size, got ", depth.sizes(), " and ",
                rays.sizes());
    TORCH_CHECK(span >= 1, "depth_to_normal: span >= 1, got ", span);
}

// Unit normals (H, W, 3) of a depth map (H, W) from its back-projected points (rays (H, W, 3)).
Tensor depth_normal_forward(Tensor depth, Tensor rays, int64_t span) {
    check_depth_rays(depth, rays, span);
    depth = depth.contiguous(), rays = rays.to(depth.scalar_type()).contiguous();
    auto normal = at::empty({depth.size(0), depth.size(1), 3}, depth.options());
    AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "eve3d_depth_normal_forward", [&] {
        eve3d::depth_normal_forward<scalar_t>(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), depth.size(0),
                                              depth.size(1), span, normal.data_ptr<scalar_t>());
    });
    return normal;
}

// d(<grad_normal, normal>) / d depth, (H, W).
Tensor depth_normal_backward(Tensor depth, Tensor rays, int64_t span, Tensor grad_normal) {
    check_depth_rays(depth, rays, span);
    TORCH_CHECK(grad_normal.sizes() == rays.sizes(), "depth_to_normal: gradient of shape ", grad_normal.sizes());
    depth = depth.contiguous(), rays = rays.to(depth.scalar_type()).contiguous();
    grad_normal = grad_normal.contiguous();
    auto g_dx = at::empty_like(grad_normal), g_dy = at::empty_like(grad_normal);
    auto g_depth = at::empty_like(depth);
    AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "eve3d_depth_normal_backward", [&] {
        eve3d::depth_normal_backward<scalar_t>(depth.data_ptr<scalar_t>(), rays.data_ptr<scalar_t>(), depth.size(0),
                                               depth.size(1), span, grad_normal.data_ptr<scalar_t>(),
                                               g_dx.data_ptr<scalar_t>(), g_dy.data_ptr<scalar_t>(),
                                               g_depth.data_ptr<scalar_t>());
    });
    return g_depth;
}

}  // namespace eve3d_ops
