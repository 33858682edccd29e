"""CUDA backend: ``gsplat.rasterization`` with our planar features as extra colour channels."""
from __future__ import annotations

import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.timing import step_part
from eve3d.gaussians.render.projection import EPS2D, CameraTensors


@step_part("rasterize")
def rasterize_gsplat(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                     features: torch.Tensor, cam: CameraTensors, near: float, far: float, absgrad: bool,
                     antialiased: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Returns features (H, W, C), alpha (H, W), radii (N, 2), means2d (N, 2), absgrad (N, 2) or None.

    ``absgrad`` is gsplat's ``means2d.absgrad``, which exists only after ``backward``; the
    returned tensor is filled in place then (a hook copies it), so callers see one API.
    """
    try:
        from gsplat import rasterization
    except ImportError as exc:
        raise Eve3dError("render backend 'gsplat' needs gsplat: pip install '.[cuda]'") from exc
    if not means.is_cuda:
        raise Eve3dError("render backend 'gsplat' needs CUDA tensors; use backend 'cpu' on this device")
    image, alpha, info = rasterization(
        means, quats, scales, opacities, features, cam.viewmat()[None], cam.K()[None], cam.width, cam.height,
        near_plane=near, far_plane=far, eps2d=EPS2D, packed=False, absgrad=absgrad,
        rasterize_mode="antialiased" if antialiased else "classic", render_mode="RGB")
    means2d = info["means2d"]  # (1, N, 2): the tensor gsplat differentiates
    if means2d.requires_grad:
        means2d.retain_grad()
    absgrad_buf = None
    if absgrad and means2d.requires_grad:
        absgrad_buf = torch.zeros(means.shape[0], 2, dtype=means.dtype, device=means.device)

        def copy_absgrad(grad, buf=absgrad_buf, src=means2d):
            # gsplat's backward sets src.absgrad before the gradient reaches this hook.
            if getattr(src, "absgrad", None) is not None:
                buf.add_(src.absgrad.reshape(buf.shape))
            return grad

        means2d.register_hook(copy_absgrad)
    return image[0], alpha[0, ..., 0], info["radii"][0], means2d, absgrad_buf
