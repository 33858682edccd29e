"""Differentiable Gaussian rasterisation with PGSR planar outputs, behind one function.

``render`` projects and composites Gaussians from one camera with either backend:

- ``cpu``: our fused projection and tile-based compositing in C++ with OpenMP (compiled on
  first use), float32 or float64.
- ``torch``: our sparse pixel–Gaussian pair rasteriser in plain PyTorch: any device, no
  compiler; the fallback when ``cpu`` cannot be built, and its independent cross-check.
- ``gsplat``: ``gsplat.rasterization`` on CUDA (``pip install .[cuda]``), with the planar
  quantities passed as extra colour channels.

``auto`` picks ``gsplat`` for CUDA tensors when gsplat imports, else ``cpu`` when the
extension builds, else ``torch``. All follow gsplat's rules (see
:mod:`eve3d.gaussians.render.projection`), so they agree.

``render_model`` renders a :class:`~eve3d.gaussians.model.GaussianModel` with a stage's
:class:`~eve3d.core.settings.RenderSettings`; every stage that renders a model (training,
previews, exported depth, the stereo pairs' right views, the nvs protocol) calls it.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera
from eve3d.core.settings import RENDER_BACKENDS, RenderSettings
from eve3d.gaussians.render.projection import CameraTensors, Projected, camera_planes, project_gaussians

if TYPE_CHECKING:
    from eve3d.gaussians.model import GaussianModel


@dataclass
class RenderOutput:
    """What one camera sees. H, W: image size; N: number of Gaussians."""

    rgb: torch.Tensor
    """(H, W, C) colours composited over the background (a colour, or the environment at infinity)."""
    alpha: torch.Tensor
    """(H, W) accumulated opacity 1 − T."""
    normal: torch.Tensor
    """(H, W, 3) alpha-blended camera-space normals (facing the camera; not renormalised)."""
    distance: torch.Tensor
    """(H, W) alpha-blended plane distances d = |n·μ_c|."""
    depth: torch.Tensor
    """(H, W) PGSR's unbiased depth D = distance / −(normal·ray); 0 where undefined."""
    depth_expected: torch.Tensor
    """(H, W) alpha-normalised expected z, Σ w·z / alpha; 0 where alpha = 0."""
    extras: torch.Tensor | None
    """(H, W, E) blended extra channels (no background), when extras were given."""
    environment: torch.Tensor | None
    """(H, W, C) what lies behind each pixel (the environment's image, or the background
    colour); None for a render without colours."""
    radii: torch.Tensor
    """(N, 2) int32 screen-space half extents; 0 for culled Gaussians."""
    means2d: torch.Tensor
    """Projected centres in pixels ((N, 2), or (1, N, 2) from gsplat); see ``means2d_grad``."""
    absgrad: torch.Tensor | None
    """(N, 2) Σ over pixels of |∂L/∂mean2d| (AbsGS), filled by ``backward`` when requested."""
    n_pairs: int | None
    """Pixel–Gaussian pairs composited (cpu and torch backends)."""
    backend: str

    @property
    def means2d_grad(self) -> torch.Tensor | None:
        """(N, 2) ∂L/∂mean2d in pixels after ``backward`` (densification's accumulator)."""
        grad = self.means2d.grad
        return None if grad is None else grad.reshape(-1, 2)

    @property
    def visible(self) -> torch.Tensor:
        """(N,) bool: the Gaussian touched the image."""
        return (self.radii > 0).any(-1)


def render(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
           colors: torch.Tensor, camera: Camera | CameraTensors, *, background: torch.Tensor | None = None,
           extras: torch.Tensor | None = None, backend: str = "auto", absgrad: bool = False,
           antialiased: bool = False, near: float = 0.01, far: float = 1e10,
           max_pairs: int = 4_000_000) -> RenderOutput:
    """Render N Gaussians from one pinhole camera.

    means (N, 3) world centres; quats (N, 4) rotations (w, x, y, z), any norm; scales (N, 3)
    standard deviations (activated); opacities (N,) in [0, 1]; colors (N, C) features
    composited over the background: (C,) one colour (default zeros), or (H, W, C) per pixel
    (an environment's image), as C + (1 − α)·background; extras (N, E) optional further
    channels. ``max_pairs`` bounds the torch backend's pairs per band of rows (memory).
    ``antialiased``: gsplat's antialiased mode (Mip-Splatting's 2D filter): each opacity is
    scaled by √(det Σ2D / det(Σ2D + 0.3 I)), so the 0.3 px² dilation no longer makes small or
    edge-on Gaussians cover more than they should.
    """
    if backend not in RENDER_BACKENDS:
        raise Eve3dError(f"render backend {backend!r} unknown; choose one of {', '.join(RENDER_BACKENDS)}")
    if backend == "auto":
        backend = _auto_backend(means)
    cam = camera if isinstance(camera, CameraTensors) else CameraTensors.from_camera(camera, means.dtype, means.device)
    n_colors = colors.shape[1]
    if background is None:
        background = torch.zeros(n_colors, dtype=means.dtype, device=means.device)
    if backend == "gsplat":  # gsplat projects; only the planes are ours
        _, means_c, normals, distances = camera_planes(means, quats, scales, cam)
        proj, cam_z = None, means_c[:, 2]
    else:
        from eve3d.gaussians.render import cpu

        project = cpu.project if backend == "cpu" else project_gaussians
        proj, opacities, normals, distances = project(means, quats, scales, opacities, cam, near, far, antialiased)
        cam_z = proj.depths
    parts = [colors, normals, distances[:, None], cam_z[:, None]] + ([extras] if extras is not None else [])
    features = torch.cat(parts, dim=1)
    image, alpha, radii, means2d, absgrad_buf, n_pairs = _rasterize(
        backend, proj, means, quats, scales, opacities, features, cam, near, far, absgrad, antialiased, max_pairs)

    background = background.expand(*alpha.shape, n_colors)
    rgb = image[..., :n_colors] + (1 - alpha)[..., None] * background
    normal = image[..., n_colors:n_colors + 3]
    distance = image[..., n_colors + 3]
    z = image[..., n_colors + 4]
    denom = -(normal * cam.rays()).sum(-1)
    defined = denom > 1e-8
    depth = torch.where(defined, distance / torch.where(defined, denom, torch.ones_like(denom)),
                        torch.zeros_like(denom))
    covered = alpha > 1e-8
    depth_expected = torch.where(covered, z / torch.where(covered, alpha, torch.ones_like(alpha)),
                                 torch.zeros_like(alpha))
    return RenderOutput(rgb=rgb, alpha=alpha, normal=normal, distance=distance, depth=depth,
                        depth_expected=depth_expected,
                        extras=image[..., n_colors + 5:] if extras is not None else None,
                        environment=background if n_colors else None,
                        radii=radii, means2d=means2d, absgrad=absgrad_buf, n_pairs=n_pairs, backend=backend)


def _rasterize(backend: str, proj: Projected | None, means: torch.Tensor, quats: torch.Tensor,
               scales: torch.Tensor, opacities: torch.Tensor, features: torch.Tensor, cam: CameraTensors, near: float,
               far: float, absgrad: bool, antialiased: bool, max_pairs: int
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None, int | None]:
    """The backend's part of :func:`render`: composited features (H, W, F), alpha (H, W),
    radii, the 2D means (their gradient retained), the AbsGS buffer and the pair count.
    ``cpu`` and ``torch`` get the projection ``proj`` and the opacities to composite (already
    × compensation when ``antialiased``); gsplat projects itself."""
    if proj is not None:
        from eve3d.gaussians.render import cpu, pairs

        means2d = proj.means2d
        if means2d.requires_grad:
            means2d.retain_grad()
        absgrad_buf = torch.zeros_like(means2d.detach()) if absgrad else None
        if backend == "cpu":
            image, alpha, n_pairs = cpu.rasterize(proj, opacities, features, cam.width, cam.height, absgrad_buf)
        else:
            image, alpha, n_pairs = pairs.rasterize(proj, opacities, features, cam.width, cam.height, absgrad_buf,
                                                    max_pairs)
        return image, alpha, proj.radii, means2d, absgrad_buf, n_pairs
    from eve3d.gaussians.render.cuda import rasterize_gsplat

    image, alpha, radii, means2d, absgrad_buf = rasterize_gsplat(
        means, quats, scales, opacities, features, cam, near, far, absgrad, antialiased)
    return image, alpha, radii, means2d, absgrad_buf, None


def render_model(model: GaussianModel, camera: Camera | CameraTensors, rendering: RenderSettings,
                 sh_degree: int | None = None, *, colors: torch.Tensor | None = None, geometry_only: bool = False,
                 fit_environment: torch.Tensor | None = None, **kw) -> RenderOutput:
    """Render ``model`` from ``camera`` as ``rendering`` says (background, backend,
    antialiasing): the one way every stage renders a model, so a trained model renders
    elsewhere (the right views, the depth maps, the nvs protocol) as it was trained. Behind
    the Gaussians lies the model's environment at infinity when it has one, else
    ``rendering.background``.

    Colours: the model's SH up to ``sh_degree`` (default: all) seen from the camera centre,
    unless ``colors`` (N, C) are given. A :class:`Camera` gives its centre from its float64
    pose; the training views' :class:`CameraTensors` from their own R and t (−Rᵀt).
    ``geometry_only``: no colours at all (``rgb`` is (H, W, 0)), for a render whose depth,
    normals and alpha are all that is used (PGSR's neighbour view): no SH evaluation, three
    channels fewer to composite and differentiate. ``kw`` goes to :func:`render`
    (``extras``, ``absgrad``, ...). ``fit_environment`` (H, W) bool: the pixels through
    which a loss fits the environment; the others see it without a gradient to it."""
    p = model.params
    means = p["means"]
    if isinstance(camera, CameraTensors):
        centre = -camera.R.T @ camera.t
    else:  # the centre from the float64 pose
        centre = torch.tensor(camera.center, dtype=means.dtype, device=means.device)
        camera = CameraTensors.from_camera(camera, means.dtype, means.device)
    if geometry_only:
        colors, background = means.new_zeros(len(model), 0), means.new_zeros(0)
    else:
        if colors is None:
            colors = model.colors(centre, sh_degree)
        background = torch.tensor(rendering.background, dtype=means.dtype, device=means.device)
    environment = model.environment if colors.shape[1] == 3 else None
    if environment is not None:
        background = background.new_zeros(3)  # composited below, where the Gaussians leave it seen
    out = render(means, p["quats"], model.scales, model.opacities, colors, camera, background=background,
                 backend=rendering.backend, antialiased=rendering.antialiased, **kw)
    if environment is None:
        return out
    behind = environment.behind(camera, out.alpha, fit_environment)
    return replace(out, rgb=out.rgb + (1 - out.alpha)[..., None] * behind, environment=behind)


def _auto_backend(means: torch.Tensor) -> str:
    if means.is_cuda:
        try:
            import gsplat  # noqa: F401

            return "gsplat"
        except ImportError:
            return "torch"
    from eve3d.gaussians.render import cpu

    return "cpu" if cpu.available() else "torch"
