"""Pretrain stage (``eve3d pretrain``): a short photometric 3DGS fit in Mini-Splatting's
spirit, whose only job is to render the virtual right views of the stereo stage.

Schedule: 3DGS with aggressive densification (a low gradient threshold, frequent
refinement); at ``reinit_at`` the Gaussians are replaced by points back-projected from the
rendered depth of every training view (Mini-Splatting's depth re-initialisation: an even,
surface-bound layout instead of the clumps densification grows); at ``simplify_at`` only
the Gaussians that carry the most blending weight over the training views are kept
(Mini-Splatting's importance-based simplification). The photos are fitted through one
contrast-limited equalisation curve of the whole scene (``equalize``), so that the right
views it renders carry the faint texture a matcher needs. Writes ``point_cloud.ply``
(standard 3DGS PLY), ``tone_curve.json`` (that curve), ``train_metrics.json`` (PSNR/SSIM of the
held-out views, against the equalised photos) and PNG previews.
"""
from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from eve3d.core.fileio import atomic_path
from eve3d.core.layout import TONE_FILE
from eve3d.core.photos import scene_tone_curve
from eve3d.core.scene import Scene
from eve3d.core.settings import PretrainSettings, RenderSettings
from eve3d.core.timing import phase
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render import RenderOutput, render_model
from eve3d.gaussians.training import LossTerms, Trainer, initial_points, photometric_terms
from eve3d.gaussians.views import View


@torch.no_grad()
def depth_points(trainer: Trainer, count: int, min_alpha: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """``count`` world points (and their photo colours) back-projected from the expected
    depth of the training views, drawn uniformly over the well-covered pixels."""
    pts, cols = [], []
    for i in trainer.views.train_ids:
        view = trainer.views[i]
        out = trainer.render(view)
        ok = (out.alpha > min_alpha) & (out.depth_expected > 0)
        world = view.camera.backproject(out.depth_expected.cpu().numpy().astype(np.float64))
        pts.append(world[ok.cpu().numpy()])
        cols.append(view.image.cpu().numpy()[ok.cpu().numpy()])
    pts, cols = np.concatenate(pts), np.concatenate(cols)
    pick = torch.randperm(len(pts), generator=trainer.generator)[:count].numpy()
    return pts[pick], cols[pick]


@torch.enable_grad()
def blend_weights(model: GaussianModel, views: list[View], rendering: RenderSettings) -> torch.Tensor:
    """(N,) Σ over ``views`` and their pixels of each Gaussian's blending weight w = α·T:
    the gradient of the composited constant channel 1 with respect to that channel."""
    frozen = GaussianModel({k: v.detach() for k, v in model.params.items()}, model.sh_degree)
    device = frozen.params["means"].device
    total = torch.zeros(len(frozen), device=device)
    for view in views:
        ones = torch.ones(len(frozen), 1, device=device, requires_grad=True)
        out = render_model(frozen, view.cam, rendering, colors=torch.zeros(len(frozen), 3, device=device),
                           extras=ones)
        out.extras.sum().backward()
        total += ones.grad[:, 0]
    return total


@dataclass
class PretrainRun:
    """A pretrain stage ready to run: ``trainer.run(loss, events)``."""

    trainer: Trainer
    loss: LossTerms
    events: Callable[[int], None]
    """Re-initialisation and simplification, on their steps."""
    tone: np.ndarray
    """The scene's equalisation curve (256,) the photos are fitted through."""


def setup_pretrain(scene: Scene, out_dir: Path, settings: PretrainSettings) -> PretrainRun:
    """The trainer with its initial Gaussians, the photometric loss and the stage's events."""
    with phase("tone curve"):
        tone = scene_tone_curve(scene, settings.equalize)
    trainer = Trainer(scene, settings, Path(out_dir), "pretrain", tone)
    state, views = trainer.state, trainer.views
    rng = np.random.default_rng(settings.seed)
    with phase("initial Gaussians"):
        points, colors = initial_points(scene, settings.init_random_points, rng, settings.init_drop_isolated)
        if colors is not None:  # the sparse points' photo colours, into the curve's grey levels
            colors = tone[np.round(colors * 255).astype(np.uint8)] / 255.0
        trainer.start_from(points, colors)

    def events(step: int) -> None:
        if step in settings.reinit_at:
            count = settings.reinit_points or len(trainer.model)
            pts, cols = depth_points(trainer, count)
            trainer.start_from(pts, cols)
            print(f"\npretrain: step {step}: re-initialised {len(pts)} Gaussians from rendered depth", file=sys.stderr)
        if step in settings.simplify_at:
            weight = blend_weights(trainer.model, [views[i] for i in views.train_ids], settings)
            keep = max(1, int(round(settings.simplify_keep * len(weight))))
            order = torch.argsort(weight, descending=True)
            drop = torch.ones(len(weight), dtype=torch.bool, device=weight.device)
            drop[order[:keep]] = False
            drop |= weight <= 0
            state.remove_gaussians(drop)
            print(f"\npretrain: step {step}: simplified to {len(trainer.model)} Gaussians", file=sys.stderr)

    def loss(step: int, view: View, out: RenderOutput) -> dict[str, torch.Tensor]:
        return photometric_terms(settings, view, out)

    return PretrainRun(trainer, loss, events, tone)


def pretrain(scene: Scene, out_dir: Path, settings: PretrainSettings) -> dict:
    """Run the stage; returns the held-out metrics (also written to ``train_metrics.json``)."""
    out_dir = Path(out_dir)
    run = setup_pretrain(scene, out_dir, settings)
    trainer, tone = run.trainer, run.tone
    trainer.run(run.loss, run.events)

    def save_tone() -> None:
        with atomic_path(out_dir / TONE_FILE) as tmp:
            tmp.write_text(json.dumps(tone.tolist()))

    def record(scores: dict) -> dict:
        return {"held_out": scores["held_out"], "train": scores["train"], "gaussians": len(trainer.model),
                "iterations": settings.iterations, "resolution": settings.resolution, "settings": asdict(settings)}

    return trainer.finish(out_dir, record, "depth_expected", save_tone)


def run_pretrain(settings: PretrainSettings, *, scene: Path, out: Path) -> None:
    """The ``pretrain`` stage: the posed dataset ``scene`` to a model in ``out``."""
    from eve3d.core.io import load_scene

    with phase("read scene"):
        loaded = load_scene(scene)
    metrics = pretrain(loaded, Path(out), settings)
    held = metrics["held_out"]
    if held:
        print(f"held-out views ({held['views']}): PSNR {held['psnr']:.2f} dB, SSIM {held['ssim']:.4f}")
    print(f"wrote {out}/point_cloud.ply ({metrics['gaussians']} Gaussians)")
