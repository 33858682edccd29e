"""``eve3d bench``: speed and memory benchmarks that print a table (never timed tests)."""
from __future__ import annotations

import json
import math
import multiprocessing
import resource
import time
from dataclasses import asdict, dataclass

import numpy as np

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

    from eve3d.render import render

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

    from eve3d.settings import SgbmSettings
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
    """:func:`eve3d.evaluate.depth.depth_accuracy` of one folder of priors, named by its backend."""
    from pathlib import Path

    from eve3d.evaluate.depth import depth_accuracy

    return {**depth_accuracy(priors_dir, reference_dir, scene), "backend": Path(priors_dir).name}


def format_stereo_tables(moto: list[dict], priors: list[dict]) -> str:
    lines = ["real pair (Middlebury Motorcycle): confident pixels only",
             "backend  size     density  EPE px  bad-2.0 %  seconds"]
    lines += [f"{r['backend']:<8} {r['size']:<8} {r['density']:7.3f}  {r['epe']:6.3f}  {r['bad2']:9.2f}  "
              f"{r['seconds']:7.2f}" for r in moto]
    if priors:
        lines += ["", "synthetic scenes: priors against the exact depth, confident pixels"]
        lines += prior_lines("scene / priors", [r["data"] for r in priors], priors)
    return "\n".join(lines)


def prior_lines(title: str, labels: list[str], rows: list[dict]) -> list[str]:
    """A table of :func:`prior_accuracy` rows, one label each."""
    width = max(len(title), *map(len, labels))
    lines = [f"{title:<{width}} {'median signed':>13} {'median rel. error':>17} {'density':>8} {'off >5 %':>9} "
             f"{'off >10 %':>9}"]
    for label, r in zip(labels, rows):
        if r["median_signed_error"] is None:  # no confident pixel with an exact depth
            lines.append(f"{label:<{width}} {'-':>13} {'-':>17} {r['density']:8.3f}")
            continue
        lines.append(f"{label:<{width}} {r['median_signed_error'] * 100:+11.2f} % {r['median_rel_error'] * 100:15.2f} % "
                     f"{r['density']:8.3f} {r['wrong_5'] * 100:7.1f} % {r['wrong_10'] * 100:7.1f} %")
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

    from eve3d.evaluate import PROTOCOLS, EvalInputs
    from eve3d.io import load_scene
    from eve3d.scene import Scene

    scene, mesh, gt = args
    scene = load_scene(scene, check_images=False) if isinstance(scene, (str, Path)) else Scene(**scene)
    start = time.perf_counter()
    m = PROTOCOLS["synthetic"].run(EvalInputs(scene, Path(mesh), Path(mesh).with_suffix(".json"), gt=Path(gt)))
    m["seconds"] = time.perf_counter() - start
    m["peak_mb"] = peak_rss_mb()
    return m


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
            pool = ctx.Pool(1)
            m = pool.apply(_evaluate_in_child, (args,))
            pool.close()  # not terminate(): pycolmap's signal handler would print a stack trace
            pool.join()
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


def _stage_seconds(path) -> float | None:
    """Wall seconds from a Snakemake benchmark file (None when the stage did not run here)."""
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        return None
    rows = path.read_text().splitlines()
    return float(rows[1].split("\t")[0]) if len(rows) > 1 else None


def methods_report(config: dict) -> dict:
    """The table of ``eve3d bench methods`` from a finished workflow run of ``config``
    (resolved): per scene and method the synthetic protocol's scores and the wall time of
    the method's own stages (joint + mesh; the stages the priors share are listed per
    scene), the means over scenes, and per scene the depth maps' accuracy against the oracle
    depth: D* (``priors/{backend}``), every learnable method's final D̂ and every trained
    method's rendered depth D (the maps its mesh fuses)."""
    from eve3d.layout import Layout, job_name
    from eve3d.methods import methods

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
            times = [_stage_seconds(p) for p in stages]
            rows.append({"scene": scene, "method": name, **{k: m.get(k) for k in (
                "chamfer", "precision", "recall", "fscore")},
                "seconds": None if None in times else sum(times)})
        shared[scene] = {job_name(*job): _stage_seconds(layout.benchmark(scene, *job))
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
                  "signed: positive = too far"]
        lines += prior_lines("scene / priors", [f"{r['data']} / {r['priors']}" for r in report["priors"]],
                             report["priors"])
    return "\n".join(lines)
