"""Joint stage (``eve3d joint``): train the Gaussians of one method and render its depth.

One loss, whose parts the settings switch on and off; the methods (``eve3d.methods``) are
named settings of it. In full (PGSR): L_rgb, the flattening loss on the smallest scale, the
single-view depth–normal consistency from ``dn_from``, the multi-view geometric and NCC
photometric losses over a rendered neighbour view from ``mv_from``, AbsGS's split, optional
per-image exposure; meshed from the unbiased depth D = d / −(N·r). With the planar and
multi-view parts off and the plain split it is 3DGS, meshed from the expected depth
Σ w z / Σ w.

Writes ``point_cloud.ply``, ``depth/{view}.npz`` (depth, confidence = rendered alpha,
camera-space normal; at the dataset's full resolution, with PNG previews), ``metrics.json``
and ``previews/``.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from eve3d.fileio import atomic_dir, atomic_path
from eve3d.gaussians import GaussianModel
from eve3d.losses import depth_normal_loss, forward_backward_error, geometric_loss, ncc_loss, rgb_loss
from eve3d.maps import save_maps
from eve3d.neighbours import select_neighbours
from eve3d.render import RenderOutput
from eve3d.scene import Eve3dError, Scene
from eve3d.training import Trainer, TrainSettings, View, initial_points

DEPTHS = ("depth", "depth_expected")


@dataclass
class JointSettings(TrainSettings):
    method: str = "pgsr"
    """The method's name (``eve3d.methods``): recorded, and names the progress bar."""
    depth: str = "depth"
    """Depth rendered for meshing: ``depth`` (PGSR's unbiased depth) or ``depth_expected``."""
    scale_weight: float = 100.0
    """Flattening loss: weight × mean(min scale of the visible Gaussians)."""
    dn_weight: float = 0.015
    dn_from: int = 7000
    """First step of the depth–normal consistency loss."""
    mv_from: int = 7000
    """First step of the multi-view losses."""
    geo_weight: float = 0.03
    ncc_weight: float = 0.15
    mv_threshold: float = 1.0
    """Pixels whose forward–backward reprojection error φ is this large (px) are left out."""
    ncc_patch: int = 7
    ncc_pixels: int = 4096
    """Reference pixels per step whose patches enter the NCC loss."""
    neighbours: int = 4
    exposure: bool = False
    """Learn a 3×4 colour transform per training image (PGSR's exposure compensation)."""
    exposure_lr: float = 1e-3
    init_random_points: int = 100_000


def loss_terms(trainer: Trainer, s: JointSettings, neighbours: list[list[int]]):
    """The loss function of the joint stage (see the module docstring)."""
    train_set = set(trainer.train_ids)

    def terms(step: int, view: View, out: RenderOutput) -> dict[str, torch.Tensor]:
        rgb = out.rgb
        if s.exposure:
            e = trainer.extra["exposure"][view.index]
            rgb = rgb @ e[:, :3].T + e[:, 3]
        t = {"rgb": rgb_loss(rgb, view.image, s.ssim_weight)}
        visible = out.visible
        if s.scale_weight and visible.any():
            t["scale"] = s.scale_weight * trainer.model.scales[visible].amin(-1).mean()
        covered = out.alpha.detach() > 0.5
        if step >= s.dn_from and s.dn_weight:
            t["depth_normal"] = s.dn_weight * depth_normal_loss(out.depth, out.normal, view.image, view.cam, covered)
        candidates = [j for j in neighbours[view.index] if j in train_set]
        if step >= s.mv_from and candidates and (s.geo_weight or s.ncc_weight):
            nbr = trainer.views[candidates[int(torch.randint(len(candidates), (1,), generator=trainer.generator))]]
            out_n = trainer.render(nbr, step)
            phi, defined = forward_backward_error(out.depth, out_n.depth, view.cam, nbr.cam)
            geo, valid = geometric_loss(phi, defined & covered, s.mv_threshold)
            t["mv_geo"] = s.geo_weight * geo
            idx = valid.flatten().nonzero().squeeze(1)
            if len(idx) and s.ncc_weight:
                pick = idx[torch.randperm(len(idx), generator=trainer.generator)[:s.ncc_pixels].to(idx.device)]
                pixels = torch.stack([pick // view.cam.width, pick % view.cam.width], -1)
                ncc, ok = ncc_loss(view.image, nbr.image, view.cam, nbr.cam, out.normal, out.distance, pixels,
                                   s.ncc_patch)
                w = torch.exp(-phi.flatten()[pick]).detach() * ok
                t["mv_ncc"] = s.ncc_weight * (ncc * w).sum() / ok.sum().clamp_min(1)
        return t

    return terms


@torch.no_grad()
def export_depths(trainer: Trainer, scene: Scene, out_dir: Path, kind: str) -> None:
    """Render ``kind`` (``depth`` or ``depth_expected``) for every view at full resolution."""
    with atomic_dir(out_dir) as tmp:
        for cam in tqdm(scene.cameras, desc=f"rendering {kind}", unit="view"):
            out = trainer.render(cam)
            normal = torch.nn.functional.normalize(out.normal, dim=-1)
            save_maps(tmp / f"{cam.view_id}.npz", depth=getattr(out, kind).cpu().numpy(),
                      confidence=out.alpha.cpu().numpy(), normal=normal.cpu().numpy())


def train_joint(scene: Scene, out_dir: Path, settings: JointSettings) -> dict:
    """Run the stage for ``settings.method``; returns the metrics it writes."""
    s = settings
    if s.depth not in DEPTHS:
        raise Eve3dError(f"joint.depth: {s.depth!r} is not one of {', '.join(DEPTHS)}")
    out_dir = Path(out_dir)
    trainer = Trainer(scene, s, out_dir, s.method)
    points, colors = initial_points(scene, s.init_random_points, np.random.default_rng(s.seed))
    trainer.set_model(GaussianModel.from_points(points, colors, s.sh_degree))
    if s.exposure:
        trainer.add_extra("exposure", torch.eye(3, 4).repeat(len(trainer.views), 1, 1), s.exposure_lr)
    trainer.run(loss_terms(trainer, s, select_neighbours(scene, s.neighbours)))
    depth_kind = s.depth
    trainer.model.save_ply(out_dir / "point_cloud.ply")
    export_depths(trainer, scene, out_dir / "depth", depth_kind)
    metrics = {"method": s.method, "train": trainer.evaluate(trainer.train_ids),
               "held_out": trainer.evaluate(trainer.test_ids), "gaussians": len(trainer.model),
               "depth": depth_kind, "settings": asdict(s)}
    with atomic_path(out_dir / "train_metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=2, default=str))
    trainer.write_previews(out_dir / "previews", depth=depth_kind)
    trainer.finish()
    return metrics
