"""``eve3d bench scale``: the whole pipeline at a real size, and each stage's peak memory (``--memory``)."""
from __future__ import annotations

import json
import multiprocessing
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from unittest import mock

from eve3d.core.errors import Eve3dError
from eve3d.tools.bench.common import in_child, peak_rss_mb

SCALE_KIND = "room"
"""The generated scene ``eve3d bench scale`` runs (a Meetingroom-like room seen from inside)."""
SCALE_METHODS = ("pgsr", "eve3d")
"""The methods it trains, meshes and scores by default (the workflow's trained ones)."""
SCALE_SIZE = {"pipeline": (300, 960, 540), "memory": (300, 1920, 1080)}
"""Default views, width and height of each mode."""
GT_POINTS = 10_000_000
"""Points of the ground-truth clouds (and synthetic samples) the memory mode scores against."""
MEMORY_PROTOCOLS = ("synthetic", "tnt", "dtu")
MEMORY_IMAGE_DIVISOR = 4
"""The memory mode generates its photos at 1/4 of the size its depth maps are made and fused
at (the fusion reads each photo at the map's size): ray casting and shading 300 photos of
1920×1080 takes longer than what it measures (docs/results.md, "Figures behind the code's
choices")."""
DTU_VIEWS = 49
"""Views of the memory mode's DTU stand-in (a scan has 49)."""


@dataclass
class StageRun:
    """One stage, run in a process of its own."""

    stage: str
    detail: str
    seconds: float
    peak_mb: float
    """The process's peak resident memory."""
    load: float
    """The 1-minute load average when it ended (other jobs on the machine show up here)."""
    error: str | None = None
    """Why it failed (the last line of its log); None when it ran through."""

    @property
    def label(self) -> str:
        return f"{self.stage} {self.detail}".strip()


_PEAK_AT_EXIT = ("import atexit, sys\n"
                 "from eve3d.tools.bench.common import peak_rss_mb\n"
                 "out = sys.argv.pop(1)\n"
                 "atexit.register(lambda: open(out, 'w').write(str(peak_rss_mb())))\n"
                 "from eve3d.cli import main\n"
                 "sys.exit(main(sys.argv[1:]))\n")
"""``python -c`` code that runs ``eve3d ARGS`` and writes its peak memory to a file at exit."""


def run_stage(stage: str, detail: str, args: Sequence, log: Path) -> StageRun:
    """``eve3d ARGS``, as the workflow runs a job, in a child process writing to ``log``:
    its wall time and its own peak memory (VmHWM, which the child writes as it exits: a
    child's rusage starts from its parent's peak; NaN when it was killed). A failure is
    returned with the log's last line as its ``error``."""
    import os
    import subprocess
    import sys

    from eve3d.config import REPO

    log.parent.mkdir(parents=True, exist_ok=True)
    peak = log.with_suffix(".peak_mb")
    # this checkout's package, wherever the bench runs from (the workflow's jobs do the same)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(REPO), os.environ.get("PYTHONPATH"))))}
    start = time.perf_counter()
    with open(log, "w") as out:
        code = subprocess.run([sys.executable, "-c", _PEAK_AT_EXIT, peak, *map(str, args)], stdout=out,
                              stderr=subprocess.STDOUT, env=env).returncode
    seconds = time.perf_counter() - start
    error = None
    if code:
        last = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()][-1:]
        error = f"exit {code}: {last[0] if last else 'no output'} (log {log})"
    return StageRun(stage, detail, seconds, float(peak.read_text()) if peak.exists() else float("nan"),
                    os.getloadavg()[0], error)


def run_setup(stage: str, detail: str, fn: Callable, args: tuple) -> StageRun:
    """``fn(args)`` (which returns :func:`peak_rss_mb`) in a fresh process, timed."""
    import os

    start = time.perf_counter()
    with mock.patch.dict(os.environ, {"TQDM_DISABLE": "1"}):  # the bench prints each step when it ends
        peak = in_child(multiprocessing.get_context("spawn"), fn, args)
    return StageRun(stage, detail, time.perf_counter() - start, peak, os.getloadavg()[0])


def pipeline_stages(work: Path, config_file: Path, kind: str, methods: Sequence[str]) -> list[tuple[str, str, list]]:
    """The workflow's jobs on a generated scene, in its order, as (stage, detail, ``eve3d``
    arguments): synth, pretrain, stereo render, sgbm priors, then per method its training,
    its mesh (TSDF of its rendered depth) and its evaluation (synthetic protocol)."""
    from eve3d.core.layout import PRETRAIN, Layout

    layout, name, cfg = Layout(work), "scene", ["--config", config_file]
    data, priors = layout.input(name), layout.priors(name, "sgbm")
    stages = [("synth", kind, ["synth", kind, data, *cfg]),
              ("pretrain", "", ["pretrain", "--scene", data, "--out", layout.pretrain(name), *cfg]),
              ("stereo render", "", ["stereo-render", "--scene", data, "--model", layout.model(name, PRETRAIN),
                                     "--out", layout.stereo(name), *cfg]),
              ("stereo depth", "sgbm", ["stereo-depth", "--backend", "sgbm", "--scene", data, "--stereo",
                                        layout.stereo(name), "--out", priors, *cfg])]
    for m in methods:
        stages += [("joint", m, ["joint", "--method", m, "--scene", data, "--priors", priors, "--out",
                                 layout.method(name, m), *cfg]),
                   ("mesh", m, ["mesh", "--scene", data, "--depth", layout.depth(name, m), "--out",
                                layout.mesh(name, m), *cfg]),
                   ("evaluate", m, ["evaluate", "--protocol", "synthetic", "--scene", data, "--mesh",
                                    layout.mesh(name, m), "--gt", layout.generated_gt_mesh(name), "--out",
                                    layout.metrics(name, m), *cfg])]
    return stages


def generate_with_depth(args: tuple) -> float:
    """The generated scene ``kind`` in ``data`` with photos at 1/``divisor`` of ``size`` and
    the exact depth of every view at ``size`` in ``depth`` (oracle ray casting, the maps'
    layout of every depth source, no previews); this process's peak memory."""
    from dataclasses import replace
    from pathlib import Path

    from eve3d.core.io import load_scene
    from eve3d.priors.oracle import priors_from_mesh
    from eve3d.synth import generate

    kind, data, depth, views, (width, height), divisor = args
    generate(kind, Path(data), views=views, width=width // divisor, height=height // divisor, supersample=1,
             matcher="sequential")  # exhaustive matching of hundreds of views would dwarf the stages timed
    scene = load_scene(Path(data))
    priors_from_mesh(replace(scene, cameras=[cam.scaled(width / cam.width) for cam in scene.cameras]), Path(depth),
                  preview=False)
    return peak_rss_mb()


def write_ground_truth(args: tuple) -> float:
    """A benchmark download with ``points`` ground-truth points (``eve3d.tools.standin``) of the
    generated scene in ``data``: T&T (``Barn``: GT points sampled on the whole GT mesh) or
    DTU (``scan24``: STL points on the GT surface the cameras see); this process's peak memory."""
    from pathlib import Path

    from eve3d.core.io import load_scene
    from eve3d.tools.standin import standin, write_dtu_release, write_tnt_release

    benchmark, data, root, points = args
    scene = load_scene(Path(data))
    if benchmark == "tnt":
        write_tnt_release(scene, Path(root), standin("tnt")[1], gt_points=points)
    else:
        write_dtu_release(scene, Path(root), standin("dtu")[1], stl_points=points)
    return peak_rss_mb()


def memory_stages(work: Path, config_file: Path, kind: str, views: int, size: tuple[int, int], gt_points: int,
                  protocols: Sequence[str]) -> list[tuple[str, str, Callable | list, tuple | None]]:
    """The memory mode's steps, in order, as (stage, detail, ``eve3d`` arguments or a set-up
    function, its arguments): the scene and its exact depth at ``size``, the TSDF of those
    maps; then per protocol its ground truth of ``gt_points`` points and the evaluation of
    a fused mesh against it (synthetic: the room's mesh with ``gt_points`` samples of each
    surface; tnt: the room's mesh against a ``Barn`` of ``gt_points`` GT points; dtu: a
    generated object's fused mesh against an STL of ``gt_points`` points)."""
    from eve3d.core.datasets import dtu_files
    from eve3d.core.layout import METRICS_FILE as METRICS
    from eve3d.tools.standin import standin

    cfg, w, h = ["--config", config_file], *size
    data, depth, mesh = work / kind, work / f"{kind}_depth", work / f"{kind}_mesh.ply"
    at = f"{views} views {w}x{h}"
    steps = [("set-up", f"{kind}, exact depth at {w}x{h}", generate_with_depth,
              (kind, data, depth, views, size, MEMORY_IMAGE_DIVISOR)),
             ("mesh", f"{kind}, {at}", ["mesh", "--scene", data, "--depth", depth, "--out", mesh, *cfg], None)]
    evaluate = ["evaluate", "--out"]
    million = f"{gt_points / 1e6:g}M GT points"
    for protocol in protocols:
        if protocol == "synthetic":
            steps.append(("evaluate", f"synthetic, {gt_points / 1e6:g}M samples",
                          [*evaluate, work / "synthetic" / METRICS, "--protocol", "synthetic", "--scene", data,
                           "--mesh", mesh, "--gt", data / "gt" / "mesh.ply", "--samples", gt_points, *cfg], None))
        elif protocol == "tnt":
            root = work / "tnt"
            steps += [("set-up", f"tnt, {million}", write_ground_truth, ("tnt", data, root, gt_points)),
                      ("evaluate", f"tnt, {million}", [*evaluate, root / METRICS, "--protocol", "tnt", "--scene",
                                                       root / standin("tnt")[1], "--mesh", mesh, *cfg], None)]
        elif protocol == "dtu":
            root, obj = work / "dtu", work / "object"
            files = dtu_files(root, standin("dtu")[1])
            steps += [("set-up", f"object, {DTU_VIEWS} views, exact depth at {w}x{h}", generate_with_depth,
                       ("object", obj, work / "object_depth", DTU_VIEWS, size, MEMORY_IMAGE_DIVISOR)),
                      ("mesh", f"object, {DTU_VIEWS} views {w}x{h}", ["mesh", "--scene", obj, "--depth",
                                                                       work / "object_depth", "--out",
                                                                       work / "object_mesh.ply", *cfg], None),
                      ("set-up", f"dtu, {million}", write_ground_truth, ("dtu", obj, root, gt_points)),
                      ("evaluate", f"dtu, {million}", [*evaluate, root / METRICS, "--protocol", "dtu", "--scene",
                                                       root / standin("dtu")[1], "--mesh", work / "object_mesh.ply",
                                                       "--gt", files["stl"], "--obs-mask", files["obs_mask"],
                                                       "--plane", files["plane"], *cfg], None)]
        else:
            raise Eve3dError(f"bench scale: protocol {protocol!r}: choose among {', '.join(MEMORY_PROTOCOLS)}")
    return steps


def machine() -> str:
    """The CPU model, its cores and the memory of this machine, in words."""
    import os

    model = "CPU"
    try:
        with open("/proc/cpuinfo") as info:
            model = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), model)
    except OSError:
        pass
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{model}, {os.cpu_count()} cores, {memory:.0f} GiB"


def bench_scale(work: Path, config: dict, memory: bool = False, kind: str = SCALE_KIND,
                methods: Sequence[str] = SCALE_METHODS, gt_points: int = GT_POINTS,
                protocols: Sequence[str] = MEMORY_PROTOCOLS) -> dict:
    """Each stage of the pipeline on a large generated scene, each in a process of its own,
    in ``work`` (an empty or missing folder): its wall time and peak memory.

    ``config`` is the job configuration (``eve3d.config.job_config``: the preset, ``--set``);
    its ``synthetic`` section gives the scene's views and size. The default mode runs the
    workflow's jobs: synth, pretrain, stereo render, sgbm priors and per method its
    training, mesh and evaluation. ``memory`` measures the two memory targets without
    training: the TSDF of the scene's exact depth maps at that size, and evaluations against
    ``gt_points`` ground-truth points (:func:`memory_stages`)."""
    import os
    import sys

    import yaml

    from eve3d.core.layout import EVALUATION, METRICS_FILE, RECORD
    from eve3d.core.settings import MeshSettings, SyntheticSettings
    from eve3d.core.settings_fields import from_mapping

    synthetic = from_mapping(SyntheticSettings, config.get("synthetic") or {}, "synthetic")
    coarsen = from_mapping(MeshSettings, config.get("mesh") or {}, "mesh").coarsen
    if work.exists() and any(work.iterdir()):
        raise Eve3dError(f"{work}: not empty; give a new or empty folder for the bench's data")
    work.mkdir(parents=True, exist_ok=True)
    config_file = work / "config.yaml"
    config_file.write_text(yaml.safe_dump({**config, "preset": None}, sort_keys=False))
    load_before = os.getloadavg()[0]
    size = (synthetic.width, synthetic.height)
    if memory:
        steps = memory_stages(work, config_file, kind, synthetic.views, size, gt_points, protocols)
    else:
        steps = [(*step, None) for step in pipeline_stages(work, config_file, kind, methods)]
    rows, failed = [], set()
    for i, (stage, detail, run, args) in enumerate(steps):
        if detail in failed:  # a method's mesh and evaluation after its training failed
            continue
        if callable(run):
            row = run_setup(stage, detail, run, args)
        else:
            row = run_stage(stage, detail, run, work / "logs" / f"{i:02d}_{stage.replace(' ', '_')}.log")
        print(f"bench scale: {row.label}: {row.seconds:.0f} s, peak {row.peak_mb:.0f} MB"
              + (f", failed ({row.error})" if row.error else ""), file=sys.stderr, flush=True)
        rows.append(row)
        if row.error:
            if memory or detail not in methods:  # what every later stage reads
                raise Eve3dError(f"bench scale: {row.label} failed, {row.error}")
            failed.add(detail)
    scores = {}
    for path in sorted(work.rglob(METRICS_FILE)):
        m = json.loads(path.read_text())
        if isinstance(m, dict) and m.get(RECORD) == EVALUATION:
            scores[str(path.parent.relative_to(work))] = {
                k: m.get(k) for k in ("protocol", "precision", "recall", "fscore", "chamfer", "n_recon", "n_gt")}
    return {"mode": "memory" if memory else "pipeline", "preset": config.get("preset", "cpu"),
            "scene": f"{kind}, {synthetic.views} views, {size[0]}x{size[1]}", "mesh_coarsen": coarsen,
            "iterations": {s: (config.get(s) or {}).get("iterations") for s in ("pretrain", "joint")},
            "machine": machine(), "load_average": [load_before, os.getloadavg()[0]], "work": str(work),
            "stages": [asdict(r) for r in rows], "scores": scores}


def format_scale_report(report: dict) -> str:
    """The stages' table (wall seconds, peak MB, load at the end), their total, the
    largest peak, the scores, the scene and the machine."""
    rows = report["stages"]
    w = max(len(r["detail"]) for r in rows + [{"detail": "detail"}])
    head = f"{'stage':<14} {'detail':<{w}} {'seconds':>8} {'peak MB':>8} {'load':>5}"
    lines = [head, "-" * len(head)]
    lines += [f"{r['stage']:<14} {r['detail']:<{w}} {r['seconds']:>8.0f} {r['peak_mb']:>8.0f} {r['load']:>5.1f}"
              + (f"  FAILED {r['error']}" if r.get("error") else "") for r in rows]
    top = max(rows, key=lambda r: r["peak_mb"])
    total = sum(r["seconds"] for r in rows)
    lines += ["-" * len(head), f"{'total':<14} {'':<{w}} {total:>8.0f} {top['peak_mb']:>8.0f}  "
                               f"({total / 60:.1f} min; largest peak: {top['stage']} {top['detail']}".rstrip() + ")"]
    if report["scores"]:
        lines += ["", f"{'scores':<40} {'precision':>9} {'recall':>7} {'F':>7} {'chamfer':>9}"]

        def cell(v, w, f):
            return f"{'-' if v is None else format(v, f):>{w}}"

        lines += [f"{k:<40} {cell(s['precision'], 9, '.4f')} {cell(s['recall'], 7, '.4f')} "
                  f"{cell(s['fscore'], 7, '.4f')} {cell(s['chamfer'], 9, '.5g')}" for k, s in report["scores"].items()]
    iterations = ", ".join(f"{k} {v}" for k, v in report["iterations"].items() if v is not None)
    before, after = report["load_average"]
    lines += ["", f"{report['mode']} mode: {report['scene']}; preset {report['preset']}, "
                  f"mesh.coarsen {report['mesh_coarsen']:g}"
              + (f" ({iterations} iterations)" if report["mode"] == "pipeline" and iterations else ""),
              f"{report['machine']}; load average (1 min) {before:.1f} before, {after:.1f} after",
              f"data and logs in {report['work']}"]
    return "\n".join(lines)


def run_bench_scale(config_file: str | None, sets: list[str], *, memory: bool = False, kind: str = SCALE_KIND,
                    size: tuple[int | None, int | None, int | None] = (None, None, None),
                    iterations: int | None = None, methods: Sequence[str] | None = None,
                    gt_points: int | None = None, protocols: Sequence[str] | None = None, work: str | None = None,
                    as_json: bool = False) -> None:
    """``eve3d bench scale``: the table (or JSON) of :func:`bench_scale`; ``size`` (views,
    width, height) and ``iterations`` override :data:`SCALE_SIZE` and the config's."""
    import contextlib
    import tempfile

    from eve3d.config import job_config

    defaults = SCALE_SIZE["memory" if memory else "pipeline"]
    flags = {f"synthetic.{k}": given or default for k, given, default in zip(("views", "width", "height"), size, defaults)}
    if iterations is not None:
        flags.update({"pretrain.iterations": iterations, "joint.iterations": iterations})
    config = job_config(config_file, sets, flags)
    with contextlib.ExitStack() as stack:
        work = Path(work) if work else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="eve3d-scale-")))
        report = bench_scale(work, config, memory=memory, kind=kind, methods=methods or SCALE_METHODS,
                             gt_points=gt_points or GT_POINTS, protocols=protocols or MEMORY_PROTOCOLS)
    print(json.dumps(report, indent=2) if as_json else format_scale_report(report))
