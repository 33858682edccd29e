"""What a training run changes, and its checkpoint.

:class:`TrainState` owns the Gaussians with one Adam per parameter, the extra parameters a
stage adds (each with its own Adam), the buffers it updates without gradients, the
densification statistics, the seeded random generator, the step and the views still to
visit in this pass. :data:`CHECKPOINT_PARTS` lists once what a checkpoint keeps of it and
how each part is saved and restored; :class:`Checkpoint` writes and resumes it when the
settings and inputs still match.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from eve3d.core.fileio import atomic_path
from eve3d.core.scene import Scene
from eve3d.core.settings import TrainSettings
from eve3d.core.timing import step_part
from eve3d.gaussians.densify import Densifier, remove
from eve3d.gaussians.environment import Environment
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render import RenderOutput


ENVIRONMENT = "environment"
"""The extra parameter of the environment's logits."""


class TrainState:
    """The optimised and checkpointed state of one training run (module docstring)."""

    def __init__(self, settings: TrainSettings, scene_scale: float, n_views: int, device: torch.device,
                 environment: Environment | None = None):
        self.settings, self.scene_scale, self.n_views, self.device = settings, scene_scale, n_views, device
        self.model: GaussianModel | None = None
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        self.extras: dict[str, torch.nn.Parameter] = {}
        self.extra_optimizers: dict[str, torch.optim.Optimizer] = {}
        self.environment: Environment | None = None
        """What lies behind the Gaussians, learnt with them (its logits are an extra)."""
        if environment is not None:
            self.set_environment(environment)
        self.buffers: dict[str, torch.Tensor] = {}
        """State that is not optimised but changes during training."""
        self.densifier = Densifier(settings.densify)
        self.densify_stats: dict[str, torch.Tensor] = {}
        self.generator = torch.Generator().manual_seed(settings.seed)
        """Every random draw of the run, so that a resumed run continues the same sequence."""
        self.step = 0
        self.order: list[int] = []
        """Training views still to visit in this pass (popped from the end)."""

    def set_model(self, model: GaussianModel) -> None:
        """Adopt ``model`` (fresh Adam states, fresh densification statistics)."""
        params = {k: torch.nn.Parameter(v) for k, v in model.to(self.device).params.items()}
        self.model = GaussianModel(params, self.settings.sh_degree, self.environment)
        lr = dataclasses.asdict(self.settings.lr)
        lr["means"] *= self.scene_scale
        self.optimizers = {k: adam(p, lr[k]) for k, p in params.items()}
        self.densify_stats = self.densifier.init_state(len(self.model), self.n_views, self.device)

    def add_extra(self, name: str, value: torch.Tensor, lr: float) -> torch.nn.Parameter:
        """A non-Gaussian parameter (e.g. per-image exposure) with its own Adam; a resume
        restores it in place, so the returned parameter stays the one trained."""
        p = torch.nn.Parameter(value.to(self.device))
        self.extras[name] = p
        self.extra_optimizers[name] = adam(p, lr)
        return p

    def set_environment(self, environment: Environment) -> None:
        """Learn ``environment`` behind the Gaussians, its logits an extra parameter."""
        logits = self.add_extra(ENVIRONMENT, environment.logits, self.settings.lr.environment)
        self.environment = Environment(logits, environment.frame.to(self.device), environment.seen)
        if self.model is not None:
            self.model.environment = self.environment

    def add_buffer(self, name: str, value: torch.Tensor) -> torch.Tensor:
        """Checkpoint ``value``, a tensor its owner updates in place (restored in place)."""
        self.buffers[name] = value
        return value

    def set_means_lr(self, lr: float) -> None:
        """The means' learning rate of the coming step (the loop's decay schedule)."""
        for group in self.optimizers["means"].param_groups:
            group["lr"] = lr

    @step_part("optimizer")
    def optimizer_step(self) -> None:
        """One Adam step of every parameter, Gaussians first; gradients cleared. An optimiser
        none of whose parameters has a gradient is not called (Adam would skip them anyway;
        eve3d's per-view priors are mostly such, and each call costs time: docs/results.md,
        "Figures behind the code's choices")."""
        for opt in [*self.optimizers.values(), *self.extra_optimizers.values()]:
            if all(p.grad is None for group in opt.param_groups for p in group["params"]):
                continue
            opt.step()
            opt.zero_grad(set_to_none=True)

    @step_part("densify")
    def densify(self, out: RenderOutput, view_index: int) -> None:
        """The densification policy's hook after the step's ``backward`` (``self.step`` done)."""
        self.densifier.step_post_backward(self.model.params, self.optimizers, self.densify_stats, self.step, out,
                                          view_index, self.scene_scale, self.generator)

    def remove_gaussians(self, mask: torch.Tensor) -> None:
        """Delete the Gaussians in ``mask`` with their Adam moments and statistics."""
        remove(self.model.params, self.optimizers, mask, self.densify_stats)


def adam(param: torch.nn.Parameter, lr: float) -> torch.optim.Adam:
    """3DGS's Adam for one parameter, fused: one kernel a step instead of a pass per elementwise
    operation (quicker on the CPU too: docs/results.md, "Figures behind the code's choices")."""
    return torch.optim.Adam([param], lr=lr, eps=1e-15, fused=True)


def _cpu(tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu() for k, v in tensors.items()}


def _copy_into(tensors: dict[str, torch.Tensor], saved: dict[str, torch.Tensor]) -> None:
    with torch.no_grad():
        for k, v in saved.items():
            tensors[k].copy_(v)


def _states(optimizers: dict[str, torch.optim.Optimizer]) -> dict[str, dict]:
    return {k: o.state_dict() for k, o in optimizers.items()}


def _load_states(optimizers: dict[str, torch.optim.Optimizer], saved: dict[str, dict]) -> None:
    for k, state in saved.items():
        optimizers[k].load_state_dict(state)


CHECKPOINT_PARTS: dict[str, tuple[Callable[[TrainState], Any], Callable[[TrainState, Any], None]]] = {
    # the model first: set_model starts fresh Adams and statistics, which the next parts restore
    "params": (lambda st: _cpu(st.model.params), lambda st, v: st.set_model(GaussianModel(v, st.settings.sh_degree))),
    "optimizers": (lambda st: _states(st.optimizers), lambda st, v: _load_states(st.optimizers, v)),
    "extra": (lambda st: _cpu(st.extras), lambda st, v: _copy_into(st.extras, v)),
    "extra_optimizers": (lambda st: _states(st.extra_optimizers), lambda st, v: _load_states(st.extra_optimizers, v)),
    "buffers": (lambda st: _cpu(st.buffers), lambda st, v: _copy_into(st.buffers, v)),
    "densify_state": (lambda st: _cpu(st.densify_stats),
                      lambda st, v: setattr(st, "densify_stats", {k: t.to(st.device) for k, t in v.items()})),
    "generator": (lambda st: st.generator.get_state(), lambda st, v: st.generator.set_state(v)),
    "order": (lambda st: list(st.order), lambda st, v: setattr(st, "order", list(v))),
    "step": (lambda st: st.step, lambda st, v: setattr(st, "step", int(v))),
}
"""What a checkpoint keeps: per key, how to save it from a :class:`TrainState` and how to
restore it (in this order)."""


class Checkpoint:
    """``checkpoint.pt`` in a run's folder, resumed only when it was written with the same
    settings, the same views and poses, and the same further inputs (:meth:`depend_on`)."""

    def __init__(self, work_dir: Path, settings: TrainSettings, scene: Scene, name: str):
        self.path = Path(work_dir) / "checkpoint.pt"
        self.settings, self.scene, self.name = settings, scene, name
        self.inputs = ""

    def depend_on(self, digest: str) -> None:
        """A digest of further inputs (e.g. the priors) that a checkpoint must match."""
        self.inputs = digest

    def fingerprint(self) -> str:
        """What a checkpoint must match to be resumed."""
        poses = [[c.name, c.K.tolist(), c.R.tolist(), c.t.tolist()] for c in self.scene.cameras]
        blob = json.dumps([dataclasses.asdict(self.settings), poses, self.inputs], sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def save(self, state: TrainState) -> None:
        """Everything a resumed run needs, written atomically."""
        ckpt = {"fingerprint": self.fingerprint(), **{k: save(state) for k, (save, _) in CHECKPOINT_PARTS.items()}}
        with atomic_path(self.path) as tmp, open(tmp, "wb") as f:
            torch.save(ckpt, f)  # to a file object: given a path, torch reports a full disk as a RuntimeError

    def resume(self, state: TrainState) -> bool:
        """Restore ``state`` from the checkpoint when its fingerprint matches."""
        if not self.path.exists():
            return False
        try:
            ckpt = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as e:  # noqa: BLE001 (a damaged checkpoint: start over, say so)
            print(f"{self.name}: ignoring unreadable checkpoint {self.path} ({e})", file=sys.stderr)
            return False
        if ckpt.get("fingerprint") != self.fingerprint():
            print(f"{self.name}: {self.path} was written with other settings; starting over", file=sys.stderr)
            return False
        for key, (_, restore) in CHECKPOINT_PARTS.items():
            restore(state, ckpt[key])
        print(f"{self.name}: resumed from {self.path} at step {state.step}", file=sys.stderr)
        return True

    def saved_step(self) -> int | str:
        """The step of the checkpoint on disk, for messages."""
        if not self.path.exists():
            return "none saved yet"
        return int(torch.load(self.path, map_location="cpu", weights_only=True)["step"])

    def remove(self) -> None:
        """Remove the checkpoint once the stage's outputs are written."""
        self.path.unlink(missing_ok=True)
