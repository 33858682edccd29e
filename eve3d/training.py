"""The Gaussian training loop shared by the pretrain and joint stages.

A stage builds a :class:`Trainer` (views at the training resolution, the model, one Adam
per parameter, the densification policy) and hands :meth:`Trainer.run` a function that
returns the loss terms of one step. The loop is the method's pseudo-code; everything else
(schedules, checkpoints, resume, NaN stop, progress bar, previews) lives here once.

Every random draw goes through one seeded ``torch.Generator`` whose state is checkpointed,
so a killed run that resumes from its last checkpoint continues the same sequence.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from eve3d.densify import Densifier
from eve3d.fileio import atomic_path, read_image, write_image
from eve3d.gaussians import GaussianModel
from eve3d.losses import psnr, rgb_loss, ssim
from eve3d.maps import preview_image
from eve3d.render import RenderOutput, render
from eve3d.render.projection import CameraTensors
from eve3d.scene import Camera, Eve3dError, Scene
from eve3d.settings import TrainSettings


@dataclass
class View:
    """One training image at the training resolution."""

    index: int
    camera: Camera
    cam: CameraTensors
    image: torch.Tensor
    """(H, W, 3) float in [0, 1]."""


def load_views(scene: Scene, resolution: float, device: torch.device, tone: np.ndarray | None = None) -> list[View]:
    """Every camera of ``scene`` with its image resized (area filter) to the training size,
    its grey levels first mapped through ``tone`` ((256,) uint8) when given."""
    import cv2

    views = []
    for i, cam in enumerate(tqdm(scene.cameras, desc="loading images", unit="img", leave=False)):
        small = cam.scaled(resolution) if resolution != 1 else cam
        if cam.image_path is None:
            raise Eve3dError(f"{scene.root}: view {cam.view_id} has no image")
        rgb = read_image(cam.image_path)
        if rgb.shape[:2] != (cam.height, cam.width):
            raise Eve3dError(f"{cam.image_path}: image is {rgb.shape[1]}×{rgb.shape[0]}, camera says "
                             f"{cam.width}×{cam.height}")
        if tone is not None:
            rgb = tone[rgb]
        if (small.width, small.height) != (cam.width, cam.height):
            rgb = cv2.resize(rgb, (small.width, small.height), interpolation=cv2.INTER_AREA)
        image = torch.from_numpy(rgb).to(device=device, dtype=torch.float32) / 255.0
        views.append(View(i, small, CameraTensors.from_camera(small, torch.float32, device), image))
    return views


def split_views(n: int, holdout: int) -> tuple[list[int], list[int]]:
    """(training, held-out) view indices: every ``holdout``-th view is held out."""
    test = [i for i in range(n) if holdout and i % holdout == 0]
    return [i for i in range(n) if i not in test], test


def initial_points(scene: Scene, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None]:
    """The scene's sparse points and colours, or ``count`` random points in the cameras'
    bounding sphere when there are none (3DGS's random initialisation)."""
    if scene.points is not None and len(scene.points) >= 4:
        colors = None if scene.point_colors is None else scene.point_colors / 255.0
        return scene.points, colors
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = scene.center + d * scene.radius * rng.random((count, 1)) ** (1 / 3)
    return pts, rng.random((count, 3))


class NonFiniteLoss(Eve3dError):
    """A loss term became NaN or infinite."""


class Trainer:
    """Optimises a :class:`GaussianModel` on a scene's views; see the module docstring."""

    def __init__(self, scene: Scene, settings: TrainSettings, work_dir: Path, name: str,
                 tone: np.ndarray | None = None):
        self.scene, self.s, self.work_dir, self.name = scene, settings, Path(work_dir), name
        want_cuda = settings.device == "cuda" or (settings.device == "auto" and torch.cuda.is_available())
        self.device = torch.device("cuda" if want_cuda else "cpu")
        self.views = load_views(scene, settings.resolution, self.device, tone)
        self.train_ids, self.test_ids = split_views(len(self.views), settings.holdout)
        if not self.train_ids:
            raise Eve3dError(f"{scene.root}: no training views left after holding out every {settings.holdout}th")
        self.scene_scale = scene.radius
        self.generator = torch.Generator().manual_seed(settings.seed)
        self.background = torch.tensor(settings.background, dtype=torch.float32, device=self.device)
        self.model: GaussianModel | None = None
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        self.extra: dict[str, torch.Tensor] = {}
        self.extra_optimizers: dict[str, torch.optim.Optimizer] = {}
        self.buffers: dict[str, torch.Tensor] = {}
        """State that is not optimised but changes during training (checkpointed)."""
        self.input_digest = ""
        """A digest of further inputs (e.g. the priors) that a checkpoint must match."""
        self.densify_state: dict[str, torch.Tensor] = {}
        self.step = 0
        self._order: list[int] = []

    # -- model and optimisers -------------------------------------------------------------

    def set_model(self, model: GaussianModel) -> None:
        """Adopt ``model`` (fresh Adam states, fresh densification statistics)."""
        params = {k: torch.nn.Parameter(v.detach().to(self.device).float().contiguous())
                  for k, v in model.params.items()}
        self.model = GaussianModel(params, self.s.sh_degree)
        lr = dataclasses.asdict(self.s.lr)
        lr["means"] *= self.scene_scale
        self.optimizers = {k: torch.optim.Adam([p], lr=lr[k], eps=1e-15) for k, p in params.items()}
        self.densifier = Densifier(self.s.densify)
        self.densify_state = self.densifier.init_state(len(self.model), len(self.views), self.device)

    def add_extra(self, name: str, value: torch.Tensor, lr: float) -> torch.Tensor:
        """A non-Gaussian parameter (e.g. per-image exposure) with its own Adam."""
        p = torch.nn.Parameter(value.to(self.device))
        self.extra[name] = p
        self.extra_optimizers[name] = torch.optim.Adam([p], lr=lr, eps=1e-15)
        return p

    def means_lr(self, step: int) -> float:
        """Exponential decay from ``lr.means`` to ``lr.means_final`` (× scene scale)."""
        t = min(step / max(self.s.iterations, 1), 1.0)
        lr0, lr1 = self.s.lr.means, self.s.lr.means_final
        return self.scene_scale * math.exp((1 - t) * math.log(lr0) + t * math.log(lr1))

    # -- rendering ------------------------------------------------------------------------

    def sh_degree(self, step: int) -> int:
        return min(self.s.sh_degree, step // max(self.s.sh_degree_interval, 1))

    def photometric_terms(self, step: int, view: View, out: RenderOutput) -> dict[str, torch.Tensor]:
        """The loss of a photometric-only stage: L_rgb."""
        return {"rgb": rgb_loss(out.rgb, view.image, self.s.ssim_weight)}

    def render(self, view: View | Camera, step: int | None = None, absgrad: bool = False, **kw) -> RenderOutput:
        """Render the current model from a training view (or any camera)."""
        m = self.model
        cam = view.cam if isinstance(view, View) else CameraTensors.from_camera(view, torch.float32, self.device)
        centre = -cam.R.T @ cam.t
        degree = self.s.sh_degree if step is None else self.sh_degree(step)
        return render(m.params["means"], m.params["quats"], m.scales, m.opacities, m.colors(centre, degree), cam,
                      background=self.background, backend=self.s.backend, absgrad=absgrad,
                      antialiased=self.s.antialiased, **kw)

    def next_view(self) -> View:
        """Training views in a fresh seeded permutation per pass."""
        if not self._order:
            perm = torch.randperm(len(self.train_ids), generator=self.generator).tolist()
            self._order = [self.train_ids[i] for i in perm]
        return self.views[self._order.pop()]

    # -- the loop ---------------------------------------------------------------------------

    def run(self, loss_terms: Callable[[int, View, RenderOutput], dict[str, torch.Tensor]],
            events: Callable[[int], None] | None = None) -> None:
        """Optimise until ``iterations``. ``loss_terms(step, view, out)`` returns the weighted
        terms whose sum is minimised; ``events(step)`` runs after each step (re-initialisation,
        simplification). Resumes from the checkpoint in ``work_dir`` when it matches."""
        self.resume()
        bar = tqdm(total=self.s.iterations, initial=self.step, desc=self.name, unit="it", file=sys.stderr,
                   mininterval=1.0)
        ema_loss = ema_psnr = None
        densify = self.densifier
        while self.step < self.s.iterations:
            step = self.step
            for group in self.optimizers["means"].param_groups:
                group["lr"] = self.means_lr(step)
            view = self.next_view()
            out = self.render(view, step, absgrad=densify.s.absgrad)
            terms = loss_terms(step, view, out)
            loss = sum(terms.values())
            if not torch.isfinite(loss):
                bad = [k for k, v in terms.items() if not torch.isfinite(v)]
                raise NonFiniteLoss(
                    f"{self.name}: loss term {', '.join(bad) or 'total'} is not finite at iteration {step}; "
                    f"the last good checkpoint is kept in {self.checkpoint_path} (step {self._saved_step()})")
            loss.backward()
            for opt in [*self.optimizers.values(), *self.extra_optimizers.values()]:
                opt.step()
                opt.zero_grad(set_to_none=True)
            self.step = step + 1
            with torch.no_grad():
                densify.step_post_backward(self.model.params, self.optimizers, self.densify_state, self.step, out,
                                           view.index, self.scene_scale, self.generator)
                if events is not None:
                    events(self.step)
            p, value = psnr(out.rgb.clamp(0, 1), view.image), float(loss.detach())
            ema_loss = value if ema_loss is None else 0.9 * ema_loss + 0.1 * value
            ema_psnr = p if ema_psnr is None else 0.9 * ema_psnr + 0.1 * p
            bar.update(1)
            if self.step % 10 == 0 or self.step == self.s.iterations:
                bar.set_postfix(loss=f"{ema_loss:.4f}", psnr=f"{ema_psnr:.2f}", n=len(self.model), refresh=False)
            if self.s.checkpoint_every and self.step % self.s.checkpoint_every == 0 and self.step < self.s.iterations:
                self.save_checkpoint()
        bar.close()

    # -- checkpoints ----------------------------------------------------------------------

    @property
    def checkpoint_path(self) -> Path:
        return self.work_dir / "checkpoint.pt"

    def fingerprint(self) -> str:
        """What a checkpoint must match to be resumed: the settings, the scene's views and
        poses, and the further inputs (``input_digest``)."""
        poses = [[c.name, c.K.tolist(), c.R.tolist(), c.t.tolist()] for c in self.scene.cameras]
        blob = json.dumps([dataclasses.asdict(self.s), poses, self.input_digest], sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def _saved_step(self) -> int | str:
        if not self.checkpoint_path.exists():
            return "none saved yet"
        return int(torch.load(self.checkpoint_path, map_location="cpu", weights_only=True)["step"])

    def save_checkpoint(self) -> None:
        """Everything a resumed run needs, written atomically."""
        ckpt = {
            "step": self.step, "fingerprint": self.fingerprint(), "sh_degree": self.model.sh_degree,
            "params": {k: v.detach().cpu() for k, v in self.model.params.items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "extra": {k: v.detach().cpu() for k, v in self.extra.items()},
            "extra_optimizers": {k: o.state_dict() for k, o in self.extra_optimizers.items()},
            "buffers": {k: v.cpu() for k, v in self.buffers.items()},
            "densify_state": {k: v.cpu() for k, v in self.densify_state.items()},
            "generator": self.generator.get_state(), "order": list(self._order),
        }
        with atomic_path(self.checkpoint_path) as tmp:
            torch.save(ckpt, tmp)

    def resume(self) -> bool:
        """Load the checkpoint in ``work_dir`` when its fingerprint matches these settings."""
        path = self.checkpoint_path
        if not path.exists():
            return False
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # noqa: BLE001 (a damaged checkpoint: start over, say so)
            print(f"{self.name}: ignoring unreadable checkpoint {path} ({e})", file=sys.stderr)
            return False
        if ckpt.get("fingerprint") != self.fingerprint():
            print(f"{self.name}: {path} was written with other settings; starting over", file=sys.stderr)
            return False
        self.set_model(GaussianModel(ckpt["params"], ckpt["sh_degree"]))
        for name, opt in self.optimizers.items():
            opt.load_state_dict(ckpt["optimizers"][name])
        for name, value in ckpt["extra"].items():
            self.extra[name].data.copy_(value)
            self.extra_optimizers[name].load_state_dict(ckpt["extra_optimizers"][name])
        for name, value in ckpt["buffers"].items():
            self.buffers[name].copy_(value)
        self.densify_state = {k: v.to(self.device) for k, v in ckpt["densify_state"].items()}
        self.generator.set_state(ckpt["generator"])
        self._order = list(ckpt["order"])
        self.step = int(ckpt["step"])
        print(f"{self.name}: resumed from {path} at step {self.step}", file=sys.stderr)
        return True

    def finish(self) -> None:
        """Remove the checkpoint once the stage's outputs are written."""
        self.checkpoint_path.unlink(missing_ok=True)

    # -- evaluation and previews ------------------------------------------------------------

    @torch.no_grad()
    def evaluate(self, ids: list[int]) -> dict[str, float]:
        """Mean PSNR and SSIM of the given views."""
        ps, ss = [], []
        for i in ids:
            out = self.render(self.views[i])
            rgb = out.rgb.clamp(0, 1)
            ps.append(psnr(rgb, self.views[i].image))
            ss.append(float(ssim(rgb, self.views[i].image)))
        return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "views": len(ids)} if ids else {}

    @torch.no_grad()
    def write_previews(self, out_dir: Path, depth: str = "depth") -> None:
        """``{view}.rgb.png`` (render | photo), ``{view}.depth.png``, ``{view}.normal.png``
        for a few views spread over the scene."""
        n = min(self.s.previews, len(self.views))
        for i in np.linspace(0, len(self.views) - 1, n).round().astype(int) if n else []:
            view = self.views[int(i)]
            out = self.render(view)
            stem = view.camera.view_id
            rgb = (torch.cat([out.rgb.clamp(0, 1), view.image], 1).cpu().numpy() * 255).round().astype(np.uint8)
            write_image(out_dir / f"{stem}.rgb.png", rgb)
            d = getattr(out, depth) * (out.alpha > 0.5)
            write_image(out_dir / f"{stem}.depth.png", preview_image("depth", d.cpu().numpy()))
            normal = torch.nn.functional.normalize(out.normal, dim=-1) * (out.alpha[..., None] > 0.5)
            write_image(out_dir / f"{stem}.normal.png", preview_image("normal", normal.cpu().numpy()))
