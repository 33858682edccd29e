"""Image and geometry losses of 3DGS and PGSR, in PyTorch (images are (H, W, C) tensors).

Conventions: camera space is OpenCV (x right, y down, z forward); rendered normals face
the camera; a pixel (u, v) has its centre at (u + 0.5, v + 0.5).
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from eve3d.render.projection import CameraTensors


def _gaussian_window(size: int, sigma: float, channels: int, like: torch.Tensor) -> torch.Tensor:
    x = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-x**2 / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, size, size).contiguous()


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of two (H, W, C) images in [0, 1] (3DGS's Gaussian window, zero padding)."""
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    c = x.shape[1]
    w = _gaussian_window(window, sigma, c, x)
    blur = lambda t: F.conv2d(t, w, padding=window // 2, groups=c)  # noqa: E731
    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.mean()


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.detach() - b.detach()) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def rgb_loss(pred: torch.Tensor, gt: torch.Tensor, ssim_weight: float = 0.2) -> torch.Tensor:
    """L_rgb = (1 − λ)·L1 + λ·(1 − SSIM)."""
    return (1 - ssim_weight) * (pred - gt).abs().mean() + ssim_weight * (1 - ssim(pred, gt))


def depth_to_points(depth: torch.Tensor, cam: CameraTensors) -> torch.Tensor:
    """(H, W) camera z → (H, W, 3) camera-space points."""
    return cam.rays() * depth[..., None]


def depth_to_normal(depth: torch.Tensor, cam: CameraTensors, span: int = 1) -> torch.Tensor:
    """(H, W, 3) unit normals facing the camera from central differences of the
    back-projected depth over ±``span`` pixels (a wider span averages out depth noise);
    zero on the ``span``-pixel border."""
    p = depth_to_points(depth, cam)
    k = span
    dx = p[k:-k, 2 * k:] - p[k:-k, :-2 * k]
    dy = p[2 * k:, k:-k] - p[:-2 * k, k:-k]
    n = F.normalize(torch.cross(dy, dx, dim=-1), dim=-1)  # y down × x right faces −z, the camera
    return F.pad(n.permute(2, 0, 1), (k, k, k, k)).permute(1, 2, 0)


def edge_weight(image: torch.Tensor) -> torch.Tensor:
    """(1 − g)² with g the grey-level gradient magnitude normalised to [0, 1] (PGSR):
    the depth–normal loss is relaxed at image edges, where depth may jump."""
    grey = image.mean(-1)
    gx = F.pad(grey[:, 2:] - grey[:, :-2], (1, 1)).abs() / 2
    gy = F.pad(grey[2:] - grey[:-2], (0, 0, 1, 1)).abs() / 2
    g = torch.sqrt(gx**2 + gy**2)
    g = (g - g.min()) / (g.max() - g.min()).clamp_min(1e-8)
    return ((1 - g).clamp(0, 1) ** 2).detach()


def depth_normal_loss(depth: torch.Tensor, normal: torch.Tensor, image: torch.Tensor, cam: CameraTensors,
                      valid: torch.Tensor) -> torch.Tensor:
    """mean((1 − g)² · |N_d − N|₁) over ``valid`` pixels; N is the rendered normal
    (normalised here), N_d the normal of the rendered depth."""
    n_d = depth_to_normal(depth, cam)
    n = F.normalize(normal, dim=-1)
    err = (n_d - n).abs().sum(-1) * edge_weight(image)
    mask = valid & (n_d.norm(dim=-1) > 0)
    return (err * mask).sum() / mask.sum().clamp_min(1)


def relative_pose(ref: CameraTensors, nbr: CameraTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """(R, t) taking reference-camera coordinates to neighbour-camera coordinates."""
    R = nbr.R @ ref.R.T
    return R, nbr.t - R @ ref.t


def _sample(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of (H, W, C) ``image`` at pixel coordinates ``uv`` (..., 2) (pixel
    centres at +0.5); the border value continues outside (callers mask what falls outside)."""
    h, w = image.shape[:2]
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1)
    out = F.grid_sample(image.permute(2, 0, 1)[None], grid.reshape(1, -1, 1, 2), align_corners=False,
                        padding_mode="border")
    return out[0, :, :, 0].T.reshape(*uv.shape[:-1], image.shape[2])


def _project(points: torch.Tensor, cam: CameraTensors) -> tuple[torch.Tensor, torch.Tensor]:
    z = points[..., 2]
    zs = torch.where(z.abs() > 1e-8, z, torch.full_like(z, 1e-8))
    uv = torch.stack([cam.fx * points[..., 0] / zs + cam.cx, cam.fy * points[..., 1] / zs + cam.cy], -1)
    return uv, z


def forward_backward_error(depth_ref: torch.Tensor, depth_nbr: torch.Tensor, ref: CameraTensors,
                           nbr: CameraTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """PGSR's multi-view geometric check. Each reference pixel is back-projected with
    ``depth_ref``, projected into the neighbour, given the neighbour's depth there
    (bilinear), back-projected and projected into the reference again. Returns φ (H, W),
    the pixel distance of that round trip, and whether the round trip was defined."""
    R, t = relative_pose(ref, nbr)
    p_ref = depth_to_points(depth_ref, ref)
    uv_n, z_n = _project(p_ref @ R.T + t, nbr)
    d_n = _sample(depth_nbr[..., None], uv_n)[..., 0]
    back = (nbr.rays_at(uv_n) * d_n[..., None] - t) @ R  # neighbour → reference: Rᵀ (x − t)
    uv_r, z_r = _project(back, ref)
    phi = (uv_r - ref.pixel_centres()).norm(dim=-1)
    inside = (uv_n[..., 0] >= 0) & (uv_n[..., 0] < nbr.width) & (uv_n[..., 1] >= 0) & (uv_n[..., 1] < nbr.height)
    defined = (depth_ref > 0) & (z_n > 0) & (d_n > 0) & (z_r > 0) & inside
    return phi, defined


def geometric_loss(phi: torch.Tensor, defined: torch.Tensor, threshold: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """mean(exp(−φ)·φ) over pixels whose round trip closes within ``threshold`` px (the
    weight is not differentiated); also returns that mask."""
    valid = defined & (phi < threshold)
    w = torch.exp(-phi).detach()
    return (w * phi * valid).sum() / valid.sum().clamp_min(1), valid


def plane_homography(ref: CameraTensors, nbr: CameraTensors, normal: torch.Tensor,
                     distance: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) homographies H = K_n (R − t nᵀ/d) K_r⁻¹ induced by the planes n·x = −d
    (reference camera space, n facing the camera, d > 0; n need not be unit length)."""
    R, t = relative_pose(ref, nbr)
    A = R - t[:, None] * normal[..., None, :] / distance[..., None, None]
    return nbr.K() @ A @ torch.linalg.inv(ref.K())


def ncc_loss(ref_image: torch.Tensor, nbr_image: torch.Tensor, ref: CameraTensors, nbr: CameraTensors,
             normal: torch.Tensor, distance: torch.Tensor, pixels: torch.Tensor, patch: int = 7,
             step: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Photometric multi-view loss 1 − NCC of ``patch``×``patch`` grey patches around the
    reference ``pixels`` (M, 2 integer (row, col)), warped into the neighbour by each
    pixel's rendered plane (``normal`` (H, W, 3), ``distance`` (H, W)). Returns the per-
    pixel loss (M,) in [0, 2] and where it is defined."""
    half = (patch - 1) / 2 * step
    offs = torch.linspace(-half, half, patch, dtype=ref_image.dtype, device=ref_image.device)
    dv, du = torch.meshgrid(offs, offs, indexing="ij")
    centres = pixels.flip(-1).to(ref_image.dtype) + 0.5  # (M, 2) as (u, v)
    uv_ref = centres[:, None, :] + torch.stack([du, dv], -1).reshape(1, -1, 2)  # (M, P, 2)
    n = normal[pixels[:, 0], pixels[:, 1]]
    d = distance[pixels[:, 0], pixels[:, 1]]
    # n and d are both blended (scaled by the pixel's alpha): their ratio is the plane's.
    H = plane_homography(ref, nbr, n, d.clamp_min(1e-6))
    hom = torch.cat([uv_ref, torch.ones_like(uv_ref[..., :1])], -1) @ H.transpose(-1, -2)
    w = hom[..., 2]
    uv_nbr = hom[..., :2] / torch.where(w.abs() > 1e-8, w, torch.full_like(w, 1e-8))[..., None]
    grey_ref = _sample(ref_image.mean(-1, keepdim=True), uv_ref)[..., 0]
    grey_nbr = _sample(nbr_image.mean(-1, keepdim=True), uv_nbr)[..., 0]
    a = grey_ref - grey_ref.mean(-1, keepdim=True)
    b = grey_nbr - grey_nbr.mean(-1, keepdim=True)
    cov = (a * b).mean(-1)
    var = (a * a).mean(-1) * (b * b).mean(-1)
    ncc = cov / torch.sqrt(var + 1e-8)
    inside = ((uv_nbr[..., 0] >= 0) & (uv_nbr[..., 0] < nbr.width) & (uv_nbr[..., 1] >= 0)
              & (uv_nbr[..., 1] < nbr.height) & (w > 0)).all(-1)
    defined = inside & (d > 0) & (var > 1e-8)
    return (1 - ncc.clamp(-1, 1)), defined
