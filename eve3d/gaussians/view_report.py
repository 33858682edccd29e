"""How a model looks from a scene's views: PSNR and SSIM against the photos, and PNG
previews, so that the training stages and the nvs protocol score and show a model alike."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from eve3d.core.fileio import write_image
from eve3d.core.maps import preview_image
from eve3d.core.settings import RenderSettings
from eve3d.gaussians.losses import psnr, ssim
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render import render_model
from eve3d.gaussians.views import Views


@torch.no_grad()
def view_metrics(model: GaussianModel, views: Views, ids: list[int], rendering: RenderSettings,
                 side_by_side: Path | None = None) -> dict[str, float]:
    """Mean PSNR and SSIM of the views ``ids`` rendered at full SH degree (empty without
    views); with ``side_by_side``, each view's render | photo as ``{view}.png`` there."""
    ps, ss = [], []
    for i in ids:
        out = render_model(model, views[i].cam, rendering)
        rgb = out.rgb.clamp(0, 1)
        if side_by_side is not None:
            pair = (torch.cat([rgb, views[i].image], 1).cpu().numpy() * 255).round().astype(np.uint8)
            write_image(side_by_side / f"{views[i].camera.view_id}.png", pair)
        ps.append(psnr(rgb, views[i].image))
        ss.append(float(ssim(rgb, views[i].image)))
    return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "views": len(ids)} if ids else {}


@torch.no_grad()
def write_previews(model: GaussianModel, views: Views, rendering: RenderSettings, count: int, out_dir: Path,
                   depth: str = "depth") -> None:
    """``{view}.rgb.png`` (render | photo), ``{view}.depth.png`` (the ``depth`` output),
    ``{view}.normal.png`` for ``count`` views spread over the scene: to see at a glance what
    a stage made."""
    n = min(count, len(views))
    for i in np.linspace(0, len(views) - 1, n).round().astype(int) if n else []:
        view = views[int(i)]
        out = render_model(model, view.cam, rendering)
        stem = view.camera.view_id
        rgb = (torch.cat([out.rgb.clamp(0, 1), view.image], 1).cpu().numpy() * 255).round().astype(np.uint8)
        write_image(out_dir / f"{stem}.rgb.png", rgb)
        d = getattr(out, depth) * (out.alpha > 0.5)
        write_image(out_dir / f"{stem}.depth.png", preview_image("depth", d.cpu().numpy()))
        normal = torch.nn.functional.normalize(out.normal, dim=-1) * (out.alpha[..., None] > 0.5)
        write_image(out_dir / f"{stem}.normal.png", preview_image("normal", normal.cpu().numpy()))
