"""The Gaussian training loop shared by the pretrain and joint stages.

A stage builds a :class:`Trainer` (the scene's views at the training resolution, an empty
:class:`~eve3d.gaussians.train_state.TrainState` and the run's checkpoint), gives its state the initial
Gaussians (:func:`initial_points`, or the stage's own) and any further parameters, and hands
:meth:`Trainer.run` a function that returns the loss terms of one step. The loop is the
method's pseudo-code; the schedules (means learning rate, SH degree, view order), the
densification calls, when to resume and checkpoint, the NaN stop and the progress bar live
here once. Each part it composes does one job: :mod:`eve3d.gaussians.views` (images, train/held-out
split), :mod:`eve3d.gaussians.train_state` (parameters, optimisers, checkpoint contents),
:func:`eve3d.gaussians.render.render_model` (rendering); :mod:`eve3d.gaussians.view_report` scores and previews
the finished model.

Every random draw goes through the state's one seeded ``torch.Generator``, which is
checkpointed, so a killed run that resumes from its last checkpoint continues the same sequence.
"""
from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from eve3d.core.cores import CoreShare
from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path
from eve3d.core.layout import MODEL_FILE, PREVIEWS_DIR, RECORD, TRAIN_METRICS_FILE, TRAINING
from eve3d.core.scene import Scene
from eve3d.core.settings import TrainSettings
from eve3d.core.timing import phase, step_part
from eve3d.gaussians.environment import scene_environment
from eve3d.gaussians.losses import psnr, rgb_loss
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render import RenderOutput, render_model
from eve3d.gaussians.train_state import Checkpoint, TrainState
from eve3d.gaussians.view_report import view_metrics, write_previews
from eve3d.gaussians.views import View, Views, coarse_views, pick_device

LossTerms = Callable[[int, View, RenderOutput], dict[str, torch.Tensor]]
"""``(step, view, rendered view) -> weighted loss terms``, whose sum a step minimises."""


def has_sparse_points(scene: Scene) -> bool:
    """Whether the scene has SfM points enough to start from (four: a volume)."""
    return scene.points is not None and len(scene.points) >= 4


def initial_points(scene: Scene, count: int, rng: np.random.Generator,
                   drop_isolated: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The scene's sparse points and colours (without its :meth:`~eve3d.core.scene.Scene.isolated`
    ones if ``drop_isolated``), or ``count`` random points in the cameras' bounding sphere
    when there are none (3DGS's random initialisation)."""
    if has_sparse_points(scene):
        points, colors = scene.points, scene.point_colors
        if drop_isolated:
            keep = ~scene.isolated()
            points, colors = points[keep], None if colors is None else colors[keep]
        return points, None if colors is None else colors / 255.0
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = scene.center + d * scene.radius * rng.random((count, 1)) ** (1 / 3)
    return pts, rng.random((count, 3))


def photometric_terms(settings: TrainSettings, view: View, out: RenderOutput,
                      rgb: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """What every training stage fits of the photos: L_rgb of ``rgb`` (default: the render's)
    and the sky loss, ``sky_weight`` × mean(α · beyond): the alpha of the pixels beyond the
    measured scene, where the environment alone is to be seen."""
    terms = {"rgb": rgb_loss(out.rgb if rgb is None else rgb, view.image, settings.ssim_weight)}
    if settings.sky_weight and view.beyond is not None:
        terms["sky"] = settings.sky_weight * (out.alpha * view.beyond).mean()
    return terms


@step_part("backward")
def backward(loss: torch.Tensor) -> None:
    """The step's backward pass (a part of its own for ``eve3d bench training``)."""
    loss.backward()


class NonFiniteLoss(Eve3dError):
    """A loss term became NaN or infinite."""

    @classmethod
    def at(cls, step: int, terms: dict[str, torch.Tensor], section: str, name: str,
           checkpoint: Checkpoint) -> NonFiniteLoss:
        """The error of a training run named ``name`` (its settings' ``section``) whose loss
        ``terms`` were not finite at ``step``: which terms, and the checkpoint that is kept."""
        bad = [k for k, v in terms.items() if not torch.isfinite(v)]
        stage = name if name == section else f"{section} ({name})"  # joint (pgsr)
        return cls(f"{stage}: loss term {', '.join(bad) or 'total'} is not finite at iteration {step}; "
                   f"the last good checkpoint is kept in {checkpoint.path} (step {checkpoint.saved_step()})")


class Trainer:
    """Optimises the Gaussians of its :class:`TrainState` on a scene's views; see the module
    docstring. ``views``, ``state`` and ``checkpoint`` are its parts, for the stage to set up."""

    def __init__(self, scene: Scene, settings: TrainSettings, work_dir: Path, name: str,
                 tone: np.ndarray | None = None):
        self.settings, self.name = settings, name
        self.device = pick_device(settings.device)
        with phase("read photos"):
            self.views = Views.load(scene, settings, settings.holdout, self.device, tone)
            self.views.coarse = coarse_views(scene, settings, self.device, tone)
        self.state = TrainState(settings, scene.radius, len(self.views), self.device,
                                scene_environment(scene, self.views, settings))
        self.checkpoint = Checkpoint(work_dir, settings, scene, name)

    @property
    def model(self) -> GaussianModel:
        """The Gaussians being trained."""
        return self.state.model

    def start_from(self, points: np.ndarray, colors: np.ndarray | None) -> None:
        """Train Gaussians at ``points`` (N, 3) from here on, coloured ``colors`` (N, 3) in
        [0, 1] or grey, of the settings' SH degree and initial thickness; fresh Adam states."""
        self.state.set_model(GaussianModel.from_points(points, colors, self.settings.sh_degree,
                                                       thickness=self.settings.init_thickness))

    @property
    def generator(self) -> torch.Generator:
        """The run's seeded generator: a loss that draws at random draws from it."""
        return self.state.generator

    def means_lr(self, step: int) -> float:
        """Exponential decay from ``lr.means`` to ``lr.means_final`` (× scene scale)."""
        t = min(step / max(self.settings.iterations, 1), 1.0)
        lr0, lr1 = self.settings.lr.means, self.settings.lr.means_final
        return self.state.scene_scale * math.exp((1 - t) * math.log(lr0) + t * math.log(lr1))

    def sh_degree(self, step: int) -> int:
        """SH degree in use at ``step``: one more every ``sh_degree_interval`` steps."""
        return min(self.settings.sh_degree, step // max(self.settings.sh_degree_interval, 1))

    @step_part("projection")
    def render(self, view: View, step: int | None = None, **kw) -> RenderOutput:
        """The current model from a training view, with the SH degree of ``step`` (default:
        all). The environment is fitted only through the view's pixels beyond the measured
        scene: a surface the Gaussians do not cover yet is not learnt into it."""
        return render_model(self.model, view.cam, self.settings, None if step is None else self.sh_degree(step),
                            fit_environment=view.beyond, **kw)

    def next_view(self) -> View:
        """Training views in a fresh seeded permutation per pass."""
        st = self.state
        if not st.order:
            perm = torch.randperm(len(self.views.train_ids), generator=st.generator).tolist()
            st.order = [self.views.train_ids[i] for i in perm]
        return self.views.at(st.order.pop(), st.step)

    def run(self, loss_terms: LossTerms, events: Callable[[int], None] | None = None,
            until: int | None = None) -> None:
        """Optimise until ``iterations``. ``loss_terms(step, view, out)`` returns the weighted
        terms whose sum is minimised; ``events(step)`` runs after each step (re-initialisation,
        simplification). Resumes from the checkpoint in ``work_dir`` when it matches.
        ``until``: stop earlier, after that many steps (a benchmark's window of steps)."""
        st = self.state
        self.checkpoint.resume(st)
        end = self.settings.iterations if until is None else min(until, self.settings.iterations)
        progress = _Progress(self.name, self.settings.iterations, st.step)
        with phase("steps"), CoreShare.from_environment() as share:
            self._loop(loss_terms, events, end, progress, share)
        progress.close()

    def _loop(self, loss_terms: LossTerms, events: Callable[[int], None] | None, end: int,
              progress: _Progress, share: CoreShare) -> None:
        """The steps of :meth:`run`, on ``share``'s part of the cores."""
        st = self.state
        while st.step < end:
            step = st.step
            share.rebalance(step)
            st.set_means_lr(self.means_lr(step))
            view = self.next_view()
            out = self.render(view, step, absgrad=self.settings.densify.absgrad)
            terms = loss_terms(step, view, out)
            loss = sum(terms.values())
            if not torch.isfinite(loss):
                progress.close()  # the error starts on a line of its own, not after the bar
                raise NonFiniteLoss.at(step, terms, self.settings.SECTION, self.name, self.checkpoint)
            backward(loss)
            st.optimizer_step()
            st.step = step + 1
            with torch.no_grad(), phase("densify"):
                st.densify(out, view.index)
                if events is not None:
                    events(st.step)
            progress.update(st.step, float(loss.detach()), psnr(out.rgb.clamp(0, 1), view.image), len(self.model))
            every = self.settings.checkpoint_every
            if every and st.step % every == 0 and st.step < self.settings.iterations:
                with phase("checkpoints"):
                    self.checkpoint.save(st)

    def finish(self, out_dir: Path, record: Callable[[dict], dict], depth: str,
               beside_model: Callable[[], None] = lambda: None) -> dict:
        """The end of a training stage: the model saved (``point_cloud.ply``), then ``beside_model``
        (what else the stage writes from it), the PSNR and SSIM of the training and held-out views
        in ``train_metrics.json`` (its fields as ``record`` arranges them, given ``train`` and
        ``held_out``), previews with the ``depth`` output, and the checkpoint removed. Returns the metrics."""
        model, views = self.model, self.views
        model.environment = model.environment and model.environment.filled()  # it shows new views from here on
        with phase("save"):
            model.save_ply(out_dir / MODEL_FILE)
        beside_model()
        with phase("metrics"):
            scores = {"train": view_metrics(model, views, views.train_ids, self.settings),
                      "held_out": view_metrics(model, views, views.test_ids, self.settings)}
            metrics = {RECORD: TRAINING, **record(scores)}
        with atomic_path(out_dir / TRAIN_METRICS_FILE) as tmp:
            tmp.write_text(json.dumps(metrics, indent=2, default=str))
        with phase("previews"):
            write_previews(model, views, self.settings, self.settings.previews, out_dir / PREVIEWS_DIR, depth=depth)
        self.checkpoint.remove()
        return metrics


class _Progress:
    """The progress bar, with running means of the loss and the PSNR."""

    def __init__(self, name: str, total: int, initial: int):
        self.total = total
        self.bar = tqdm(total=total, initial=initial, desc=name, unit="it", file=sys.stderr, mininterval=1.0)
        self.loss: float | None = None
        self.psnr: float | None = None

    def update(self, step: int, loss: float, psnr: float, gaussians: int) -> None:
        self.loss = loss if self.loss is None else 0.9 * self.loss + 0.1 * loss
        self.psnr = psnr if self.psnr is None else 0.9 * self.psnr + 0.1 * psnr
        self.bar.update(1)
        if step % 10 == 0 or step == self.total:
            self.bar.set_postfix(loss=f"{self.loss:.4f}", psnr=f"{self.psnr:.2f}", n=gaussians, refresh=False)

    def close(self) -> None:
        self.bar.close()
