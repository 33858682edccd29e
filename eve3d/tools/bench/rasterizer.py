"""``eve3d bench rasterizer``: the rasteriser's forward and backward time and memory at three sizes."""
from __future__ import annotations

import json
import math
import multiprocessing
import time
from dataclasses import asdict, dataclass

import numpy as np

from eve3d.tools.bench.common import peak_rss_mb


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


def run_bench_rasterizer(sizes=RASTERIZER_SIZES, backend: str = "auto", repeats: int = 5,
                         as_json: bool = False) -> None:
    """``eve3d bench rasterizer``: the table (or JSON) of :func:`bench_rasterizer`."""
    rows = bench_rasterizer(sizes, backend=backend, repeats=repeats)
    print(rasterizer_json(rows) if as_json else format_rasterizer_table(rows))
