"""Joint stage (``eve3d joint``): train the Gaussians of one method and render its depth.

One loss, whose parts the settings switch on and off; the methods (``eve3d.core.methods``) are
named settings of it. In full (PGSR): L_rgb, the flattening loss on the smallest scale, the
single-view depth–normal consistency from ``dn_from``, the multi-view geometric and NCC
photometric losses over a rendered neighbour view from ``mv_from``, AbsGS's split, optional
per-image exposure; meshed from the unbiased depth D = d / −(N·r). With the planar and
multi-view parts off and the plain split it is 3DGS, meshed from the expected depth
Σ w z / Σ w.

Writes ``point_cloud.ply``, ``depth/{view}.npz`` (depth, confidence = rendered alpha,
camera-space normal; at the dataset's full resolution, with PNG previews),
``train_metrics.json``, ``previews/`` and, for learnable priors, ``priors/`` (the final D̂).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir, atomic_path, write_image
from eve3d.core.layout import DEPTH_DIR, MODEL_FILE, PREVIEWS_DIR, PRIORS_DIR, RECORD, TRAIN_METRICS_FILE, TRAINING
from eve3d.core.maps import save_maps
from eve3d.core.methods import uses_priors
from eve3d.core.scene import Scene
from eve3d.core.settings import JointSettings, RenderSettings
from eve3d.core.timing import phase
from eve3d.gaussians.geometry import CameraStack, depth_to_normal, depth_to_points
from eve3d.gaussians.losses import (depth_confirmation, depth_normal_loss, forward_backward_error, geometric_loss,
                                    ncc_loss, rgb_loss)
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.neighbours import select_neighbours
from eve3d.gaussians.render import RenderOutput, render_model
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.gaussians.train_state import TrainState
from eve3d.gaussians.training import LossTerms, Trainer, initial_points
from eve3d.gaussians.view_report import view_metrics, write_previews
from eve3d.gaussians.views import View, Views
from eve3d.priors.learnable import Priors, comparison_preview, filled_log_depth, load_priors, prior_points


def multiview_terms(ref: View, nbrs: list[View], depth: torch.Tensor, normal: torch.Tensor, distance: torch.Tensor,
                    nbr_depths: list[torch.Tensor], mask: torch.Tensor, s: JointSettings, generator: torch.Generator,
                    with_ncc: bool = True
                    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor] | None, torch.Tensor]:
    """PGSR's multi-view terms of one reference against K neighbours at once, shared by
    PGSR's loss (one neighbour, its depth rendered) and Eve3D's LBA (K neighbours, their
    priors D̂_n). ``depth``, ``normal`` and ``distance`` are the reference's depth and plane
    (rendered, or of the reference prior). Per neighbour k (tensors of shape (K,)): the
    geometric term mean(exp(−φ)·φ) over the pixels of ``mask`` whose forward–backward error
    φ is below ``mv_threshold``; the photometric term 1 − NCC of ``ncc_patch`` patches
    warped by the plane-induced homography at ``ncc_pixels`` of those pixels drawn at random,
    as the sum of its exp(−φ)-weighted values and the count of pixels where it is defined
    (None when no pixel is drawn); and (K, H, W) the pixels whose round trip is defined and
    closes within ``mv_threshold`` (whatever ``mask``)."""
    cams = CameraStack([n.cam for n in nbrs])
    phi, defined = forward_backward_error(depth, nbr_depths, ref.cam, cams)
    geo, valid = geometric_loss(phi, defined & mask, s.mv_threshold)
    ncc_term = None
    if with_ncc:  # (sum, count) apart: PGSR scales the sum before dividing
        picks = [idx[torch.randperm(len(idx), generator=generator)[:s.ncc_pixels].to(idx.device)]
                 for idx in (v.flatten().nonzero().squeeze(1) for v in valid)]
        drawn = max(len(p) for p in picks)
        if drawn:  # each neighbour's draw, padded to the longest with pixel 0 (not counted)
            pick = torch.zeros(len(nbrs), drawn, dtype=torch.long, device=depth.device)
            counted = torch.zeros(len(nbrs), drawn, dtype=torch.bool, device=depth.device)
            for k, p in enumerate(picks):
                pick[k, :len(p)], counted[k, :len(p)] = p, True
            pixels = torch.stack([pick // ref.cam.width, pick % ref.cam.width], -1)
            ncc, ok = ncc_loss(ref.grey, [n.grey for n in nbrs], ref.cam, cams, normal, distance, pixels,
                               s.ncc_patch)
            ok = ok & counted
            w = torch.exp(-phi.flatten(1).gather(1, pick)).detach() * ok
            ncc_term = (ncc * w).sum(-1), ok.sum(-1).clamp_min(1)
    return geo, ncc_term, defined & (phi < s.mv_threshold)


def prior_plane(depth: torch.Tensor, view: View, span: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Normal (from the depth's finite differences over ±``span`` pixels, facing the camera;
    0 on the border) and plane distance d = −N·X of a depth map, for the homography of a
    prior reference."""
    normal = depth_to_normal(depth, view.cam, span)
    return normal, -(normal * depth_to_points(depth, view.cam)).sum(-1)


class PriorState:
    """The priors inside training: D*, the confidence M^c (a checkpointed buffer) and, for
    ``priors: learnable``, the log-depth D̂ of every view as its own parameter."""

    def __init__(self, state: TrainState, views: Views, priors: Priors, s: JointSettings):
        self.views, self.s, self.star = views, s, priors
        self.confidence = [state.add_buffer(f"prior_confidence/{i}", c.clone())
                           for i, c in enumerate(priors.confidence)]
        self.learnable = s.priors == "learnable"
        self.blank = {i for i, d in enumerate(priors.depth) if not (d > 0).any()}
        """Views without any prior depth: nobody's LBA neighbour (their D̂ is a constant)."""
        self.log_depth = []
        if self.learnable:  # a blank view's D̂ starts at the median of the other views' median depths
            typical = float(torch.stack([d[d > 0].median() for i, d in enumerate(priors.depth)
                                         if i not in self.blank]).median()) if self.blank else 1.0
            self.log_depth = [state.add_extra(f"prior_log_depth/{i}", filled_log_depth(d, typical), s.prior_lr)
                              for i, d in enumerate(priors.depth)]

    def depth(self, i: int) -> torch.Tensor:
        """D̂_i (learnable) or D*_i (fixed)."""
        return torch.exp(self.log_depth[i]) if self.learnable else self.star.depth[i]

    def trusted(self, i: int) -> torch.Tensor:
        """D_prior,i where M^c_i trusts it, 0 elsewhere: how a neighbour's prior enters the
        LBA, so that a pixel the stereo never measured, or the check refuted, confirms nothing."""
        return torch.where(self.confidence[i], self.depth(i), torch.zeros_like(self.depth(i)))

    @torch.no_grad()
    def update_confidence(self, i: int, neighbours: list[View]) -> None:
        """M^c_i ← the stereo's own confidence in D*_i (never more), where D_prior,i is
        confirmed by at least ``consistent_views`` neighbours' priors on pixels the stereo
        measured there (within ``confirm_depth``) and by the photos of at least
        ``confirm_photos`` neighbours (NCC ≥ ``confirm_ncc``; textureless windows pass). The
        neighbours count by what their stereo measured, not by their own M^c: a check against
        checked pixels would shrink from view to view, whatever the priors' quality."""
        s = self.s
        if not neighbours:
            self.confidence[i].zero_()
            return
        view = self.views[i]
        agrees, ncc, flat = depth_confirmation(
            self.depth(i), view.grey, view.cam, CameraStack([n.cam for n in neighbours]),
            [self.depth(n.index) for n in neighbours], [self.star.confidence[n.index] for n in neighbours],
            [n.grey for n in neighbours], s.confirm_depth)
        confirmed = agrees.sum(0) >= s.consistent_views
        if s.confirm_photos:
            confirmed &= flat | ((ncc >= s.confirm_ncc).sum(0) >= s.confirm_photos)
        self.confidence[i].copy_(self.star.confidence[i] & confirmed)


@torch.no_grad()
def on_prior_surface(model: GaussianModel, view: View, priors: PriorState, margin: float) -> torch.Tensor:
    """(N,) bool: the Gaussians whose centre projects into ``view`` onto a pixel where the
    prior is confident and lies within ``margin`` × its depth of the centre's depth."""
    cam = view.cam
    uv, z = (x[0] for x in CameraStack([cam]).project((model.params["means"] @ cam.R.T + cam.t)[None]))
    u, v = torch.floor(uv).long().unbind(-1)
    inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    u, v = u.clamp(0, cam.width - 1), v.clamp(0, cam.height - 1)
    depth = priors.depth(view.index)[v, u]
    return inside & priors.confidence[view.index][v, u] & ((z - depth).abs() <= margin * depth)


def loss_terms(trainer: Trainer, s: JointSettings, neighbours: list[list[int]], priors: PriorState | None = None,
               exposure: torch.Tensor | None = None) -> LossTerms:
    """The loss function of the joint stage (see the module docstring). ``exposure``: the
    (views, 3, 4) affine colour correction of each view, when ``s.exposure``."""
    train_set = set(trainer.views.train_ids)

    def terms(step: int, view: View, out: RenderOutput) -> dict[str, torch.Tensor]:
        rgb = out.rgb
        if s.exposure:
            e = exposure[view.index]
            rgb = rgb @ e[:, :3].T + e[:, 3]
        t = {"rgb": rgb_loss(rgb, view.image, s.ssim_weight)}
        visible = out.visible
        if s.scale_weight and visible.any():
            t["scale"] = s.scale_weight * trainer.model.scales[visible].amin(-1).mean()
        lowering = not s.opacity_while_densifying or step < s.densify.refine_stop
        if s.opacity_weight and lowering and visible.any():
            lowered = visible
            if priors is not None and s.opacity_spare:
                lowered = visible & ~on_prior_surface(trainer.model, view, priors, s.opacity_spare)
            # per visible Gaussian, the same push whether or not some are spared
            t["opacity"] = s.opacity_weight * trainer.model.opacities[lowered].sum() / visible.sum()
        covered = out.alpha.detach() > 0.5
        if step >= s.dn_from and s.dn_weight:
            t["depth_normal"] = s.dn_weight * depth_normal_loss(out.depth, out.normal, view.image, view.cam, covered)
        candidates = [j for j in neighbours[view.index] if j in train_set]
        if step >= s.mv_from and candidates and (s.geo_weight or s.ncc_weight):
            nbr = trainer.views[candidates[int(torch.randint(len(candidates), (1,), generator=trainer.generator))]]
            out_n = trainer.render(nbr, step, geometry_only=True)  # only its depth is used
            geo, ncc, _ = multiview_terms(view, [nbr], out.depth, out.normal, out.distance, [out_n.depth], covered,
                                          s, trainer.generator, with_ncc=bool(s.ncc_weight))
            t["mv_geo"] = s.geo_weight * geo[0]
            if ncc is not None:
                t["mv_ncc"] = s.ncc_weight * ncc[0][0] / ncc[1][0]
        if priors is not None and step >= s.prior_from:
            t.update(prior_terms(step, view, out, covered, [trainer.views[j] for j in candidates], priors, s,
                                 trainer.generator))
        return t

    return terms


def prior_terms(step: int, view: View, out: RenderOutput, covered: torch.Tensor, neighbours: list[View],
                priors: PriorState, s: JointSettings, generator: torch.Generator) -> dict[str, torch.Tensor]:
    """Eve3D's terms (DESIGN §3). Before T_joint (``joint_from``): L_prior towards the fixed
    D*, and the LBA among the priors (reference D̂_i against the neighbours' D̂_n: a
    consistent initialisation). From T_joint: L_prior towards D̂_i, L_pull of D̂_i towards
    the rendered depth where M^c is not confident, and the LBA of the rendered depth
    against the neighbours' D̂_n (no neighbour is rendered); gradients reach the
    Gaussians and every D̂ involved. Each visit first re-checks M^c_i
    (``PriorState.update_confidence``) when the LBA is on."""
    t: dict[str, torch.Tensor] = {}
    i, joint = view.index, step >= s.joint_from
    neighbours = [n for n in neighbours if n.index not in priors.blank][:s.neighbours]
    if s.lba_weight:  # the multi-view check is the LBA's: without it M^c stays the stereo's
        priors.update_confidence(i, neighbours)
    confident = priors.confidence[i] & covered
    target = priors.depth(i) if joint else priors.star.depth[i]
    if s.prior_weight and confident.any():
        target_normal = depth_to_normal(target, view.cam, s.prior_normal_span) if joint else priors.star.normal[i]
        normal = torch.nn.functional.normalize(out.normal, dim=-1)
        depth_term = ((target - out.depth).abs() * confident).sum() / confident.sum()
        on_normal = confident & (target_normal.norm(dim=-1) > 0)
        normal_term = ((1 - (target_normal * normal).sum(-1)) * on_normal).sum() / on_normal.sum().clamp_min(1)
        t["prior"] = s.prior_weight * (depth_term + s.prior_normal_weight * normal_term)
    unconfident = ~priors.confidence[i] & covered
    if priors.learnable and joint and s.pull_weight and unconfident.any():
        pull = (priors.depth(i) - out.depth.detach()).abs() * unconfident
        t["pull"] = s.pull_weight * pull.sum() / unconfident.sum()
    if s.lba_weight and neighbours and (joint or priors.learnable):
        if joint:  # the rendered depth and plane against the neighbours' priors
            depth, normal, distance, mask = out.depth, out.normal, out.distance, covered
        else:  # the confident priors among themselves
            depth = priors.depth(i)
            normal, distance = prior_plane(depth, view, s.prior_normal_span)
            mask = priors.confidence[i] & (normal.norm(dim=-1) > 0)
        geo, ncc, _ = multiview_terms(view, neighbours, depth, normal, distance,
                                      [priors.trusted(n.index) for n in neighbours], mask, s, generator)
        total = geo.sum() + (0.0 if ncc is None else (ncc[0] / ncc[1]).sum())
        t["lba"] = s.lba_weight * total / len(neighbours)
    return t


@torch.no_grad()
def export_priors(trainer: Trainer, scene: Scene, priors: PriorState, out_dir: Path, kind: str) -> None:
    """The final D̂ of every view at the dataset's resolution (``{view}.npz``: depth, the
    updated confidence, normal; PNG previews), and ``{view}.compare.png``: D* | D̂ | the
    rendered depth at the training resolution, under one colour scale."""
    import cv2

    with atomic_dir(out_dir) as tmp:
        for view, cam in zip(trainer.views, tqdm(scene.cameras, desc="exporting priors", unit="view")):
            small = priors.depth(view.index).cpu().numpy()
            depth = cv2.resize(small, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
            conf = priors.confidence[view.index].cpu().numpy().astype(np.uint8)
            conf = cv2.resize(conf, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST).astype(np.float32)
            normal = depth_to_normal(torch.from_numpy(depth), CameraTensors.from_camera(cam)).numpy()
            save_maps(tmp / f"{cam.view_id}.npz", depth=depth, confidence=conf, normal=normal)
            rendered = getattr(trainer.render(view), kind).cpu().numpy()
            write_image(tmp / f"{cam.view_id}.compare.png",
                        comparison_preview(priors.star.depth[view.index].cpu().numpy(), small, rendered))


@torch.no_grad()
def export_depths(model: GaussianModel, scene: Scene, rendering: RenderSettings, out_dir: Path, kind: str) -> None:
    """Render ``kind`` (``depth`` or ``depth_expected``) for every view at full resolution:
    the depth maps the mesh is fused from."""
    with atomic_dir(out_dir) as tmp:
        for cam in tqdm(scene.cameras, desc=f"rendering {kind}", unit="view"):
            out = render_model(model, cam, rendering)
            normal = torch.nn.functional.normalize(out.normal, dim=-1)
            save_maps(tmp / f"{cam.view_id}.npz", depth=getattr(out, kind).cpu().numpy(),
                      confidence=out.alpha.cpu().numpy(), normal=normal.cpu().numpy())


@dataclass
class JointRun:
    """A joint stage ready to run: ``trainer.run(loss)``."""

    trainer: Trainer
    loss: LossTerms
    priors: PriorState | None


def setup_joint(scene: Scene, out_dir: Path, settings: JointSettings, priors_dir: Path | None = None) -> JointRun:
    """The trainer, its initial Gaussians, the priors and the loss of ``settings``' method.
    ``priors_dir`` holds the stereo priors (``priors/{backend}``) of a method that uses them."""
    s = settings
    with_priors = uses_priors(asdict(s))
    if with_priors and priors_dir is None:
        raise Eve3dError(f"method {s.method} uses the stereo priors: give their folder (--priors "
                         f"results/SCENE/priors/BACKEND, made by `eve3d stereo-render` and `eve3d stereo-depth`)")
    out_dir = Path(out_dir)
    trainer = Trainer(scene, s, out_dir, s.method)
    state, views = trainer.state, trainer.views
    rng = np.random.default_rng(s.seed)
    prior = None
    if with_priors:
        with phase("read priors"):
            loaded = load_priors(Path(priors_dir), scene.cameras, views.cameras, trainer.device, s.prior_normal_span)
        if s.init == "priors":
            points, colors = prior_points(loaded, views.cameras, views.images, views.train_ids, s.init_prior_points,
                                          rng)
        prior = PriorState(state, views, loaded, s) if s.priors != "none" else None
        trainer.checkpoint.depend_on(loaded.digest)
    with phase("initial Gaussians"):
        if s.init != "priors":
            points, colors = initial_points(scene, s.init_random_points, rng, s.init_drop_isolated)
        state.set_model(GaussianModel.from_points(points, colors, s.sh_degree, thickness=s.init_thickness))
    exposure = None
    if s.exposure:
        exposure = state.add_extra("exposure", torch.eye(3, 4).repeat(len(views), 1, 1), s.exposure_lr)
    return JointRun(trainer, loss_terms(trainer, s, select_neighbours(scene, s.neighbours), prior, exposure), prior)


def train_joint(scene: Scene, out_dir: Path, settings: JointSettings, priors_dir: Path | None = None) -> dict:
    """Run the stage for ``settings.method``; returns the metrics it writes."""
    s, out_dir = settings, Path(out_dir)
    run = setup_joint(scene, out_dir, s, priors_dir)
    trainer, prior = run.trainer, run.priors
    trainer.run(run.loss)
    model, views, depth_kind = trainer.model, trainer.views, s.depth
    if prior is not None and prior.learnable:
        with phase("export priors"):
            export_priors(trainer, scene, prior, out_dir / PRIORS_DIR, depth_kind)
    with phase("save"):
        model.save_ply(out_dir / MODEL_FILE)
    with phase("export depths"):
        export_depths(model, scene, s, out_dir / DEPTH_DIR, depth_kind)
    with phase("metrics"):
        metrics = {RECORD: TRAINING, "method": s.method, "train": view_metrics(model, views, views.train_ids, s),
                   "held_out": view_metrics(model, views, views.test_ids, s), "gaussians": len(model),
                   "depth": depth_kind, "settings": asdict(s)}
    with atomic_path(out_dir / TRAIN_METRICS_FILE) as tmp:
        tmp.write_text(json.dumps(metrics, indent=2, default=str))
    with phase("previews"):
        write_previews(model, views, s, s.previews, out_dir / PREVIEWS_DIR, depth=depth_kind)
    trainer.checkpoint.remove()
    return metrics


def run(settings: JointSettings, *, scene: Path, out: Path, priors: Path | None = None) -> None:
    """The ``joint`` stage: train ``settings.method`` on the posed dataset ``scene`` into ``out``."""
    from eve3d.core.io import load_scene

    with phase("read scene"):
        loaded = load_scene(scene)
    metrics = train_joint(loaded, Path(out), settings, Path(priors) if priors else None)
    print(f"training views: PSNR {metrics['train']['psnr']:.2f} dB; wrote {out}/point_cloud.ply "
          f"({metrics['gaussians']} Gaussians) and {out}/depth/")
