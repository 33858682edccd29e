"""Image and multi-view losses of 3DGS and PGSR, in PyTorch (images are (H, W, C) tensors); the
camera geometry they use is :mod:`eve3d.gaussians.geometry`.

Conventions: camera space is OpenCV (x right, y down, z forward); rendered normals face
the camera; a pixel (u, v) has its centre at (u + 0.5, v + 0.5).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F

from eve3d.gaussians.geometry import (CameraStack, depth_to_normal, plane_homographies, relative_poses, reproject,
                                      sample_maps)
from eve3d.gaussians.render import cpu
from eve3d.gaussians.render.projection import CameraTensors


def _gaussian_window(size: int, sigma: float, channels: int, like: torch.Tensor) -> torch.Tensor:
    x = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-x**2 / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, size, size).contiguous()


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5, fused: bool | None = None
         ) -> torch.Tensor:
    """Mean SSIM of two (H, W, C) images in [0, 1] (3DGS's Gaussian window, zero padding).

    ``fused``: compute it in the C++ extension (``csrc/losses.cpp``: separable blurs and an
    analytic backward; gradients reach ``a`` only), which by default it does in training: CPU
    tensors, ``a`` needing a gradient and ``b`` none (the training image), and an extension
    that builds; else with the PyTorch operations below (the reference)."""
    if fused is None:
        fused = a.requires_grad and not b.requires_grad and cpu.fused_here(a)
    if fused:
        if b.requires_grad:
            raise ValueError("ssim(fused=True) differentiates the first image only; b needs a gradient here")
        return _FusedSsim.apply(a, b, window, sigma)
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    c = x.shape[1]
    # the five blurred maps in one grouped convolution (one call, forward and backward)
    stacked = torch.cat([x, y, x * x, y * y, x * y], 1)
    w = _gaussian_window(window, sigma, 5 * c, x)
    mu_x, mu_y, xx, yy, xy = F.conv2d(stacked, w, padding=window // 2, groups=5 * c).split(c, 1)
    var_x = xx - mu_x**2
    var_y = yy - mu_y**2
    cov = xy - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.mean()


class _FusedSsim(torch.autograd.Function):
    @staticmethod
    def forward(ctx, a, b, window, sigma):
        value, derivs = cpu.extension().ssim_forward(a.detach(), b.detach(), window, sigma)
        ctx.save_for_backward(a, b, derivs)
        ctx.window = window, sigma
        return value

    @staticmethod
    def backward(ctx, grad):
        a, b, derivs = ctx.saved_tensors
        return cpu.extension().ssim_backward(a.detach(), b.detach(), derivs, *ctx.window, float(grad)), None, None, None


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.detach() - b.detach()) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def rgb_loss(pred: torch.Tensor, gt: torch.Tensor, ssim_weight: float = 0.2) -> torch.Tensor:
    """L_rgb = (1 − λ)·L1 + λ·(1 − SSIM)."""
    return (1 - ssim_weight) * (pred - gt).abs().mean() + ssim_weight * (1 - ssim(pred, gt))


def edge_weight(image: torch.Tensor) -> torch.Tensor:
    """(1 − g)² with g the grey-level gradient magnitude normalised to [0, 1] (PGSR):
    the depth–normal loss is relaxed at image edges, where depth may jump."""
    grey = image.mean(-1)
    gx = F.pad(grey[:, 2:] - grey[:, :-2], (1, 1)).abs() / 2
    gy = F.pad(grey[2:] - grey[:-2], (0, 0, 1, 1)).abs() / 2
    g = torch.sqrt(gx**2 + gy**2)
    g = (g - g.min()) / (g.max() - g.min()).clamp_min(1e-8)
    return ((1 - g).clamp(0, 1) ** 2).detach()


def depth_normal_loss(depth: torch.Tensor, normal: torch.Tensor, edges: torch.Tensor, cam: CameraTensors,
                      valid: torch.Tensor) -> torch.Tensor:
    """mean((1 − g)² · |N_d − N|₁) over ``valid`` pixels; N is the rendered normal
    (normalised here), N_d the normal of the rendered depth, ``edges`` the photo's (1 − g)²
    (:func:`edge_weight`)."""
    n_d = depth_to_normal(depth, cam)
    n = F.normalize(normal, dim=-1)
    err = (n_d - n).abs().sum(-1) * edges
    mask = valid & (n_d.norm(dim=-1) > 0)
    return (err * mask).sum() / mask.sum().clamp_min(1)


def _extension_cameras(ref: CameraTensors, nbrs: CameraStack, dtype: torch.dtype
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, tuple[float, float, float, float]]:
    """The cameras as the extension takes them: relative poses R (K, 3, 3) and t (K, 3), the
    neighbours' intrinsics (K, 4) fx, fy, cx, cy, in ``dtype``, and the reference's."""
    R, t = relative_poses(ref, nbrs)
    intrinsics = torch.cat([nbrs.focal, nbrs.centre], 1)
    return R.to(dtype), t.to(dtype), intrinsics.to(dtype), (ref.fx, ref.fy, ref.cx, ref.cy)


def forward_backward_error(depth_ref: torch.Tensor, depth_nbrs: Sequence[torch.Tensor], ref: CameraTensors,
                           nbrs: CameraStack, fused: bool | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """PGSR's multi-view geometric check against K neighbours at once. Each reference pixel
    is back-projected with ``depth_ref`` (H, W), projected into neighbour k, given that
    neighbour's depth there (bilinear in ``depth_nbrs[k]``), back-projected and projected
    into the reference again. Returns φ (K, H, W), the pixel distance of each round trip,
    and whether the round trip was defined (K, H, W).

    ``fused``: compute it in one pass of the C++ extension (``csrc/roundtrip.cpp``, an
    analytic backward), which by default it does on the CPU when the neighbours' maps share a
    size and the extension builds; else with the PyTorch operations below (the reference)."""
    if cpu.fused_here(depth_ref, depth_nbrs) if fused is None else fused:
        R, t, intrinsics, ref_intrinsics = _extension_cameras(ref, nbrs, depth_ref.dtype)
        return _RoundTrip.apply(depth_ref, torch.stack(list(depth_nbrs)), R, t, intrinsics, ref_intrinsics)
    uv_n, z_n = reproject(depth_ref, ref, nbrs)
    R, t = relative_poses(ref, nbrs)
    d_n = sample_maps([d[..., None] for d in depth_nbrs], uv_n)[..., 0]
    back = (nbrs.rays_at(uv_n) * d_n[..., None] - t[:, None]) @ R  # neighbour → reference: Rᵀ (x − t)
    uv_r, z_r = CameraStack([ref]).project(back)
    shape = (len(nbrs), *depth_ref.shape)
    phi = (uv_r - ref.pixel_centres().reshape(1, -1, 2)).norm(dim=-1).reshape(shape)
    defined = (depth_ref > 0).reshape(1, -1) & (z_n > 0) & (d_n > 0) & (z_r > 0) & nbrs.inside(uv_n)
    return phi, defined.reshape(shape)


class _RoundTrip(torch.autograd.Function):
    """:func:`forward_backward_error`'s φ and definedness from the C++ extension; gradients
    reach the reference depth and every neighbour depth."""

    @staticmethod
    def forward(ctx, depth_ref, depth_nbrs, R, t, intrinsics, ref_intrinsics):
        args = (R, t, intrinsics, *ref_intrinsics)
        phi, defined = cpu.extension().roundtrip_forward(depth_ref.detach(), depth_nbrs.detach(), *args)
        ctx.save_for_backward(depth_ref, depth_nbrs)
        ctx.args = args
        ctx.mark_non_differentiable(defined)
        return phi, defined

    @staticmethod
    def backward(ctx, grad_phi, _):
        depth_ref, depth_nbrs = ctx.saved_tensors
        grad_ref, grad_nbrs = cpu.extension().roundtrip_backward(depth_ref.detach(), depth_nbrs.detach(), *ctx.args,
                                                                 grad_phi)
        return grad_ref, grad_nbrs, None, None, None, None


FLAT_STD = 0.5 / 255
"""A grey-level window whose standard deviation is below this (half an 8-bit level) has no
texture: a photometric check can neither confirm nor refute a depth there."""


def window_ncc(a, b, box):
    """The NCC of two images over every window that ``box`` averages (OpenCV's box filter on
    NumPy arrays, or a pooling on tensors), cov / √(var_a · var_b), and both variances: a
    window whose variance is below ``FLAT_STD``² (grey levels in [0, 1]; (255·``FLAT_STD``)²
    in 0–255) has no texture, and its NCC says nothing."""
    mean_a, mean_b = box(a), box(b)
    var_a = (box(a * a) - mean_a * mean_a).clip(min=0)
    var_b = (box(b * b) - mean_b * mean_b).clip(min=0)
    return (box(a * b) - mean_a * mean_b) / (var_a * var_b + 1e-12) ** 0.5, var_a, var_b


@torch.no_grad()
def depth_confirmation(depth: torch.Tensor, ref_grey: torch.Tensor, ref: CameraTensors, nbrs: CameraStack,
                       nbr_depths: Sequence[torch.Tensor], nbr_confident: Sequence[torch.Tensor],
                       nbr_greys: Sequence[torch.Tensor], tolerance: float, window: int = 7
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What K neighbours say of a reference depth map ``depth`` (H, W): every pixel is
    back-projected and projected into neighbour k. Returns (K, H, W) ``agrees``: it lands
    inside k's image, on pixels that are all confident there (every bilinear tap of
    ``nbr_confident[k]``), and its depth in k's frame is within ``tolerance`` (relative) of
    ``nbr_depths[k]``; (K, H, W) ``ncc``: the NCC over ``window``² pixels between the
    reference grey image (H, W, 1) and k's grey image sampled where each pixel lands (−1
    where it falls outside k's image or behind it); and (H, W) ``flat``: the reference
    window has no texture (std below ``FLAT_STD``), so the NCC says nothing there.

    A tolerance in relative depth means the same at every image size, where a pixel
    tolerance loosens as the images shrink and the baselines narrow."""
    uv, z = reproject(depth, ref, nbrs)
    shape = (len(nbrs), *depth.shape)
    seen = ((depth > 0).reshape(1, -1) & (z > 0) & nbrs.inside(uv)).reshape(shape)
    sampled = sample_maps([torch.stack([d, c.to(d.dtype), g[..., 0]], -1) for d, c, g in
                           zip(nbr_depths, nbr_confident, nbr_greys)], uv).reshape(*shape, 3)
    theirs, confident, grey = sampled.unbind(-1)
    agrees = seen & (confident >= 1 - 1e-6) & ((z.reshape(shape) - theirs).abs() <= tolerance * theirs)
    ncc, var_a, var_b = window_ncc(
        ref_grey[..., 0][None], grey,
        lambda x: F.avg_pool2d(x[:, None], window, 1, window // 2, count_include_pad=False)[:, 0])
    ncc = torch.where(seen & (var_b > FLAT_STD ** 2), ncc, torch.full_like(ncc, -1.0))
    return agrees, ncc, var_a[0] < FLAT_STD ** 2


def geometric_loss(phi: torch.Tensor, defined: torch.Tensor, threshold: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """mean(exp(−φ)·φ) over the pixels of each (H, W) map of ``phi`` (..., H, W) whose round
    trip closes within ``threshold`` px (the weight is not differentiated): shape (...);
    also returns that mask."""
    valid = defined & (phi < threshold)
    w = torch.exp(-phi).detach()
    return (w * phi * valid).sum((-2, -1)) / valid.sum((-2, -1)).clamp_min(1), valid


def ncc_loss(ref_grey: torch.Tensor, nbr_greys: Sequence[torch.Tensor], ref: CameraTensors, nbrs: CameraStack,
             normal: torch.Tensor, distance: torch.Tensor, pixels: torch.Tensor, patch: int = 7,
             step: float = 1.0, fused: bool | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Photometric multi-view loss 1 − NCC of ``patch``×``patch`` patches of grey images
    ((H, W, 1) ``ref_grey``, one of ``nbr_greys`` per neighbour) around reference
    ``pixels`` (K, M, 2 integer (row, col)), those of row k warped into neighbour k by each
    pixel's rendered plane (``normal`` (H, W, 3), ``distance`` (H, W)). Returns the per-
    pixel loss (K, M) in [0, 2] and where it is defined. ``fused``: as in
    :func:`forward_backward_error` (the C++ path takes patches of up to 8×8)."""
    centres = pixels.flip(-1).to(ref_grey.dtype) + 0.5  # (K, M, 2) as (u, v)
    n = normal[pixels[..., 0], pixels[..., 1]]
    d = distance[pixels[..., 0], pixels[..., 1]]
    if patch <= 8 and cpu.fused_here(ref_grey, nbr_greys) if fused is None else fused:
        R, t, intrinsics, ref_intrinsics = _extension_cameras(ref, nbrs, ref_grey.dtype)
        greys = torch.stack([g[..., 0] for g in nbr_greys])
        return _FusedNcc.apply(ref_grey[..., 0], greys, centres, n, d, R, t, intrinsics,
                               (*ref_intrinsics, patch, step))
    half = (patch - 1) / 2 * step
    offs = torch.linspace(-half, half, patch, dtype=ref_grey.dtype, device=ref_grey.device)
    dv, du = torch.meshgrid(offs, offs, indexing="ij")
    uv_ref = centres[..., None, :] + torch.stack([du, dv], -1).reshape(-1, 2)  # (K, M, P, 2)
    # n and d are both blended (scaled by the pixel's alpha): their ratio is the plane's.
    H = plane_homographies(ref, nbrs, n, d.clamp_min(1e-6))
    hom = torch.cat([uv_ref, torch.ones_like(uv_ref[..., :1])], -1) @ H.transpose(-1, -2)
    w = hom[..., 2]
    uv_nbr = hom[..., :2] / torch.where(w.abs() > 1e-8, w, torch.full_like(w, 1e-8))[..., None]
    grey_ref = sample_maps([ref_grey], uv_ref.reshape(1, -1, 2)).reshape(uv_ref.shape[:-1])
    grey_nbr = sample_maps(nbr_greys, uv_nbr)[..., 0]
    a = grey_ref - grey_ref.mean(-1, keepdim=True)
    b = grey_nbr - grey_nbr.mean(-1, keepdim=True)
    cov = (a * b).mean(-1)
    var = (a * a).mean(-1) * (b * b).mean(-1)
    ncc = cov / torch.sqrt(var + 1e-8)
    inside = (nbrs.inside(uv_nbr) & (w > 0)).all(-1)
    defined = inside & (d > 0) & (var > 1e-8)
    return (1 - ncc.clamp(-1, 1)), defined


class _FusedNcc(torch.autograd.Function):
    """:func:`ncc_loss` from the C++ extension; gradients reach the planes (normal, distance)."""

    @staticmethod
    def forward(ctx, ref_grey, nbr_greys, centres, normal, distance, R, t, intrinsics, settings):
        ctx.inputs = (ref_grey, nbr_greys, centres)
        ctx.args = (R, t, intrinsics, *settings)
        ctx.save_for_backward(normal, distance)
        loss, defined = cpu.extension().ncc_forward(ref_grey, nbr_greys, centres, normal.detach(), distance.detach(),
                                                    *ctx.args)
        ctx.mark_non_differentiable(defined)
        return loss, defined

    @staticmethod
    def backward(ctx, grad_loss, _):
        normal, distance = ctx.saved_tensors
        g_normal, g_distance = cpu.extension().ncc_backward(*ctx.inputs, normal.detach(), distance.detach(),
                                                            *ctx.args, grad_loss)
        return None, None, None, g_normal, g_distance, None, None, None, None
