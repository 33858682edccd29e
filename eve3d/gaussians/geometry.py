"""Camera geometry in PyTorch for the training losses and the priors: cameras as batched
tensors, relative poses, depth to points and normals, plane-induced homographies and
bilinear lookups of per-view maps.

Conventions: camera space is OpenCV (x right, y down, z forward); normals face the camera;
a pixel (u, v) has its centre at (u + 0.5, v + 0.5).
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from eve3d.gaussians.render import cpu
from eve3d.gaussians.render.projection import CameraTensors


def depth_to_points(depth: torch.Tensor, cam: CameraTensors) -> torch.Tensor:
    """(H, W) camera z → (H, W, 3) camera-space points."""
    return cam.rays() * depth[..., None]


def depth_to_normal(depth: torch.Tensor, cam: CameraTensors, span: int = 1, fused: bool | None = None
                    ) -> torch.Tensor:
    """(H, W, 3) unit normals facing the camera from central differences of the
    back-projected depth over ±``span`` pixels (a wider span averages out depth noise);
    zero on the ``span``-pixel border.

    ``fused``: in one pass of the C++ extension (``csrc/losses.cpp``, an analytic backward
    for the depth), which by default it is in training (a CPU depth that needs a gradient,
    an extension that builds: stages that never render do not build it for this); else the
    PyTorch operations below (the reference)."""
    if depth.requires_grad and cpu.fused_here(depth) if fused is None else fused:
        return _DepthNormal.apply(depth, cam.rays(), span)
    p = depth_to_points(depth, cam)
    k = span
    dx = p[k:-k, 2 * k:] - p[k:-k, :-2 * k]
    dy = p[2 * k:, k:-k] - p[:-2 * k, k:-k]
    n = F.normalize(torch.cross(dy, dx, dim=-1), dim=-1)  # y down × x right faces −z, the camera
    return F.pad(n, (0, 0, k, k, k, k))  # (H, W, 3) in memory too: a reduction over the last axis is far faster


class _DepthNormal(torch.autograd.Function):
    @staticmethod
    def forward(ctx, depth, rays, span):
        ctx.save_for_backward(depth, rays)
        ctx.span = span
        return cpu.extension().depth_normal_forward(depth.detach(), rays, span)

    @staticmethod
    def backward(ctx, grad):
        depth, rays = ctx.saved_tensors
        return cpu.extension().depth_normal_backward(depth.detach(), rays, ctx.span, grad), None, None


class CameraStack:
    """K pinhole cameras as batched tensors, for the multi-view terms of one reference view
    against K neighbours at once (a few large tensor operations instead of K times as many
    small ones). Broadcasts against (K, ..., 2) pixel coordinates."""

    def __init__(self, cams: Sequence[CameraTensors]):
        opts = dict(dtype=cams[0].R.dtype, device=cams[0].R.device)
        self.R = torch.stack([c.R for c in cams])  # (K, 3, 3)
        self.t = torch.stack([c.t for c in cams])  # (K, 3)
        self.focal = torch.tensor([[c.fx, c.fy] for c in cams], **opts)  # (K, 2)
        self.centre = torch.tensor([[c.cx, c.cy] for c in cams], **opts)  # (K, 2)
        self.size = torch.tensor([[c.width, c.height] for c in cams], **opts)  # (K, 2)

    def __len__(self) -> int:
        return len(self.R)

    def per_camera(self, x: torch.Tensor, ndim: int) -> torch.Tensor:
        """(K, C) → (K, 1, …, 1, C), to broadcast against (K, …, C) with ``ndim`` dims."""
        return x.reshape(len(self), *([1] * (ndim - 2)), x.shape[-1])

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(K, ..., 3) points in each camera's frame → pixel coordinates (K, ..., 2) and z."""
        z = points[..., 2:]
        zs = torch.where(z.abs() > 1e-8, z, torch.full_like(z, 1e-8))
        n = points.dim()
        return self.per_camera(self.focal, n) * points[..., :2] / zs + self.per_camera(self.centre, n), z[..., 0]

    def rays_at(self, uv: torch.Tensor) -> torch.Tensor:
        """(K, ..., 3) camera-space rays through pixel coordinates (K, ..., 2)."""
        n = uv.dim()
        xy = (uv - self.per_camera(self.centre, n)) / self.per_camera(self.focal, n)
        return torch.cat([xy, torch.ones_like(xy[..., :1])], -1)

    def inside(self, uv: torch.Tensor) -> torch.Tensor:
        """(K, ...) whether pixel coordinates (K, ..., 2) fall inside each camera's image."""
        return ((uv >= 0) & (uv < self.per_camera(self.size, uv.dim()))).all(-1)

    def K(self) -> torch.Tensor:
        """(K, 3, 3) intrinsic matrices."""
        k = torch.zeros(len(self), 3, 3, dtype=self.R.dtype, device=self.R.device)
        k[:, 0, 0], k[:, 1, 1] = self.focal[:, 0], self.focal[:, 1]
        k[:, :2, 2], k[:, 2, 2] = self.centre, 1
        return k


def relative_poses(ref: CameraTensors, nbrs: CameraStack) -> tuple[torch.Tensor, torch.Tensor]:
    """(R (K, 3, 3), t (K, 3)) taking reference-camera coordinates to each neighbour's."""
    R = nbrs.R @ ref.R.T
    return R, nbrs.t - R @ ref.t


def reproject(depth: torch.Tensor, ref: CameraTensors, nbrs: CameraStack) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each pixel of a reference depth map (H, W) lands in K neighbours: it is
    back-projected and projected into each. Returns pixel coordinates (K, HW, 2) and the
    depth in each neighbour's frame (K, HW)."""
    R, t = relative_poses(ref, nbrs)
    return nbrs.project(depth_to_points(depth, ref).reshape(1, -1, 3) @ R.transpose(1, 2) + t[:, None])


def sample_maps(maps: Sequence[torch.Tensor], uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of K (H, W, C) ``maps`` at pixel coordinates ``uv`` (K, ..., 2), map
    k at uv[k] (pixel centres at +0.5); the border value continues outside (callers mask
    what falls outside). Returns (K, ..., C)."""
    k, c = len(maps), maps[0].shape[2]
    if any(m.shape != maps[0].shape for m in maps):  # sizes differ: one map at a time
        return torch.cat([sample_maps([m], p[None]) for m, p in zip(maps, uv)])
    h, w = maps[0].shape[:2]
    grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1).reshape(k, -1, 1, 2)
    images = torch.stack(list(maps)).permute(0, 3, 1, 2)
    out = F.grid_sample(images, grid, align_corners=False, padding_mode="border")  # (K, C, L, 1)
    return out[..., 0].transpose(1, 2).reshape(*uv.shape[:-1], c)


def plane_homographies(ref: CameraTensors, nbrs: CameraStack, normal: torch.Tensor,
                       distance: torch.Tensor) -> torch.Tensor:
    """(K, M, 3, 3) homographies H = K_n (R − t nᵀ/d) K_r⁻¹ into each neighbour k induced by
    the planes n·x = −d (``normal`` (K, M, 3), ``distance`` (K, M), reference camera space,
    n facing the camera, d > 0; n need not be unit length)."""
    R, t = relative_poses(ref, nbrs)
    A = R[:, None] - t[:, None, :, None] * normal[..., None, :] / distance[..., None, None]
    return nbrs.K()[:, None] @ A @ torch.linalg.inv(ref.K())
