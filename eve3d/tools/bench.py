"""``eve3d bench``: speed and memory benchmarks that print a table (never timed tests)."""
from __future__ import annotations

import bisect
import contextlib
import functools
import json
import math
import multiprocessing
import resource
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from unittest import mock

import numpy as np

from eve3d.core.scene import Eve3dError
from eve3d.evaluate.depth import WEAK_TEXTURE

if TYPE_CHECKING:
    import torch

    from eve3d.gaussians.training import LossTerms, Trainer

RASTERIZER_SIZES = ((5_000, 160, 120), (20_000, 320, 240), (100_000, 640, 480))


def surface_gaussians(n: int, width: int, height: int, seed: int = 0):
    """N Gaussians of the kind surface training produces, and a camera that sees them.

    Centres are sampled on the synthetic object and table (the ``eve3d synth object``
    meshes, table cropped to the cameras' view); each Gaussian is a disc in the surface's
    tangent plane with in-plane standard deviations of 0.4–0.8 × the mean spacing of the
    samples and a thickness of 2 % of that, opacity 0.3–1, random colours. The camera is the
    first of the synthetic object's spiral (3 units away, f = 1.1 × width).
    """
    import trimesh
    from scipy.spatial.transform import Rotation

    from eve3d.synth import object_cameras, object_parts

    rng = np.random.default_rng(seed)
    meshes = []
    for part in object_parts():
        m = trimesh.Trimesh(np.asarray(part.mesh.vertices), np.asarray(part.mesh.triangles), process=False)
        meshes.append(m)
    mesh = trimesh.util.concatenate(meshes)
    keep = np.abs(mesh.triangles_center[:, :2]).max(axis=1) < 1.2
    mesh.update_faces(keep)
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    normals = mesh.face_normals[faces]
    spacing = math.sqrt(mesh.area / n)
    tangent_scale = spacing * rng.uniform(0.4, 0.8, (n, 1))
    scales = np.hstack([tangent_scale, tangent_scale * rng.uniform(0.6, 1.0, (n, 1)), 0.02 * tangent_scale])
    # Rotation whose third axis is the surface normal, with a random spin about it.
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    spin = rng.uniform(0, 2 * np.pi, (n, 1))
    u, v = np.cos(spin) * u + np.sin(spin) * v, -np.sin(spin) * u + np.cos(spin) * v
    xyzw = Rotation.from_matrix(np.stack([u, v, normals], axis=2)).as_quat()
    cam = object_cameras(1, width, height, np.random.default_rng(seed))[0]
    params = (points, xyzw[:, [3, 0, 1, 2]], scales, rng.uniform(0.3, 1.0, n), rng.uniform(0, 1, (n, 3)))
    return tuple(np.ascontiguousarray(p, dtype=np.float32) for p in params), cam


@dataclass
class RasterizerTiming:
    gaussians: int
    width: int
    height: int
    backend: str
    pairs: int | None
    forward_ms: float
    backward_ms: float
    peak_mb: float


def time_rasterizer(params: tuple[np.ndarray, ...], cam, backend: str = "auto", repeats: int = 5
                    ) -> RasterizerTiming:
    """Median forward and backward times of one render and a loss on every output."""
    import torch

    from eve3d.gaussians.render import render

    device = "cuda" if backend in ("auto", "gsplat") and torch.cuda.is_available() else "cpu"
    params = [torch.from_numpy(p).to(device).requires_grad_(True) for p in params]
    n, width, height = params[0].shape[0], cam.width, cam.height
    target = torch.rand(height, width, 3, generator=torch.Generator().manual_seed(0)).to(device)
    forward, backward = [], []
    for i in range(repeats + 1):  # the first run warms up
        for p in params:
            p.grad = None
        _sync(device)
        t0 = time.perf_counter()
        out = render(*params, cam, backend=backend, absgrad=True)
        _sync(device)
        t1 = time.perf_counter()
        loss = (out.rgb - target).abs().mean() + out.depth.mean() + out.normal.abs().mean()
        loss.backward()
        _sync(device)
        t2 = time.perf_counter()
        if i:
            forward.append(t1 - t0)
            backward.append(t2 - t1)
    peak = torch.cuda.max_memory_allocated() / 2**20 if device == "cuda" else peak_rss_mb()
    return RasterizerTiming(n, width, height, out.backend, out.n_pairs, 1e3 * float(np.median(forward)),
                            1e3 * float(np.median(backward)), peak)


def peak_rss_mb() -> float:
    """This process's peak resident memory. Read from /proc (VmHWM), which starts afresh
    at exec: getrusage's ru_maxrss keeps the spawning parent's peak."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _sync(device: str) -> None:
    if device == "cuda":
        import torch

        torch.cuda.synchronize()


def _time_in_child(args) -> RasterizerTiming:
    return time_rasterizer(*args)


def bench_rasterizer(sizes=RASTERIZER_SIZES, backend: str = "auto", repeats: int = 5) -> list[RasterizerTiming]:
    """Each size in a fresh process that imports only torch and the renderer, so its peak
    memory (whole-process RSS on the CPU, allocator peak on CUDA) is the renderer's own."""
    ctx = multiprocessing.get_context("spawn")
    results = []
    for n, w, h in sizes:
        params, cam = surface_gaussians(n, w, h)
        with ctx.Pool(1) as pool:
            results.append(pool.apply(_time_in_child, ((params, cam, backend, repeats),)))
    return results


def format_rasterizer_table(rows: list[RasterizerTiming]) -> str:
    head = f"{'gaussians':>9} {'width':>5} {'height':>6} {'backend':>7} {'pairs':>10} {'forward ms':>10} " \
           f"{'backward ms':>11} {'peak MB':>8}"
    lines = [head, "-" * len(head)]
    for r in rows:
        pairs = f"{r.pairs:,}" if r.pairs is not None else "-"
        lines.append(f"{r.gaussians:>9,} {r.width:>5} {r.height:>6} {r.backend:>7} {pairs:>10} "
                     f"{r.forward_ms:>10.1f} {r.backward_ms:>11.1f} {r.peak_mb:>8.0f}")
    return "\n".join(lines)


def rasterizer_json(rows: list[RasterizerTiming]) -> str:
    return json.dumps([asdict(r) for r in rows], indent=2)


# --- stereo --------------------------------------------------------------------------------

def stereo_motorcycle(block_size: int = 5, lr_threshold: float = 1.0, wls: bool = False) -> dict:
    """``sgbm`` on the Middlebury Motorcycle pair that scikit-image ships (real photos,
    ground-truth disparity; inf = unknown): density (confident / known pixels), end-point
    error and bad-2.0 (% of confident pixels off by more than 2 px)."""
    from skimage import data

    from eve3d.core.settings import SgbmSettings
    from eve3d.stereo import sgbm_disparity

    left, right, gt = data.stereo_motorcycle()
    known = np.isfinite(gt)
    start = time.perf_counter()
    disp, confidence = sgbm_disparity(left, right, float(np.max(gt[known])),
                                      SgbmSettings(block_size=block_size, lr_threshold=lr_threshold, wls=wls))
    seconds = time.perf_counter() - start
    used = known & (confidence >= 0.5)
    err = np.abs(disp[used] - gt[used])
    return {"data": "Motorcycle (Middlebury, skimage)", "backend": "sgbm+wls" if wls else "sgbm", "size": f"{left.shape[1]}x{left.shape[0]}",
            "density": float(used.sum() / known.sum()), "epe": float(err.mean()),
            "bad2": float((err > 2).mean() * 100), "seconds": seconds}


def prior_accuracy(priors_dir, reference_dir, scene: str = "") -> dict:
    """:func:`eve3d.evaluate.depth.depth_accuracy` of one folder of priors
    (``results/{scene}/priors/{backend}``), named by its backend; on a generated scene's
    weakly textured pixels too, from its photos (``results/{scene}/input/images``)."""
    from pathlib import Path

    from eve3d.core.layout import Layout
    from eve3d.evaluate.depth import depth_accuracy

    scene_dir = Path(priors_dir).parent.parent
    images = Layout(scene_dir.parent).input(scene_dir.name) / "images"
    return {**depth_accuracy(priors_dir, reference_dir, scene, images=images if images.is_dir() else None),
            "backend": Path(priors_dir).name}


def format_stereo_tables(moto: list[dict], priors: list[dict], agreement: list[dict] = ()) -> str:
    lines = ["real pair (Middlebury Motorcycle): confident pixels only",
             "backend  size     density  EPE px  bad-2.0 %  seconds"]
    lines += [f"{r['backend']:<8} {r['size']:<8} {r['density']:7.3f}  {r['epe']:6.3f}  {r['bad2']:9.2f}  "
              f"{r['seconds']:7.2f}" for r in moto]
    if priors:
        lines += ["", "synthetic scenes: priors against the exact depth, confident pixels"]
        lines += prior_lines("scene / priors", [r["data"] for r in priors], priors)
    if agreement:
        lines += ["", "without ground truth: neighbouring views' priors against each other, confident pixels"]
        lines += agreement_lines(agreement)
    return "\n".join(lines)


def agreement_lines(rows: list[dict]) -> list[str]:
    """A table of :func:`eve3d.evaluate.depth.prior_agreement` rows."""
    width = max(len("priors"), *(len(r["data"]) for r in rows))
    lines = [f"{'priors':<{width}} {'density':>8} {'median disagreement':>20} {'over 5 %':>9} {'compared':>9}"]
    for r in rows:
        median = "-" if r["median_disagreement"] is None else f"{r['median_disagreement'] * 100:.2f} %"
        over = "-" if r["disagree_5"] is None else f"{r['disagree_5'] * 100:.1f} %"
        lines.append(f"{r['data']:<{width}} {r['density']:8.3f} {median:>20} {over:>9} {r['compared']:>9,}")
    return lines


def prior_lines(title: str, labels: list[str], rows: list[dict]) -> list[str]:
    """A table of :func:`prior_accuracy` rows, one label each."""
    width = max(len(title), *map(len, labels))
    weak = any("weak_share" in r for r in rows)
    lines = [f"{title:<{width}} {'median signed':>13} {'median rel. error':>17} {'density':>8} {'off >5 %':>9} "
             f"{'off >10 %':>9} {'on empty':>9}" + (f" {'weak texture: share':>19} {'density':>8} {'error':>8}"
                                                   if weak else "")]
    percent = lambda v, f=".2f": "-" if v is None else f"{v * 100:{f}} %"  # noqa: E731
    for label, r in zip(labels, rows):
        line = f"{label:<{width}} "
        if r["median_signed_error"] is None:  # no confident pixel with an exact depth
            line += f"{'-':>13} {'-':>17} {r['density']:8.3f} {'-':>9} {'-':>9} "
        else:
            line += (f"{r['median_signed_error'] * 100:+11.2f} % {r['median_rel_error'] * 100:15.2f} % "
                     f"{r['density']:8.3f} {r['wrong_5'] * 100:7.1f} % {r['wrong_10'] * 100:7.1f} % ")
        line += f"{percent(r.get('on_empty')):>9}"
        if weak:
            line += (f" {percent(r.get('weak_share'), '.1f'):>19} {r.get('weak_density', 0):8.3f} "
                     f"{percent(r.get('weak_rel_error')):>8}")
        lines.append(line)
    if weak:
        lines.append(f"weak texture: pixels with a surface whose photo varies less than {WEAK_TEXTURE:g} grey levels "
                     f"over the matcher's window")
    return lines


# --- evaluation ----------------------------------------------------------------------------

def floater_mesh(gt, floaters: int, subdivide: int, rng: np.random.Generator):
    """The GT mesh, midpoint-subdivided ``subdivide`` times, plus ``floaters`` small random
    triangles in the air above the table: the worst case for a nearest-neighbour search."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(gt).subdivide_midpoint(subdivide) if subdivide else o3d.geometry.TriangleMesh(gt)
    centres = rng.uniform([-1.5, -1.5, 0.1], [1.5, 1.5, 2.0], (floaters, 3))
    corners = centres[:, None, :] + rng.normal(0, 0.01, (floaters, 3, 3))
    air = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(corners.reshape(-1, 3)),
                                    o3d.utility.Vector3iVector(np.arange(3 * floaters).reshape(-1, 3)))
    return mesh + air


def _evaluate_in_child(args) -> dict:
    from pathlib import Path

    from eve3d.core.io import load_scene
    from eve3d.core.scene import Scene
    from eve3d.evaluate import PROTOCOLS, EvalInputs

    scene, mesh, gt = args
    scene = load_scene(scene, check_images=False) if isinstance(scene, (str, Path)) else Scene(**scene)
    start = time.perf_counter()
    m = PROTOCOLS["synthetic"].run(EvalInputs(scene, Path(mesh), Path(mesh).with_suffix(".json"), gt=Path(gt)))
    m["seconds"] = time.perf_counter() - start
    m["peak_mb"] = peak_rss_mb()
    return m


def _in_child(ctx: multiprocessing.context.BaseContext, fn: Callable, args: tuple):
    """``fn(args)`` in a fresh process of ``ctx``."""
    pool = ctx.Pool(1)
    result = pool.apply(fn, (args,))
    pool.close()  # not terminate(): pycolmap's signal handler would print a stack trace
    pool.join()
    return result


def bench_evaluate(meshes: list[tuple[str, str]] = (), scene=None, gt=None) -> list[dict]:
    """Time the synthetic protocol, each run in a fresh process (peak = its RSS): on the
    built-in object's GT plus 1M and 2.2M floating triangles (constructed), then on the
    given (label, mesh) pairs against ``gt`` with the cameras of ``scene``."""
    import tempfile
    from pathlib import Path

    import open3d as o3d

    from eve3d.synth import object_cameras, object_parts

    ctx = multiprocessing.get_context("spawn")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        gt_mesh = o3d.geometry.TriangleMesh()
        for part in object_parts():
            gt_mesh += part.mesh
        gt_path = Path(tmp) / "gt.ply"
        o3d.io.write_triangle_mesh(str(gt_path), gt_mesh)
        cams = {"root": Path(tmp), "cameras": object_cameras(32, 320, 240, np.random.default_rng(0))}
        cases = [(f"GT x64 + {n / 1e6:g}M floaters", floater_mesh(gt_mesh, n, 3, np.random.default_rng(0)))
                 for n in (1_000_000, 2_200_000)]
        jobs = []
        for i, (label, mesh) in enumerate(cases):
            path = Path(tmp) / f"case{i}.ply"
            o3d.io.write_triangle_mesh(str(path), mesh)
            jobs.append((label, len(mesh.triangles), (cams, str(path), str(gt_path))))
        for label, path in meshes:
            jobs.append((label, len(o3d.io.read_triangle_mesh(str(path)).triangles), (str(scene), str(path), str(gt))))
        for label, triangles, args in jobs:
            m = _in_child(ctx, _evaluate_in_child, args)
            rows.append({"mesh": label, "triangles": triangles, **{k: m[k] for k in (
                "seconds", "peak_mb", "precision", "recall", "fscore", "n_recon", "n_gt")}})
    return rows


def format_evaluate_table(rows: list[dict]) -> str:
    w = max(len(r["mesh"]) for r in rows)
    head = f"{'mesh':<{w}} {'triangles':>10} {'seconds':>8} {'peak MB':>8} {'precision':>9} {'recall':>7} {'F':>6}"
    lines = [head, "-" * len(head)]
    lines += [f"{r['mesh']:<{w}} {r['triangles']:>10,} {r['seconds']:>8.1f} {r['peak_mb']:>8.0f} {r['precision']:>9.4f} "
              f"{r['recall']:>7.4f} {r['fscore']:>6.4f}" for r in rows]
    return "\n".join(lines)


def methods_report(config: dict) -> dict:
    """The table of ``eve3d bench methods`` from a finished workflow run of ``config``
    (resolved): per scene and method the synthetic protocol's scores and the wall time of
    the method's own stages (joint + mesh; the stages the priors share are listed per
    scene), the means over scenes, and per scene the depth maps' accuracy against the oracle
    depth: D* (``priors/{backend}``), every learnable method's final D̂ and every trained
    method's rendered depth D (the maps its mesh fuses)."""
    from eve3d.core.layout import Layout, benchmark_seconds, job_name
    from eve3d.core.methods import methods

    layout, backend = Layout(config["results"]), config["stereo"]["backend"]
    known = methods(config.get("variants"))
    rows, shared, priors = [], {}, []
    for scene, sc in config["scenes"].items():
        for name in sc.get("methods", config["methods"]):
            path = layout.metrics(scene, name)
            if not path.is_file():
                continue
            m = json.loads(path.read_text())
            stages = [layout.benchmark(scene, "mesh", name)] + (
                [layout.benchmark(scene, "joint", name)] if known[name].trains else [])
            times = [benchmark_seconds(p) for p in stages]
            rows.append({"scene": scene, "method": name, **{k: m.get(k) for k in (
                "chamfer", "precision", "recall", "fscore")},
                "seconds": None if None in times else sum(times)})
        shared[scene] = {job_name(*job): benchmark_seconds(layout.benchmark(scene, *job))
                         for job in (("pretrain",), ("stereo_render",), ("stereo_depth", backend))}
        oracle = layout.priors(scene, "oracle")
        if oracle.is_dir():
            star = layout.priors(scene, backend)
            if star.is_dir():
                priors.append({**prior_accuracy(star, oracle, scene), "priors": f"D* ({backend})"})
            for name in sc.get("methods", config["methods"]):
                for maps, what in ((layout.learned_priors(scene, name), "D̂"), (layout.depth(scene, name), "D")):
                    if maps.is_dir():
                        priors.append({**prior_accuracy(maps, oracle, scene), "priors": f"{what} of {name}"})
    means = []
    for name in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == name]
        mean = lambda k: (float(np.mean([r[k] for r in mine])) if all(r[k] is not None for r in mine)  # noqa: E731
                          else None)
        means.append({"scene": f"mean of {len(mine)}", "method": name,
                      **{k: mean(k) for k in ("chamfer", "precision", "recall", "fscore", "seconds")}})
    return {"rows": rows, "means": means, "shared_seconds": shared, "priors": priors}


def format_methods_report(report: dict) -> str:
    cell = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    head = f"{'scene':<22} {'method':<18} {'chamfer':>9} {'precision':>9} {'recall':>7} {'F':>7} {'seconds':>8}"
    lines = [head, "-" * len(head)]
    for r in report["rows"] + report["means"]:
        lines.append(f"{r['scene']:<22} {r['method']:<18} {cell(r['chamfer'], '9.5f')} {cell(r['precision'], '9.4f')} "
                     f"{cell(r['recall'], '7.4f')} {cell(r['fscore'], '7.4f')} {cell(r['seconds'], '8.0f')}")
    lines += ["", "seconds = the method's own stages (joint + mesh); shared by every method that uses the priors:"]
    for scene, stages in report["shared_seconds"].items():
        lines.append(f"  {scene}: " + ", ".join(f"{k} {cell(v, '.0f')} s" for k, v in stages.items()))
    if report["priors"]:
        lines += ["", "depth against the exact depth, on confident pixels (priors: M^c; rendered D: alpha ≥ 0.5);",
                  "on empty: the share of the pixels without a surface that have a confident depth (floaters);",
                  "signed: positive = too far"]
        lines += prior_lines("scene / priors", [f"{r['data']} / {r['priors']}" for r in report["priors"]],
                             report["priors"])
    return "\n".join(lines)


def real_report(config: dict) -> dict:
    """The table of ``eve3d bench real`` from a finished workflow run of ``config``
    (resolved): per scene the photos and the views SfM registered, every job's wall time,
    the held-out PSNR/SSIM of the pretrain and of each trained method, the priors' density
    and the agreement of neighbouring views' priors, and each mesh's triangles and extent
    against the sparse points' 5–95 % box."""
    from pathlib import Path

    import open3d as o3d

    from eve3d.core.io import load_scene
    from eve3d.core.layout import PRETRAIN, Layout, benchmark_seconds
    from eve3d.core.photos import scan_photos
    from eve3d.evaluate.depth import prior_agreement
    from eve3d.mesh import extent_report

    layout, backend = Layout(config["results"]), config["stereo"]["backend"]
    scenes = []
    for name, sc in config["scenes"].items():
        posed = layout.sfm(name) if layout.sfm(name).is_dir() else Path(sc["path"])
        scene = load_scene(posed, check_images=False)
        row = {"scene": name, "photos": len(scan_photos(Path(sc["path"]) / "images")), "registered": len(scene.cameras),
               "points": 0 if scene.points is None else len(scene.points)}
        row["seconds"] = {p.stem: benchmark_seconds(p) for p in sorted(layout.benchmarks(name).glob("*.tsv"))}
        held = {}
        pre = layout.train_metrics(name, PRETRAIN)
        if pre.is_file():
            held[PRETRAIN] = json.loads(pre.read_text()).get("held_out", {})
        meshes = {}
        for method in sc.get("methods", config["methods"]):
            if layout.metrics(name, method).is_file():
                m = json.loads(layout.metrics(name, method).read_text())
                held[method] = {k: m.get(k) for k in ("psnr", "ssim", "views")}
            if layout.mesh(name, method).is_file():
                meshes[method] = extent_report(o3d.io.read_triangle_mesh(str(layout.mesh(name, method))), scene)
        row["held_out"], row["meshes"] = held, meshes
        priors = layout.priors(name, backend)
        row["priors"] = prior_agreement(scene, priors) if priors.is_dir() else None
        scenes.append(row)
    return {"scenes": scenes}


def format_real_report(report: dict) -> str:
    cell = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    lines = []
    for r in report["scenes"]:
        total = sum(v for v in r["seconds"].values() if v is not None)
        lines += [f"{r['scene']}: {r['registered']} of {r['photos']} photos registered, {r['points']:,} sparse points",
                  "", f"{'job':<28} {'seconds':>8}"]
        lines += [f"{job:<28} {cell(sec, '8.0f')}" for job, sec in r["seconds"].items()]
        lines += [f"{'total':<28} {total:8.0f}  ({total / 60:.1f} min)", "",
                  f"{'held-out views':<16} {'PSNR dB':>8} {'SSIM':>7} {'views':>6}"]
        lines += [f"{m:<16} {cell(h.get('psnr'), '8.2f')} {cell(h.get('ssim'), '7.4f')} {cell(h.get('views'), '6d')}"
                  for m, h in r["held_out"].items()]
        if r["priors"]:
            lines += ["", "priors, neighbouring views against each other (confident pixels)"]
            lines += agreement_lines([{**r["priors"], "data": "priors"}])
        if r["meshes"]:
            lines += ["", f"{'mesh':<16} {'triangles':>10} {'extent':>26} {'× sparse 5–95 % box':>20}"]
            lines += [f"{m:<16} {x['triangles']:>10,} {' × '.join(f'{e:.2f}' for e in x['extent']):>26} "
                      f"{cell(x['extent_ratio'], '20.2f')}" for m, x in r["meshes"].items()]
            box = next(iter(r["meshes"].values()))["sparse_extent"]
            if box:
                lines.append(f"sparse points' 5–95 % box: {' × '.join(f'{e:.2f}' for e in box)}")
        lines.append("")
    return "\n".join(lines)


# --- training step -------------------------------------------------------------------------

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
    """Self times of the parts of training steps, by wrapping the functions a step calls;
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

    def timed(self, part: str, fn: Callable) -> Callable:
        """``fn``, its self time charged to ``part``."""
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            self._enter(part)
            try:
                return fn(*args, **kwargs)
            finally:
                self._leave()
        return wrapper

    def timed_backward(self, backward: Callable) -> Callable:
        """``Tensor.backward``, its time split among the backward parts by pre-hooks on the
        first node of each forward part's stretch of the graph."""
        def wrapper(tensor, *args, **kwargs):
            start = time.perf_counter()
            self._charge()
            for node, part in self._stretch_starts(tensor.grad_fn):
                node.register_prehook(functools.partial(self._backward_reaches, part))
            self.sync()
            self.open.append("losses_backward")
            self.overhead += time.perf_counter() - start
            self.since = time.perf_counter()
            try:
                return backward(tensor, *args, **kwargs)
            finally:
                self._leave()
                self.marks = self.marks[-1:]
        return wrapper

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


@contextlib.contextmanager
def _instrumented(trainer: Trainer, profiler: StepProfiler, counts: dict, ticks: list[float]):
    """``trainer``'s render, the backends' entries, the optimiser step, densification and
    ``Tensor.backward`` wrapped with ``profiler``'s timers for the duration (see
    :func:`profile_steps`); ``counts`` and ``ticks`` receive the renders, pairs and steps."""
    import torch

    from eve3d.gaussians.render import cpu, cuda, pairs

    st = trainer.state
    optimizer_step = profiler.timed("optimizer", st.optimizer_step)

    def counted(render: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            out = render(*args, **kwargs)
            counts["renders"] += 1
            counts["pairs"] += out.n_pairs or 0
            return out
        return wrapper

    def counted_step() -> None:
        counts["gaussians"] += len(trainer.model)
        ticks.append(time.perf_counter() - profiler.overhead)
        optimizer_step()

    with contextlib.ExitStack() as stack:
        patch = lambda target, name, new: stack.enter_context(mock.patch.object(target, name, new))  # noqa: E731
        patch(trainer, "render", counted(profiler.timed("projection", trainer.render)))
        for module, name in ((cpu, "rasterize"), (pairs, "rasterize"), (cuda, "rasterize_gsplat")):
            patch(module, name, profiler.timed("rasterize", getattr(module, name)))
        patch(st, "optimizer_step", counted_step)
        patch(st, "densify", profiler.timed("densify", st.densify))
        patch(torch.Tensor, "backward", profiler.timed_backward(torch.Tensor.backward))
        yield


def profile_steps(trainer: Trainer, loss: LossTerms, events: Callable[[int], None] | None, start: int, warmup: int,
                  steps: int) -> StageTiming:
    """Run ``warmup`` then ``steps`` steps of ``trainer`` from step ``start`` of its schedule
    and return the mean time of each part of the timed steps.

    Method (the training code is not changed; every wrapper is removed afterwards):

    - forward: ``Trainer.render`` is charged to projection forward, the backend's entry
      (``cpu.rasterize``: the depth sort and pixel boxes, then the C++ tile compositing;
      ``pairs.rasterize``; ``rasterize_gsplat``) to rasterise forward, the stage's loss
      function to losses forward, ``TrainState.optimizer_step`` and ``TrainState.densify``
      to theirs. Each part is charged its self time: a render inside the loss (pgsr's
      neighbour) is not the loss's, the compositing is not the render's. So projection
      forward is everything ``render_model`` does around the compositing: SH colours,
      rotations, planar features, the EWA projection, the outputs' depth division.
    - backward: ``loss.backward()`` is wrapped. On the CPU autograd runs the graph's nodes in
      decreasing sequence number, the reverse of their creation, so each forward part's
      stretch of creation runs as one stretch of backward. The wrapper walks the graph first
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
    with _instrumented(trainer, profiler, counts, ticks):
        timed_loss = profiler.timed("losses", loss)
        trainer.run(timed_loss, events, until=start + warmup)
        profiler.reset()
        counts.update(dict.fromkeys(counts, 0))
        ticks[:] = [time.perf_counter()]
        trainer.run(timed_loss, events, until=start + warmup + steps)
        wall = time.perf_counter() - ticks[0] - profiler.overhead
    done = st.step - start - warmup
    if done != steps:
        raise Eve3dError(f"{trainer.name}: ran {done} of {steps} timed steps (the schedule has "
                         f"{trainer.s.iterations} iterations; start {start}, warm-up {warmup})")
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
    checkpoints, drawing ``gaussians`` prior points where the method starts from the priors."""
    from eve3d.config import method_settings, stage_settings
    from eve3d.core.settings import PretrainSettings

    if stage == "pretrain":
        return stage_settings(PretrainSettings, "pretrain", config, checkpoint_every=0)
    return method_settings(stage, config, "--stages", checkpoint_every=0, init_prior_points=gaussians)


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
    s = stage_settings_for("pgsr", config, 1)
    return max(s.dn_from, s.mv_from, s.prior_from, s.joint_from)


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
    from eve3d.core.settings import SyntheticSettings, from_mapping
    from eve3d.priors.oracle import oracle_priors
    from eve3d.synth import generate

    config = job_config() if config is None else config
    synthetic = from_mapping(SyntheticSettings, config.get("synthetic") or {}, "synthetic")
    start = default_start(config) if start is None else start
    settings = {stage: stage_settings_for(stage, config, gaussians) for stage in stages}
    for stage, s in settings.items():
        if start + warmup + steps > s.iterations:
            raise Eve3dError(f"{stage}: steps {start}..{start + warmup + steps} run past its {s.iterations} iterations")
    ctx = multiprocessing.get_context("spawn")
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir = generate("object", Path(tmp) / "object", views=synthetic.views, width=synthetic.width,
                             height=synthetic.height, seed=synthetic.seed, surface_samples=gaussians)
        priors = None
        if any(stage != "pretrain" and uses_priors(asdict(s)) for stage, s in settings.items()):
            priors = Path(tmp) / "priors"
            oracle_priors(load_scene(scene_dir), priors, preview=False)
        rows = []
        with mock.patch.dict(os.environ, {"TQDM_DISABLE": "1"}):  # no progress bars in the children
            for stage in stages:
                args = str(scene_dir), stage, config, gaussians, start, warmup, steps, priors and str(priors)
                rows.append(_in_child(ctx, _time_training_in_child, args))
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
    row = lambda label, cells: f"{label:<{label_w}} " + " ".join(f"{c:>{w}}" for c in cells)  # noqa: E731
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
1920×1080 takes about 13 minutes, longer than what it measures."""
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
                 "from eve3d.tools.bench import peak_rss_mb\n"
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
        peak = _in_child(multiprocessing.get_context("spawn"), fn, args)
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
    from eve3d.priors.oracle import oracle_priors
    from eve3d.synth import generate

    kind, data, depth, views, (width, height), divisor = args
    generate(kind, Path(data), views=views, width=width // divisor, height=height // divisor, supersample=1,
             matcher="sequential")  # exhaustive matching of hundreds of views would dwarf the stages timed
    scene = load_scene(Path(data))
    oracle_priors(replace(scene, cameras=[cam.scaled(width / cam.width) for cam in scene.cameras]), Path(depth),
                  preview=False)
    return peak_rss_mb()


def write_ground_truth(args: tuple) -> float:
    """A benchmark download with ``points`` ground-truth points (``eve3d.tools.standin``) of the
    generated scene in ``data``: T&T (``Barn``: GT points sampled on the whole GT mesh) or
    DTU (``scan24``: STL points on the GT surface the cameras see); this process's peak memory."""
    from pathlib import Path

    from eve3d.core.io import load_scene
    from eve3d.tools.standin import STANDIN_SCENE, write_dtu_release, write_tnt_release

    benchmark, data, root, points = args
    scene = load_scene(Path(data))
    if benchmark == "tnt":
        write_tnt_release(scene, Path(root), STANDIN_SCENE["tnt"], gt_points=points)
    else:
        write_dtu_release(scene, Path(root), int(STANDIN_SCENE["dtu"][4:]), stl_points=points)
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
    from eve3d.tools.standin import STANDIN_SCENE

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
                                                       root / STANDIN_SCENE["tnt"], "--mesh", mesh, *cfg], None)]
        elif protocol == "dtu":
            root, obj = work / "dtu", work / "object"
            files = dtu_files(root, STANDIN_SCENE["dtu"])
            steps += [("set-up", f"object, {DTU_VIEWS} views, exact depth at {w}x{h}", generate_with_depth,
                       ("object", obj, work / "object_depth", DTU_VIEWS, size, MEMORY_IMAGE_DIVISOR)),
                      ("mesh", f"object, {DTU_VIEWS} views {w}x{h}", ["mesh", "--scene", obj, "--depth",
                                                                       work / "object_depth", "--out",
                                                                       work / "object_mesh.ply", *cfg], None),
                      ("set-up", f"dtu, {million}", write_ground_truth, ("dtu", obj, root, gt_points)),
                      ("evaluate", f"dtu, {million}", [*evaluate, root / METRICS, "--protocol", "dtu", "--scene",
                                                       root / STANDIN_SCENE["dtu"], "--mesh", work / "object_mesh.ply",
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
    from eve3d.core.settings import MeshSettings, SyntheticSettings, from_mapping

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
        cell = lambda v, w, f: f"{'-' if v is None else format(v, f):>{w}}"  # noqa: E731
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
