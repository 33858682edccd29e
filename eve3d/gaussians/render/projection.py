"""EWA projection of 3D Gaussians and their PGSR plane parameters, in PyTorch.

Our own code (gsplat's CUDA kernels do the same on a GPU), written to gsplat's rules so
both backends mean the same thing: quaternions (w, x, y, z), normalised here; the
Jacobian's tangent clamped at 1.3 × the half field of view; 0.3 px² added to the 2D
covariance (EWA dilation); Gaussians behind the near plane, with opacity < 1/255 or
outside the image culled; an opacity-aware bounding box (extent min(3.33, √(2 ln(255 o))) σ).
"""
from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

import torch

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.999
T_MIN = 1e-4
EPS2D = 0.3
COMPENSATION_FLOOR = 1e-12
"""Smallest squared opacity compensation (an opacity factor of 1e-6: invisible)."""


@dataclass
class CameraTensors:
    """One pinhole camera as tensors: world-to-camera ``R`` (3, 3), ``t`` (3,), intrinsics."""

    R: torch.Tensor
    t: torch.Tensor
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    _centres: torch.Tensor | None = field(default=None, init=False, repr=False, compare=False)
    _rays: torch.Tensor | None = field(default=None, init=False, repr=False, compare=False)
    _world_rays: torch.Tensor | None = field(default=None, init=False, repr=False, compare=False)
    _memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def from_camera(cls, camera, dtype: torch.dtype = torch.float32, device=None) -> "CameraTensors":
        """From an :class:`eve3d.core.scene.Camera`."""
        K = camera.K
        return cls(torch.as_tensor(camera.R, dtype=dtype, device=device),
                   torch.as_tensor(camera.t, dtype=dtype, device=device).reshape(3),
                   float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   int(camera.width), int(camera.height))

    def viewmat(self) -> torch.Tensor:
        """4×4 world-to-camera matrix."""
        m = torch.eye(4, dtype=self.R.dtype, device=self.R.device)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    def K(self) -> torch.Tensor:
        return torch.tensor([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]],
                            dtype=self.R.dtype, device=self.R.device)

    def pixel_centres(self) -> torch.Tensor:
        """(H, W, 2) pixel-centre coordinates (u + 0.5, v + 0.5); computed once per camera
        (the losses ask for it every step), so never modify it in place."""
        if self._centres is None:
            opts = dict(dtype=self.R.dtype, device=self.R.device)
            v, u = torch.meshgrid(torch.arange(self.height, **opts) + 0.5, torch.arange(self.width, **opts) + 0.5,
                                  indexing="ij")
            self._centres = torch.stack([u, v], -1)
        return self._centres

    def rays_at(self, uv: torch.Tensor) -> torch.Tensor:
        """(..., 3) camera-space rays ((u−cx)/fx, (v−cy)/fy, 1) through pixel coordinates ``uv`` (..., 2)."""
        return torch.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy,
                            torch.ones_like(uv[..., 0])], dim=-1)

    def rays(self) -> torch.Tensor:
        """(H, W, 3) camera-space rays through the pixel centres (computed once, as
        :meth:`pixel_centres`)."""
        if self._rays is None:
            self._rays = self.rays_at(self.pixel_centres())
        return self._rays

    def world_rays(self) -> torch.Tensor:
        """(H, W, 3) the same rays in world coordinates, Rᵀ r (computed once, as :meth:`rays`)."""
        if self._world_rays is None:
            self._world_rays = self.rays() @ self.R
        return self._world_rays

    def memo(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """``compute()``, once per ``key`` for this camera: for what follows from its rays alone.
        A training view's camera lasts the whole run; a one-off camera's values go with it."""
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(N, 4) quaternions (w, x, y, z), any norm → (N, 3, 3) rotation matrices."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def plane_features(means_c: torch.Tensor, rotmats: torch.Tensor, scales: torch.Tensor,
                   R: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """PGSR planes: camera-space normal of the shortest axis, facing the camera, and d = |n·μ|.

    Returns ``normals`` (N, 3) and ``distances`` (N,), with n·μ_c = −d.
    """
    shortest = scales.argmin(dim=-1)
    axis = torch.gather(rotmats, 2, shortest[:, None, None].expand(-1, 3, 1))[..., 0]
    normals = axis @ R.T
    facing = (normals * means_c).sum(-1, keepdim=True)
    normals = torch.where(facing > 0, -normals, normals)
    return normals, -(normals * means_c).sum(-1)


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities (N rows; culled rows have ``radii == 0``)."""

    means2d: torch.Tensor  # (N, 2) pixels
    conics: torch.Tensor  # (N, 3) inverse 2D covariance (a, b, c): σ = ½(a dx² + c dy²) + b dx dy
    depths: torch.Tensor  # (N,) camera z
    radii: torch.Tensor  # (N, 2) int32 half extents of the bounding box in pixels, 0 = culled
    compensation: torch.Tensor  # (N,) √(det Σ2D / det(Σ2D + 0.3 I)): opacity factor of antialiased mode


def project(means_c: torch.Tensor, rotmats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
            cam: CameraTensors, near: float = 0.01, far: float = 1e10) -> Projected:
    """Project Gaussians, given by camera-space centres (N, 3) and world rotation matrices
    (N, 3, 3), into ``cam`` (differentiable in every input)."""
    M = cam.R @ rotmats * scales[:, None, :]  # camera-space R_g S
    cov_c = M @ M.transpose(1, 2)
    x, y, z = means_c.unbind(-1)
    z_safe = torch.where(z > near, z, torch.full_like(z, near))
    # Tangents clamped 30 % of the half field of view beyond the image (as gsplat), so far
    # off-screen Gaussians do not blow up the Jacobian.
    margin_x, margin_y = 0.3 * 0.5 * cam.width / cam.fx, 0.3 * 0.5 * cam.height / cam.fy
    tx = z_safe * torch.clamp(x / z_safe, -(cam.cx / cam.fx + margin_x), (cam.width - cam.cx) / cam.fx + margin_x)
    ty = z_safe * torch.clamp(y / z_safe, -(cam.cy / cam.fy + margin_y), (cam.height - cam.cy) / cam.fy + margin_y)
    zero = torch.zeros_like(z)
    J = torch.stack([cam.fx / z_safe, zero, -cam.fx * tx / z_safe**2,
                     zero, cam.fy / z_safe, -cam.fy * ty / z_safe**2], dim=-1).reshape(-1, 2, 3)
    cov2d = J @ cov_c @ J.transpose(1, 2)
    a = cov2d[:, 0, 0] + EPS2D
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + EPS2D
    det = a * c - b * b
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    det_raw = (a - EPS2D) * (c - EPS2D) - b * b
    # Bounded below so that its gradient stays finite: an edge-on disc whose thin axis has
    # shrunk to ~1e-7 of the others has det_raw = 0 in float32, and √'s slope there is
    # infinite (0 · ∞ = NaN reached the parameters). gsplat bounds the same slope (+1e-6).
    compensation = torch.sqrt(torch.clamp(det_raw / det_safe, min=COMPENSATION_FLOOR))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)
    means2d = torch.stack([cam.fx * x / z_safe + cam.cx, cam.fy * y / z_safe + cam.cy], dim=-1)

    with torch.no_grad():
        o = opacities.clamp_min(ALPHA_MIN)
        extend = torch.sqrt(2.0 * torch.log(o / ALPHA_MIN)).clamp_max(3.33)
        rx = torch.ceil(extend * a.clamp_min(0).sqrt())
        ry = torch.ceil(extend * c.clamp_min(0).sqrt())
        mx, my = means2d[:, 0], means2d[:, 1]
        keep = ((z >= near) & (z <= far) & (det > 0) & (opacities >= ALPHA_MIN) & ((rx > 0) | (ry > 0))
                & (mx + rx > 0) & (mx - rx < cam.width) & (my + ry > 0) & (my - ry < cam.height))
        radii = torch.stack([rx, ry], dim=-1).to(torch.int32) * keep[:, None]
    return Projected(means2d, conics, z, radii, compensation)


def camera_planes(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, cam: CameraTensors
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rotation matrices (N, 3, 3), camera-space centres (N, 3), and PGSR's planes: normals
    (N, 3) and distances (N,) (:func:`plane_features`)."""
    rotmats = quat_to_rotmat(quats)
    means_c = means @ cam.R.T + cam.t
    return (rotmats, means_c, *plane_features(means_c, rotmats, scales, cam.R))


def project_gaussians(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                      cam: CameraTensors, near: float = 0.01, far: float = 1e10, antialiased: bool = False
                      ) -> tuple[Projected, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Everything the rasterisers need per Gaussian, from world-space parameters: the
    projection, the opacities to composite (× compensation when ``antialiased``), and the
    camera-space normals (N, 3) and plane distances (N,).

    The reference (autograd) that the ``cpu`` backend's fused C++ projection reproduces."""
    rotmats, means_c, normals, distances = camera_planes(means, quats, scales, cam)
    proj = project(means_c, rotmats, scales, opacities, cam, near, far)
    return proj, opacities * proj.compensation if antialiased else opacities, normals, distances


def front_to_back(proj: Projected, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices of the visible Gaussians sorted by depth (so that their position in the list
    is the depth rank), and their inclusive pixel boxes (V, 4) x0, y0, x1, y1 (int64): the
    pixels whose centres lie within mean ± radius, clipped to the image."""
    visible = (proj.radii > 0).any(-1).nonzero()[:, 0]
    visible = visible[torch.argsort(proj.depths.detach()[visible], stable=True)]
    means2d = proj.means2d.detach()[visible]
    r = proj.radii[visible].to(means2d.dtype)
    lo = torch.ceil(means2d - r - 0.5).clamp_min(0)
    hi = torch.floor(means2d + r - 0.5)
    hi = torch.minimum(hi, torch.tensor([width - 1, height - 1], dtype=hi.dtype, device=hi.device))
    return visible, torch.cat([lo, hi], dim=1).long()
