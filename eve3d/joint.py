"""Joint stage (``eve3d joint``): train the Gaussians of one method and render its depth.

One loss, whose parts the settings switch on and off; the methods (``eve3d.core.methods``) are
named settings of it. In full (PGSR): L_rgb, the flattening loss on the smallest scale, the
single-view depth–normal consistency from ``dn_from``, the multi-view geometric and NCC
photometric losses over a rendered neighbour view from ``mv_from``, AbsGS's split, optional
per-image exposure; meshed from the unbiased depth D = d / −(N·r). With the planar and
multi-view parts off and the plain split it is 3DGS, meshed from the expected depth
Σ w z / Σ w.

Writes ``point_cloud.ply``, ``depth/{view}.npz`` (depth, confidence = rendered alpha,
camera-space normal, and with an environment ``sky``: what it explains, which no mesh fuses;
at the dataset's full resolution, with PNG previews),
``train_metrics.json``, ``previews/`` and, for learnable priors, ``priors/`` (the final D̂).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir, write_image
from eve3d.core.layout import DEPTH_DIR, PRIORS_DIR
from eve3d.core.maps import save_maps
from eve3d.core.methods import uses_priors
from eve3d.core.scene import Scene
from eve3d.core.settings import JointSettings, RenderSettings
from eve3d.core.timing import phase
from eve3d.gaussians.environment import explained
from eve3d.gaussians.geometry import CameraStack, depth_to_normal, depth_to_points
from eve3d.gaussians.losses import (depth_confirmation, depth_normal_loss, forward_backward_error, geometric_loss,
                                    ncc_loss)
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.neighbours import select_neighbours
from eve3d.gaussians.render import RenderOutput, render_model
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.gaussians.train_state import TrainState
from eve3d.gaussians.training import LossTerms, Trainer, has_sparse_points, initial_points, photometric_terms
from eve3d.gaussians.views import View, Views
from eve3d.priors.learnable import Priors, comparison_preview, filled_log_depth, load_priors, prior_points


def multiview_terms(ref: View, nbrs: list[View], depth: torch.Tensor, normal: torch.Tensor, distance: torch.Tensor,
                    nbr_depths: list[torch.Tensor], mask: torch.Tensor, settings: JointSettings,
                    generator: torch.Generator, with_ncc: bool = True
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
    geo, valid = geometric_loss(phi, defined & mask, settings.mv_threshold)
    ncc_term = None
    if with_ncc:  # (sum, count) apart: PGSR scales the sum before dividing
        picks = [idx[torch.randperm(len(idx), generator=generator)[:settings.ncc_pixels].to(idx.device)]
                 for idx in (v.flatten().nonzero().squeeze(1) for v in valid)]
        drawn = max(len(p) for p in picks)
        if drawn:  # each neighbour's draw, padded to the longest with pixel 0 (not counted)
            pick = torch.zeros(len(nbrs), drawn, dtype=torch.long, device=depth.device)
            counted = torch.zeros(len(nbrs), drawn, dtype=torch.bool, device=depth.device)
            for k, p in enumerate(picks):
                pick[k, :len(p)], counted[k, :len(p)] = p, True
            pixels = torch.stack([pick // ref.cam.width, pick % ref.cam.width], -1)
            ncc, ok = ncc_loss(ref.grey, [n.grey for n in nbrs], ref.cam, cams, normal, distance, pixels,
                               settings.ncc_patch)
            ok = ok & counted
            w = torch.exp(-phi.flatten(1).gather(1, pick)).detach() * ok
            ncc_term = (ncc * w).sum(-1), ok.sum(-1).clamp_min(1)
    return geo, ncc_term, defined & (phi < settings.mv_threshold)


def prior_plane(depth: torch.Tensor, view: View, span: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Normal (from the depth's finite differences over ±``span`` pixels, facing the camera;
    0 on the border) and plane distance d = −N·X of a depth map, for the homography of a
    prior reference."""
    normal = depth_to_normal(depth, view.cam, span)
    return normal, -(normal * depth_to_points(depth, view.cam)).sum(-1)


class PriorState:
    """The priors inside training: D*, the confidence M^c (a checkpointed buffer) and, for
    ``priors: learnable``, the log-depth D̂ of every view as its own parameter."""

    def __init__(self, state: TrainState, views: Views, priors: Priors, settings: JointSettings):
        self.views, self.settings, self.star = views, settings, priors
        self.confidence = [state.add_buffer(f"prior_confidence/{i}", c.clone())
                           for i, c in enumerate(priors.confidence)]
        self.learnable = settings.priors == "learnable"
        self.blank = {i for i, d in enumerate(priors.depth) if not (d > 0).any()}
        """Views without any prior depth: nobody's LBA neighbour (their D̂ is a constant)."""
        self.log_depth = []
        if self.learnable:  # a blank view's D̂ starts at the median of the other views' median depths
            typical = float(torch.stack([d[d > 0].median() for i, d in enumerate(priors.depth)
                                         if i not in self.blank]).median()) if self.blank else 1.0
            self.log_depth = [state.add_extra(f"prior_log_depth/{i}", filled_log_depth(d, typical), settings.prior_lr)
                              for i, d in enumerate(priors.depth)]

    def depth(self, i: int) -> torch.Tensor:
        """D̂_i (learnable) or D*_i (fixed)."""
        return torch.exp(self.log_depth[i]) if self.learnable else self.star.depth[i]

    @staticmethod
    def sized(fine: torch.Tensor, view: View, step: int | None = None) -> torch.Tensor:
        """A map (H, W, ...) of view ``view.index`` at the training size, at ``view``'s size:
        itself, or on a coarse step (``train.coarse_until``) one fine pixel of each coarse
        pixel's block, so that a depth is never blended across an edge and a confidence stays a
        mask. Which pixel of the block moves with ``step`` along a low-discrepancy sequence
        (Roberts' R2), so that over the coarse steps every pixel of a learnable D̂ is trained;
        the block's centre without a step."""
        h, w = view.image.shape[:2]
        if fine.shape[:2] == (h, w):
            return fine
        dv, du = (0.5, 0.5) if step is None else ((step * 0.7548776662) % 1, (step * 0.5698402910) % 1)
        rows = ((torch.arange(h, device=fine.device) + dv) * (fine.shape[0] / h)).long()
        cols = ((torch.arange(w, device=fine.device) + du) * (fine.shape[1] / w)).long()
        return fine[rows][:, cols]

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
        settings = self.settings
        if not neighbours:
            self.confidence[i].zero_()
            return
        view = self.views[i]
        agrees, ncc, flat = depth_confirmation(
            self.depth(i), view.grey, view.cam, CameraStack([n.cam for n in neighbours]),
            [self.depth(n.index) for n in neighbours], [self.star.confidence[n.index] for n in neighbours],
            [n.grey for n in neighbours], settings.confirm_depth)
        confirmed = agrees.sum(0) >= settings.consistent_views
        if settings.confirm_photos:
            confirmed &= flat | ((ncc >= settings.confirm_ncc).sum(0) >= settings.confirm_photos)
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
    depth = priors.sized(priors.depth(view.index), view)[v, u]
    return inside & priors.sized(priors.confidence[view.index], view)[v, u] & ((z - depth).abs() <= margin * depth)


def loss_terms(trainer: Trainer, settings: JointSettings, neighbours: list[list[int]], priors: PriorState | None = None,
               exposure: torch.Tensor | None = None) -> LossTerms:
    """The loss function of the joint stage (see the module docstring). ``exposure``: the
    (views, 3, 4) affine colour correction of each view, when ``settings.exposure``."""
    train_set = set(trainer.views.train_ids)

    def terms(step: int, view: View, out: RenderOutput) -> dict[str, torch.Tensor]:
        rgb = out.rgb
        if settings.exposure:
            e = exposure[view.index]
            rgb = rgb @ e[:, :3].T + e[:, 3]
        t = photometric_terms(settings, view, out, rgb)
        visible = out.visible
        if settings.scale_weight and visible.any():
            t["scale"] = settings.scale_weight * trainer.model.scales[visible].amin(-1).mean()
        lowering = not settings.opacity_while_densifying or step < settings.densify.refine_stop
        if settings.opacity_weight and lowering and visible.any():
            lowered = visible
            if priors is not None and settings.opacity_spare:
                lowered = visible & ~on_prior_surface(trainer.model, view, priors, settings.opacity_spare)
            # per visible Gaussian, the same push whether or not some are spared
            t["opacity"] = settings.opacity_weight * trainer.model.opacities[lowered].sum() / visible.sum()
        covered = out.alpha.detach() > 0.5
        if step >= settings.dn_from and settings.dn_weight:
            t["depth_normal"] = settings.dn_weight * depth_normal_loss(out.depth, out.normal, view.edge_weight,
                                                                       view.cam, covered)
        candidates = [j for j in neighbours[view.index] if j in train_set]
        if step >= settings.mv_from and candidates and (settings.geo_weight or settings.ncc_weight):
            pick = candidates[int(torch.randint(len(candidates), (1,), generator=trainer.generator))]
            nbr = trainer.views.at(pick, step)
            out_n = trainer.render(nbr, step, geometry_only=True)  # only its depth is used
            geo, ncc, _ = multiview_terms(view, [nbr], out.depth, out.normal, out.distance, [out_n.depth], covered,
                                          settings, trainer.generator, with_ncc=bool(settings.ncc_weight))
            t["mv_geo"] = settings.geo_weight * geo[0]
            if ncc is not None:
                t["mv_ncc"] = settings.ncc_weight * ncc[0][0] / ncc[1][0]
        if priors is not None and step >= settings.prior_from:
            nbrs = [trainer.views.at(j, step) for j in candidates]
            t.update(prior_terms(step, view, out, covered, nbrs, priors, settings, trainer.generator))
        return t

    return terms


FLAT_LEVELS = 4 / 255
"""Grey-level standard deviation over 5×5 pixels from which a photo counts as textured
(``JointSettings.prior_flat_weight``); the rooms' walls lie below it on most pixels."""


def prior_weights(view: View, settings: JointSettings) -> torch.Tensor | float:
    """λ_prior per pixel of ``view``: ``prior_weight`` on texture, rising linearly to
    ``prior_flat_weight`` as the 5×5 grey-level standard deviation falls to 0; the scalar
    ``prior_weight`` where ``prior_flat_weight`` is 0."""
    if not settings.prior_flat_weight:
        return settings.prior_weight
    flat = (1 - view.contrast / FLAT_LEVELS).clamp(0, 1)
    return settings.prior_weight + (settings.prior_flat_weight - settings.prior_weight) * flat


def prior_terms(step: int, view: View, out: RenderOutput, covered: torch.Tensor, neighbours: list[View],
                priors: PriorState, settings: JointSettings, generator: torch.Generator) -> dict[str, torch.Tensor]:
    """Eve3D's terms (DESIGN §3). Before T_joint (``joint_from``): L_prior towards the fixed
    D*, and the LBA among the priors (reference D̂_i against the neighbours' D̂_n: a
    consistent initialisation). From T_joint: L_prior towards D̂_i, L_pull of D̂_i towards
    the rendered depth where M^c is not confident, and the LBA of the rendered depth
    against the neighbours' D̂_n (no neighbour is rendered); gradients reach the
    Gaussians and every D̂ involved. Each visit first re-checks M^c_i at the training size
    (``PriorState.update_confidence``) when the LBA is on. A coarse step's ``view`` and
    ``neighbours`` are smaller: every map is taken at their size (``PriorState.sized``)."""
    t: dict[str, torch.Tensor] = {}
    i, joint = view.index, step >= settings.joint_from
    neighbours = [n for n in neighbours if n.index not in priors.blank][:settings.neighbours]

    def at(fine: torch.Tensor, v: View = view) -> torch.Tensor:
        return priors.sized(fine, v, step)

    if settings.lba_weight:  # the multi-view check is the LBA's: without it M^c stays the stereo's
        priors.update_confidence(i, [priors.views[n.index] for n in neighbours])  # at the training size
    confidence = at(priors.confidence[i])
    confident = confidence & covered
    target = at(priors.depth(i) if joint else priors.star.depth[i])
    if (settings.prior_weight or settings.prior_flat_weight) and confident.any():
        target_normal = (depth_to_normal(target, view.cam, settings.prior_normal_span) if joint
                         else at(priors.star.normal[i]))
        normal = torch.nn.functional.normalize(out.normal, dim=-1)
        weight = prior_weights(view, settings)
        depth_term = (weight * (target - out.depth).abs() * confident).sum() / confident.sum()
        on_normal = confident & (target_normal.norm(dim=-1) > 0)
        normal_term = (weight * (1 - (target_normal * normal).sum(-1)) * on_normal).sum() / on_normal.sum().clamp_min(1)
        t["prior"] = depth_term + settings.prior_normal_weight * normal_term
    unconfident = ~confidence & covered
    if priors.learnable and joint and settings.pull_weight and unconfident.any():
        pull = (at(priors.depth(i)) - out.depth.detach()).abs() * unconfident
        t["pull"] = settings.pull_weight * pull.sum() / unconfident.sum()
    if settings.lba_weight and neighbours and (joint or priors.learnable):
        if joint:  # the rendered depth and plane against the neighbours' priors
            depth, normal, distance, mask = out.depth, out.normal, out.distance, covered
        else:  # the confident priors among themselves
            depth = at(priors.depth(i))
            normal, distance = prior_plane(depth, view, settings.prior_normal_span)
            mask = confidence & (normal.norm(dim=-1) > 0)
        geo, ncc, _ = multiview_terms(view, neighbours, depth, normal, distance,
                                      [at(priors.trusted(n.index), n) for n in neighbours], mask, settings, generator)
        total = geo.sum() + (0.0 if ncc is None else (ncc[0] / ncc[1]).sum())
        t["lba"] = settings.lba_weight * total / len(neighbours)
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
def export_depths(model: GaussianModel, scene: Scene, rendering: RenderSettings, out_dir: Path, kind: str,
                  sky_tolerance: float = 0.0) -> None:
    """Render ``kind`` (``depth`` or ``depth_expected``) for every view at full resolution:
    the depth maps the mesh is fused from. With an environment at infinity and a
    ``sky_tolerance``, each map also marks as ``sky`` the pixels whose photo the environment
    explains (``train.sky_tolerance``), which no mesh fuses."""
    from eve3d.core.photos import read_view

    sky = model.environment is not None and sky_tolerance > 0
    with atomic_dir(out_dir) as tmp:
        for cam in tqdm(scene.cameras, desc=f"rendering {kind}", unit="view"):
            out = render_model(model, cam, rendering)
            normal = torch.nn.functional.normalize(out.normal, dim=-1)
            maps = {"depth": getattr(out, kind).cpu().numpy(), "confidence": out.alpha.cpu().numpy(),
                    "normal": normal.cpu().numpy()}
            if sky:
                photo = torch.from_numpy(read_view(cam)).float() / 255
                tensors = CameraTensors.from_camera(cam, device=out.alpha.device)
                maps["sky"] = explained(model.environment, tensors, photo.to(out.alpha.device), sky_tolerance).cpu().numpy()
            save_maps(tmp / f"{cam.view_id}.npz", **maps)


@dataclass
class JointRun:
    """A joint stage ready to run: ``trainer.run(loss)``."""

    trainer: Trainer
    loss: LossTerms
    priors: PriorState | None


def with_sparse_points(scene: Scene, points: np.ndarray, colors: np.ndarray,
                       drop_isolated: bool) -> tuple[np.ndarray, np.ndarray]:
    """The prior points and the scene's SfM points together (``init: both``): the SfM
    points seed what the priors refuse, such as the far ends of a floor."""
    sparse, sparse_colors = initial_points(scene, 0, None, drop_isolated)
    sparse_colors = np.full_like(sparse, 0.5) if sparse_colors is None else sparse_colors
    return np.concatenate([points, sparse]), np.concatenate([colors, sparse_colors])


def setup_joint(scene: Scene, out_dir: Path, settings: JointSettings, priors_dir: Path | None = None) -> JointRun:
    """The trainer, its initial Gaussians, the priors and the loss of ``settings``' method.
    ``priors_dir`` holds the stereo priors (``priors/{backend}``) of a method that uses them."""
    with_priors = uses_priors(asdict(settings))
    if with_priors and priors_dir is None:
        raise Eve3dError(f"method {settings.method} uses the stereo priors: give their folder (--priors "
                         f"results/SCENE/priors/BACKEND, made by `eve3d stereo-render` and `eve3d stereo-depth`)")
    out_dir = Path(out_dir)
    trainer = Trainer(scene, settings, out_dir, settings.method)
    state, views = trainer.state, trainer.views
    rng = np.random.default_rng(settings.seed)
    prior = None
    if with_priors:
        with phase("read priors"):
            loaded = load_priors(Path(priors_dir), scene.cameras, views.cameras, trainer.device,
                                 settings.prior_normal_span)
        for confidence, view in zip(loaded.confidence, views):
            if view.beyond is not None:  # the environment explains these pixels: no surface to measure
                confidence &= ~view.beyond
        if settings.init in ("priors", "both"):
            points, colors = prior_points(loaded, views.cameras, views.images, views.train_ids,
                                          settings.init_prior_points, rng)
        prior = PriorState(state, views, loaded, settings) if settings.priors != "none" else None
        trainer.checkpoint.depend_on(loaded.digest)
    with phase("initial Gaussians"):
        if settings.init == "sparse":
            points, colors = initial_points(scene, settings.init_random_points, rng, settings.init_drop_isolated)
        elif settings.init == "both" and has_sparse_points(scene):
            points, colors = with_sparse_points(scene, points, colors, settings.init_drop_isolated)
        trainer.start_from(points, colors)
    exposure = None
    if settings.exposure:
        exposure = state.add_extra("exposure", torch.eye(3, 4).repeat(len(views), 1, 1), settings.exposure_lr)
    return JointRun(trainer, loss_terms(trainer, settings, select_neighbours(scene, settings.neighbours), prior,
                                        exposure), prior)


def train_joint(scene: Scene, out_dir: Path, settings: JointSettings, priors_dir: Path | None = None) -> dict:
    """Run the stage for ``settings.method``; returns the metrics it writes."""
    out_dir = Path(out_dir)
    run = setup_joint(scene, out_dir, settings, priors_dir)
    trainer, prior = run.trainer, run.priors
    trainer.run(run.loss)
    model, depth_kind = trainer.model, settings.depth
    if prior is not None and prior.learnable:
        with phase("export priors"):
            export_priors(trainer, scene, prior, out_dir / PRIORS_DIR, depth_kind)

    def save_depths() -> None:
        with phase("export depths"):
            export_depths(model, scene, settings, out_dir / DEPTH_DIR, depth_kind, settings.sky_tolerance)

    def record(scores: dict) -> dict:
        return {"method": settings.method, **scores, "gaussians": len(model), "depth": depth_kind,
                "settings": asdict(settings)}

    return trainer.finish(out_dir, record, depth_kind, save_depths)


def run_joint(settings: JointSettings, *, scene: Path, out: Path, priors: Path | None = None) -> None:
    """The ``joint`` stage: train ``settings.method`` on the posed dataset ``scene`` into ``out``."""
    from eve3d.core.io import load_scene

    with phase("read scene"):
        loaded = load_scene(scene)
    metrics = train_joint(loaded, Path(out), settings, Path(priors) if priors else None)
    print(f"training views: PSNR {metrics['train']['psnr']:.2f} dB; wrote {out}/point_cloud.ply "
          f"({metrics['gaussians']} Gaussians) and {out}/depth/")
