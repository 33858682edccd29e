"""The ``nvs`` protocol: novel views, the Mip-NeRF 360 convention.

Every 8th view (index % 8 == 0) is held out of training (the workflow sets
``joint.holdout`` for scenes with this protocol); the trained Gaussians are rendered from
those views at the training resolution, with the training's rasterisation settings (read
from ``train_metrics.json`` beside the model), and scored by PSNR and SSIM against the
photos (resized with an area filter, as in training). Each held-out view's render | photo is
written as ``held_out/{view}.png`` beside the metrics.
"""
from __future__ import annotations

import json

from eve3d.core.errors import Eve3dError
from eve3d.core.layout import HELD_OUT_DIR, TRAIN_METRICS_FILE
from eve3d.evaluate.protocol import EvalInputs, Protocol

HOLDOUT = 8
"""Every 8th view is held out (Mip-NeRF 360's convention)."""

RENDER_KEYS = ("resolution", "max_side", "background", "antialiased", "backend", "device")
"""Training settings that change what a view renders to."""


def evaluate_views(inputs: EvalInputs) -> dict:
    """PSNR and SSIM of the held-out views (module docstring)."""
    from eve3d.core.settings import TrainSettings
    from eve3d.gaussians.model import GaussianModel
    from eve3d.gaussians.view_report import view_metrics
    from eve3d.gaussians.views import Views, pick_device

    model_path = inputs.reconstruction
    record = model_path.parent / TRAIN_METRICS_FILE
    try:
        trained = json.loads(record.read_text())["settings"]
    except (OSError, ValueError, KeyError) as e:
        raise Eve3dError(f"{record}: the nvs protocol reads the training settings from here ({e})") from None
    if trained.get("holdout") != HOLDOUT:
        raise Eve3dError(f"{model_path}: trained with holdout {trained.get('holdout')}, so the views the nvs protocol "
                         f"scores (every {HOLDOUT}th) were training views; train with joint.holdout: {HOLDOUT} "
                         f"(the workflow does so for scenes with protocol: nvs)")
    render = {k: tuple(v) if isinstance(v, list) else v for k, v in trained.items() if k in RENDER_KEYS}
    settings = TrainSettings(holdout=HOLDOUT, **render)
    device = pick_device(settings.device)
    views = Views.load(inputs.scene, settings, HOLDOUT, device)
    model = GaussianModel.load_ply(model_path).to(device)
    held = view_metrics(model, views, views.test_ids, settings, inputs.out.parent / HELD_OUT_DIR)
    return {**held, "resolution": settings.resolution, "max_side": settings.max_side, "holdout": HOLDOUT}


PROTOCOL = Protocol("nvs", f"held-out views (every {HOLDOUT}th, Mip-NeRF 360): PSNR and SSIM of the rendered "
                    "model", "model", evaluate_views, joint_settings={"holdout": HOLDOUT})
