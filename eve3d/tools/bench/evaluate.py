"""``eve3d bench evaluate``: the evaluation's time and memory, on given meshes or a generated one with
floaters."""
from __future__ import annotations

import multiprocessing
import time

import numpy as np

from eve3d.tools.bench.common import in_child, peak_rss_mb


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
            m = in_child(ctx, _evaluate_in_child, args)
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


def run_bench_evaluate(meshes: list[str] = (), scene: str | None = None, gt: str | None = None,
                       as_json: bool = False) -> None:
    """``eve3d bench evaluate``: the table (or JSON) of :func:`bench_evaluate`."""
    import json
    from pathlib import Path

    from eve3d.core.errors import Eve3dError

    if meshes and not (scene and gt):
        raise Eve3dError("--meshes needs --scene (the cameras) and --gt (the GT mesh)")
    rows = bench_evaluate([("/".join(Path(m).parts[-3:]), str(m)) for m in meshes], scene, gt)
    print(json.dumps(rows, indent=2) if as_json else format_evaluate_table(rows))
