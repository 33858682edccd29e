"""``eve3d bench training``: the training step of each stage, timed and broken into its parts."""
from __future__ import annotations

import bisect
import functools
import multiprocessing
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING
from unittest import mock

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.timing import timing_step_parts
from eve3d.tools.bench.common import in_child, peak_rss_mb

if TYPE_CHECKING:
    import torch

    from eve3d.gaussians.training import LossTerms, Trainer


TRAINING_STAGES = ("pretrain", "pgsr", "eve3d")
STEP_PARTS = {
    "projection": "projection forward",
    "rasterize": "rasterise forward",
    "losses": "losses forward",
    "losses_backward": "losses backward",
    "rasterize_backward": "rasterise backward",
    "projection_backward": "projection backward",
    "optimizer": "optimiser step",
    "densify": "densification",
    "other": "other",
}
"""The parts of a training step that ``eve3d bench training`` times: key, label."""
_BACKWARD_OF = {"projection": "projection_backward", "rasterize": "rasterize_backward"}
"""The backward part of the nodes a forward part creates; any other node's: losses_backward."""
_ACCUMULATE_GRAD = 2**64 - 1
"""The sequence number of every AccumulateGrad node (run as soon as ready)."""


class StepProfiler:
    """Self times of the parts of training steps, timed around the calls of a step's parts;
    the method is :func:`profile_steps`'. ``sync`` waits for the device (CUDA) at every
    boundary, so that its work is charged to the part that queued it."""

    def __init__(self, sync: Callable[[], None] = lambda: None):
        self.sync = sync
        self.seconds = dict.fromkeys(STEP_PARTS, 0.0)
        self.overhead = 0.0
        """Time spent preparing the backward hooks: not the step's."""
        self.open: list[str] = []
        """Parts running, innermost last: each is charged only while it is innermost."""
        self.since = time.perf_counter()
        self.marks: list[tuple[int, str | None]] = []
        """(autograd sequence number, innermost forward part from there) since the last backward."""

    def reset(self) -> None:
        """Start counting afresh."""
        self.seconds = dict.fromkeys(STEP_PARTS, 0.0)
        self.overhead = 0.0

    def _charge(self) -> None:
        now = time.perf_counter()
        if self.open:
            self.seconds[self.open[-1]] += now - self.since
        self.since = now

    def _mark(self) -> None:
        import torch

        self.marks.append((torch._C._autograd._get_sequence_nr(), self.open[-1] if self.open else None))

    def _enter(self, part: str) -> None:
        self.sync()
        self._charge()
        self.open.append(part)
        self._mark()

    def _leave(self) -> None:
        self.sync()
        self._charge()
        self.open.pop()
        self._mark()

    def call(self, part: str, fn: Callable, *args, **kwargs):
        """``fn(*args, **kwargs)``, its self time charged to ``part``."""
        self._enter(part)
        try:
            return fn(*args, **kwargs)
        finally:
            self._leave()

    def backward(self, backward: Callable, loss: torch.Tensor):
        """``backward(loss)``, its time split among the backward parts by pre-hooks on the
        first node of each forward part's stretch of ``loss``'s graph."""
        start = time.perf_counter()
        self._charge()
        for node, part in self._stretch_starts(loss.grad_fn):
            node.register_prehook(functools.partial(self._backward_reaches, part))
        self.sync()
        self.open.append("losses_backward")
        self.overhead += time.perf_counter() - start
        self.since = time.perf_counter()
        try:
            return backward(loss)
        finally:
            self._leave()
            self.marks = self.marks[-1:]

    def _backward_reaches(self, part: str, grad_outputs) -> None:
        self.sync()
        self._charge()
        self.open[-1] = part

    def _stretch_starts(self, root: torch.autograd.graph.Node | None) -> list[tuple[torch.autograd.graph.Node, str]]:
        """For each stretch of sequence numbers that one forward part created (``marks``),
        the node of the graph under ``root`` that backward runs first in it (the highest
        number), and the backward part it starts."""
        starts = [seq for seq, _ in self.marks]
        first: dict[int, tuple[int, torch.autograd.graph.Node]] = {}
        seen, todo = set(), [root] if root is not None else []
        while todo:
            node = todo.pop()
            seq = node._sequence_nr()
            if seq == _ACCUMULATE_GRAD or seq in seen:
                continue
            seen.add(seq)
            stretch = bisect.bisect_right(starts, seq) - 1
            if stretch not in first or seq > first[stretch][0]:
                first[stretch] = seq, node
            todo += [nxt for nxt, _ in node.next_functions if nxt is not None]
        return [(node, _BACKWARD_OF.get(self.marks[k][1] if k >= 0 else None, "losses_backward"))
                for k, (_, node) in first.items()]


@dataclass
class StageTiming:
    stage: str
    steps: int
    start: int
    """The first timed step of the stage's schedule."""
    gaussians: float
    """Mean per step."""
    renders: float
    """Renders per step (pgsr renders a neighbour too)."""
    pairs: float | None
    """Pixel–Gaussian pairs composited per step, all renders (None: gsplat)."""
    step_ms: float
    step_median_ms: float
    """The median step: far below the mean when other jobs took the cores for a while."""
    parts_ms: dict[str, float]
    """Mean ms per step of each of :data:`STEP_PARTS`; they sum to ``step_ms``."""
    peak_mb: float
    device: str
    threads: int
    uncounted_ms: float
    """Per step, the bench's walk of the graph before each backward: left out of ``step_ms``."""


def _part_timer(trainer: Trainer, profiler: StepProfiler, counts: dict, ticks: list[float]):
    """The timer of the step's parts (:func:`eve3d.core.timing.step_part`), each charged by
    ``profiler`` (see :func:`profile_steps`); ``counts`` and ``ticks`` receive the renders,
    pairs and steps."""
    def timed(part: str, fn: Callable, args: tuple, kwargs: dict):
        if part == "backward":
            return profiler.backward(fn, *args, **kwargs)
        if part == "optimizer":
            counts["gaussians"] += len(trainer.model)
            ticks.append(time.perf_counter() - profiler.overhead)
        out = profiler.call(part, fn, *args, **kwargs)
        if part == "projection":
            counts["renders"] += 1
            counts["pairs"] += out.n_pairs or 0
        return out
    return timed


def profile_steps(trainer: Trainer, loss: LossTerms, events: Callable[[int], None] | None, start: int, warmup: int,
                  steps: int) -> StageTiming:
    """Run ``warmup`` then ``steps`` steps of ``trainer`` from step ``start`` of its schedule
    and return the mean time of each part of the timed steps.

    Method (the training code marks its parts with :func:`eve3d.core.timing.step_part`,
    plain calls but while this installs its timer, so it changes nothing and names none of
    them):

    - forward: ``Trainer.render`` is charged to projection forward, the backend's entry
      (``cpu.rasterize``: the depth sort and pixel boxes, then the C++ tile compositing;
      ``pairs.rasterize``; ``rasterize_gsplat``) to rasterise forward, the stage's loss
      function to losses forward, ``TrainState.optimizer_step`` and ``TrainState.densify``
      to theirs. Each part is charged its self time: a render inside the loss (pgsr's
      neighbour) is not the loss's, the compositing is not the render's. So projection
      forward is everything ``render_model`` does around the compositing: SH colours,
      rotations, planar features, the EWA projection, the outputs' depth division.
    - backward: the step's ``backward(loss)`` is timed. On the CPU autograd runs the graph's nodes in
      decreasing sequence number, the reverse of their creation, so each forward part's
      stretch of creation runs as one stretch of backward. The timer walks the graph first
      (not counted) and puts a pre-hook on the node that starts each stretch; when it fires,
      the time from there on is that part's backward: the compositing's (rasterise
      backward), the render's (projection backward), anything else's (losses backward).
      This is the boundary rule "losses until the gradient reaches the render outputs,
      rasteriser until it reaches the projection's outputs, projection until the inputs",
      applied to every render of the step in turn.
    - other: the step's wall time less the parts (view choice, loss sum, progress bar, events).

    On CUDA every boundary synchronises the device, which serialises it: the parts then
    add up, but the step is slower than an unsynchronised one.
    """
    import torch

    st = trainer.state
    cuda_device = trainer.device.type == "cuda"
    profiler = StepProfiler(torch.cuda.synchronize if cuda_device else lambda: None)
    counts = {"gaussians": 0, "renders": 0, "pairs": 0}
    ticks: list[float] = []  # when each timed step reached the optimiser (the bench's own time left out)
    st.step = start
    st.densify_stats["birth"].fill_(start)  # the first model is born here: no pruning by views seen before
    with timing_step_parts(_part_timer(trainer, profiler, counts, ticks)):
        timed_loss = functools.partial(profiler.call, "losses", loss)
        trainer.run(timed_loss, events, until=start + warmup)
        profiler.reset()
        counts.update(dict.fromkeys(counts, 0))
        ticks[:] = [time.perf_counter()]
        trainer.run(timed_loss, events, until=start + warmup + steps)
        wall = time.perf_counter() - ticks[0] - profiler.overhead
    done = st.step - start - warmup
    if done != steps:
        raise Eve3dError(f"{trainer.name}: ran {done} of {steps} timed steps (the schedule has "
                         f"{trainer.settings.iterations} iterations; start {start}, warm-up {warmup})")
    parts = {k: 1e3 * v / steps for k, v in profiler.seconds.items()}
    parts["other"] = 1e3 * wall / steps - sum(parts.values())
    ticks[-1] = ticks[0] + wall  # from one optimiser step to the next: one step each
    peak = torch.cuda.max_memory_allocated() / 2**20 if cuda_device else peak_rss_mb()
    return StageTiming(trainer.name, steps, start + warmup, counts["gaussians"] / steps, counts["renders"] / steps,
                       counts["pairs"] / steps if counts["pairs"] else None, 1e3 * wall / steps,
                       1e3 * float(np.median(np.diff(ticks))), parts, peak, trainer.device.type,
                       torch.get_num_threads(), 1e3 * profiler.overhead / steps)


def stage_settings_for(stage: str, config: dict, gaussians: int):
    """The settings of ``stage`` (``pretrain`` or a trained method) under ``config``, without
    checkpoints, drawing ``gaussians`` prior points where the method starts from the priors
    (from them alone: with the SfM points too, ``init: both``, it would start from twice as many)."""
    from eve3d.config import method_settings, stage_settings
    from eve3d.core.settings import PretrainSettings

    if stage == "pretrain":
        return stage_settings(PretrainSettings, "pretrain", config, checkpoint_every=0)
    settings = method_settings(stage, config, "--stages", checkpoint_every=0, init_prior_points=gaussians)
    return replace(settings, init="priors") if settings.init == "both" else settings


def time_training(scene_dir: str, stage: str, config: dict, gaussians: int, start: int, warmup: int, steps: int,
                  priors_dir: str | None = None) -> StageTiming:
    """:func:`profile_steps` of ``stage`` on the dataset ``scene_dir``, set up as its job
    would be (in a scratch folder, nothing written)."""
    import tempfile
    from pathlib import Path

    from eve3d.core.io import load_scene
    from eve3d.joint import setup_joint
    from eve3d.pretrain import setup_pretrain

    settings = stage_settings_for(stage, config, gaussians)
    scene = load_scene(scene_dir)
    with tempfile.TemporaryDirectory() as work:
        if stage == "pretrain":
            run = setup_pretrain(scene, Path(work), settings)
            trainer, loss, events = run.trainer, run.loss, run.events
        else:
            run = setup_joint(scene, Path(work), settings, Path(priors_dir) if priors_dir else None)
            trainer, loss, events = run.trainer, run.loss, None
        return profile_steps(trainer, loss, events, start, warmup, steps)


def _time_training_in_child(args: tuple) -> StageTiming:
    return time_training(*args)


def default_start(config: dict) -> int:
    """The first step at which every term of the joint stage is on (dn_from, mv_from,
    prior_from, joint_from): cpu preset 500."""
    settings = stage_settings_for("pgsr", config, 1)
    return max(settings.dn_from, settings.mv_from, settings.prior_from, settings.joint_from)


def bench_training(stages: Sequence[str] = TRAINING_STAGES, steps: int = 30, warmup: int = 3, gaussians: int = 35_000,
                   config: dict | None = None, start: int | None = None) -> dict:
    """:func:`profile_steps` of each stage on the generated object (the config's ``synthetic``
    size; cpu preset unless ``config`` says otherwise), each in a fresh process (peak = its own).

    The model has ``gaussians`` Gaussians from the start, as many as the cpu preset's runs
    reach: the object is generated with that many sparse points (pretrain's and pgsr's
    initialisation) and eve3d draws that many prior points. The priors are the oracle's
    (exact depth by ray casting): as costly to train on as stereo priors, and cheap to make.
    """
    import os
    import tempfile
    from pathlib import Path

    from eve3d.config import job_config
    from eve3d.core.io import load_scene
    from eve3d.core.methods import uses_priors
    from eve3d.core.settings import SyntheticSettings
    from eve3d.core.settings_fields import from_mapping
    from eve3d.priors.oracle import priors_from_mesh
    from eve3d.synth import generate

    config = job_config() if config is None else config
    synthetic = from_mapping(SyntheticSettings, config.get("synthetic") or {}, "synthetic")
    start = default_start(config) if start is None else start
    settings = {stage: stage_settings_for(stage, config, gaussians) for stage in stages}
    for stage, stage_settings in settings.items():
        if start + warmup + steps > stage_settings.iterations:
            raise Eve3dError(f"{stage}: steps {start}..{start + warmup + steps} run past its "
                             f"{stage_settings.iterations} iterations")
    ctx = multiprocessing.get_context("spawn")
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir = generate("object", Path(tmp) / "object", views=synthetic.views, width=synthetic.width,
                             height=synthetic.height, seed=synthetic.seed, surface_samples=gaussians)
        priors = None
        if any(stage != "pretrain" and uses_priors(asdict(stage_settings))
               for stage, stage_settings in settings.items()):
            priors = Path(tmp) / "priors"
            priors_from_mesh(load_scene(scene_dir), priors, preview=False)
        rows = []
        with mock.patch.dict(os.environ, {"TQDM_DISABLE": "1"}):  # no progress bars in the children
            for stage in stages:
                args = str(scene_dir), stage, config, gaussians, start, warmup, steps, priors and str(priors)
                rows.append(in_child(ctx, _time_training_in_child, args))
    resolution = settings[stages[0]].resolution
    return {"scene": f"object {synthetic.width}x{synthetic.height}, {synthetic.views} views",
            "resolution": f"{round(synthetic.width * resolution)}x{round(synthetic.height * resolution)}",
            "priors": "oracle" if priors else None, "gaussians_at_start": gaussians, "warmup": warmup,
            "load_average": [load_before, os.getloadavg()[0]], "stages": [asdict(r) for r in rows]}


def format_training_table(report: dict) -> str:
    """Per stage (columns) the mean ms of each part of a step, their total, and the model's size."""
    stages = report["stages"]
    w = max(9, *(len(r["stage"]) for r in stages))
    label_w = max(len(label) for label in STEP_PARTS.values())

    def row(label, cells):
        return f"{label:<{label_w}} " + " ".join(f"{c:>{w}}" for c in cells)

    head = row("ms per step", [r["stage"] for r in stages])
    lines = [head, "-" * len(head)]
    lines += [row(label, [f"{r['parts_ms'][k]:.1f}" for r in stages]) for k, label in STEP_PARTS.items()]
    lines += ["-" * len(head), row("step", [f"{r['step_ms']:.1f}" for r in stages]),
              row("median step", [f"{r['step_median_ms']:.1f}" for r in stages]), ""]
    lines += [row("Gaussians", [f"{r['gaussians']:,.0f}" for r in stages]),
              row("renders per step", [f"{r['renders']:g}" for r in stages]),
              row("pairs per step", ["-" if r["pairs"] is None else f"{r['pairs']:,.0f}" for r in stages]),
              row("peak MB", [f"{r['peak_mb']:.0f}" for r in stages])]
    first, (load_before, load_after) = stages[0], report["load_average"]
    lines += ["", (f"{report['scene']}, trained at {report['resolution']}; steps {first['start']}.."
                   f"{first['start'] + first['steps'] - 1} of each schedule after {report['warmup']} warm-up steps, "
                   f"from {report['gaussians_at_start']:,} Gaussians"),
              (f"{first['device']}, {first['threads']} threads; load average (1 min) {load_before:.1f} before, "
               f"{load_after:.1f} after")]
    if report["priors"]:
        lines.append(f"stereo priors: {report['priors']} (exact depth: for timing only)")
    return "\n".join(lines)


# --- scale ---------------------------------------------------------------------------------


def run_bench_training(config: dict, stages: Sequence[str] = TRAINING_STAGES, steps: int = 30, warmup: int = 3,
                       gaussians: int = 35_000, start: int | None = None, as_json: bool = False) -> None:
    """``eve3d bench training``: the table (or JSON) of :func:`bench_training`."""
    import json

    report = bench_training(stages, steps, warmup, gaussians, config, start)
    print(json.dumps(report, indent=2) if as_json else format_training_table(report))
