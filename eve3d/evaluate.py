"""Evaluation stage (``eve3d evaluate``): a mesh against ground truth.

Protocols (DESIGN §4):

* ``synthetic``: sample both surfaces densely (spacing τ/3), crop the reconstruction to the
  GT bounding box (grown by τ), then accuracy = mean recon→GT distance,
  completeness = mean GT→recon, Chamfer = their mean, precision/recall at τ, F-score.
* ``dtu``: DTUeval-python semantics, in DTU mm: cull the mesh by the dilated object masks,
  undo ``scale_mat``, sample at 0.2 mm, thin to 0.2 mm, keep points in the bounding box and
  the ``ObsMask``; accuracy over those, completeness of the GT above the ground plane;
  distances ≥ 20 mm excluded; Chamfer = mean(acc, comp).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from eve3d.scene import Eve3dError, Scene
from eve3d.surface import sample_surface

TAU_FRACTION = 0.005
"""Default synthetic threshold τ as a fraction of the scene radius."""


def nearest_distances(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distance from each query point to its nearest reference point."""
    if not len(reference):
        return np.full(len(query), np.inf)
    return cKDTree(reference).query(query, k=1, workers=-1)[0]


def cloud_metrics(recon: np.ndarray, gt: np.ndarray, tau: float) -> dict[str, float]:
    """Accuracy, completeness, Chamfer, precision, recall and F-score of two point sets."""
    d_rg = nearest_distances(recon, gt)
    d_gr = nearest_distances(gt, recon)
    precision = float(np.mean(d_rg < tau)) if len(d_rg) else 0.0
    recall = float(np.mean(d_gr < tau)) if len(d_gr) else 0.0
    fscore = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    accuracy = float(np.mean(d_rg)) if len(d_rg) else float("inf")
    completeness = float(np.mean(d_gr))
    return {"accuracy": accuracy, "completeness": completeness, "chamfer": (accuracy + completeness) / 2,
            "precision": precision, "recall": recall, "fscore": fscore}


def read_mesh(path: Path):
    import open3d as o3d

    if not Path(path).is_file():
        raise Eve3dError(f"{path}: mesh not found")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise Eve3dError(f"{path}: not a triangle mesh, or an empty one")
    return mesh


def mesh_samples(mesh, spacing: float, rng: np.random.Generator, max_points: int) -> np.ndarray:
    """Uniform surface samples with about one point per spacing² of area."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    count = int(np.clip(mesh.get_surface_area() / spacing**2, 1000, max_points))
    return sample_surface(v, f, count, rng)


def evaluate_synthetic(mesh_path: Path, gt_path: Path, scene: Scene | None = None, tau: float | None = None,
                       max_points: int = 2_000_000, seed: int = 0) -> dict:
    """The synthetic protocol (module docstring). τ defaults to 0.005 × scene radius (or ×
    half the GT bounding-box diagonal without a scene)."""
    rng = np.random.default_rng(seed)
    recon_mesh, gt_mesh = read_mesh(mesh_path), read_mesh(gt_path)
    lo, hi = gt_mesh.get_min_bound(), gt_mesh.get_max_bound()
    radius = scene.radius if scene is not None else float(np.linalg.norm(hi - lo)) / 2
    tau = float(tau) if tau is not None else TAU_FRACTION * radius
    gt = mesh_samples(gt_mesh, tau / 3, rng, max_points)
    recon = mesh_samples(recon_mesh, tau / 3, rng, max_points)
    recon = recon[np.all((recon >= lo - tau) & (recon <= hi + tau), axis=1)]
    return {"protocol": "synthetic", "tau": tau, **cloud_metrics(recon, gt, tau),
            "n_recon": int(len(recon)), "n_gt": int(len(gt))}


# --- DTU ---------------------------------------------------------------------------------

def cull_by_masks(mesh, scene: Scene, dilation: int = 24):
    """2DGS/DTU culling: drop vertices that project inside some image but outside its object
    mask dilated by a disk of ``dilation`` px; faces keep only if all vertices stay."""
    import cv2

    from eve3d.fileio import read_mask

    v = np.asarray(mesh.vertices)
    keep = np.ones(len(v), dtype=bool)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilation + 1, 2 * dilation + 1))
    for cam in scene.cameras:
        if cam.mask_path is None:
            raise Eve3dError(f"{scene.root}: the DTU protocol needs object masks (mask/) for every view")
        mask = cv2.dilate(read_mask(cam.mask_path).astype(np.uint8), kernel) > 0
        uv, z = cam.project(v)
        px = np.floor(uv).astype(np.int64)
        inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        ok = np.ones(len(v), dtype=bool)
        ok[inside] = mask[px[inside, 1], px[inside, 0]]
        keep &= ok
    tri = np.asarray(mesh.triangles)
    mesh.remove_triangles_by_mask(~keep[tri].all(axis=1))
    mesh.remove_unreferenced_vertices()
    return mesh


def dtu_sample_mesh(vertices: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """DTUeval-python's deterministic triangle sampling: a grid of barycentric points per
    triangle with step ``density`` (plus the vertices)."""
    tri = vertices[triangles]
    v1, v2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    l1, l2 = np.linalg.norm(v1, axis=-1), np.linalg.norm(v2, axis=-1)
    area2 = np.linalg.norm(np.cross(v1, v2), axis=-1)
    ok = area2 > 0
    tri, v1, v2, l1, l2, area2 = tri[ok], v1[ok], v2[ok], l1[ok], l2[ok], area2[ok]
    thr = density * np.sqrt(l1 * l2 / area2)
    n1, n2 = np.floor(l1 / thr), np.floor(l2 / thr)
    out = [vertices]
    for (a, b), group in _group_by_counts(n1, n2):
        c = np.mgrid[: a + 1, : b + 1].reshape(2, -1).astype(np.float64) + 0.5
        c[0] /= max(a, 1e-7)
        c[1] /= max(b, 1e-7)
        c = c[:, c[0] + c[1] < 1]
        if c.shape[1]:
            pts = v1[group, None] * c[0][None, :, None] + v2[group, None] * c[1][None, :, None] + tri[group, 0, None]
            out.append(pts.reshape(-1, 3))
    return np.concatenate(out)


def _group_by_counts(n1: np.ndarray, n2: np.ndarray):
    """Triangles grouped by their (n1, n2) sample counts, so each group samples in one go."""
    keys = np.stack([n1, n2], 1).astype(np.int64)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    for k, (a, b) in enumerate(uniq):
        yield (int(a), int(b)), np.flatnonzero(inverse.ravel() == k)


def radius_thin(points: np.ndarray, radius: float, rng: np.random.Generator) -> np.ndarray:
    """DTUeval-python's greedy thinning: in random order, keep a point and drop every other
    point within ``radius`` of it."""
    points = points[rng.permutation(len(points))]
    tree = cKDTree(points)
    keep = np.ones(len(points), dtype=bool)
    for i, nbrs in enumerate(tree.query_ball_point(points, r=radius, workers=-1)):
        if keep[i]:
            keep[nbrs] = False
            keep[i] = True
    return points[keep]


def evaluate_dtu(mesh_path: Path, scene: Scene, stl_path: Path, obs_mask_path: Path, plane_path: Path,
                 density: float = 0.2, max_dist: float = 20.0, patch: float = 60.0, seed: int = 0) -> dict:
    """The DTU protocol (module docstring); distances in mm."""
    import open3d as o3d
    from scipy.io import loadmat

    rng = np.random.default_rng(seed)
    mesh = cull_by_masks(read_mesh(mesh_path), scene)
    if len(mesh.triangles) == 0:
        raise Eve3dError(f"{mesh_path}: nothing of the mesh lies inside the object masks")
    mesh.transform(scene.to_world)
    data = dtu_sample_mesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), density)
    data = radius_thin(data, density, rng)
    try:
        obs = loadmat(obs_mask_path)
        obs_mask, bb, res = obs["ObsMask"], obs["BB"].astype(np.float32), float(np.squeeze(obs["Res"]))
        plane = loadmat(plane_path)["P"].reshape(4)
    except Exception as e:
        raise Eve3dError(f"{obs_mask_path} / {plane_path}: cannot read DTU observation mask or plane ({e})") from None
    inbound = np.all((data >= bb[:1] - patch) & (data < bb[1:] + patch * 2), axis=1)
    data_in = data[inbound]
    grid = np.around((data_in - bb[:1]) / res).astype(np.int32)
    grid_ok = np.all((grid >= 0) & (grid < np.array(obs_mask.shape)), axis=1)
    in_obs = obs_mask[grid[grid_ok, 0], grid[grid_ok, 1], grid[grid_ok, 2]].astype(bool)
    data_in_obs = data_in[grid_ok][in_obs]
    stl = np.asarray(o3d.io.read_point_cloud(str(stl_path)).points)
    if not len(stl):
        raise Eve3dError(f"{stl_path}: empty or unreadable ground-truth point cloud")
    d2s = nearest_distances(data_in_obs, stl)
    above = np.concatenate([stl, np.ones((len(stl), 1))], 1) @ plane > 0
    s2d = nearest_distances(stl[above], data_in)
    acc = float(d2s[d2s < max_dist].mean())
    comp = float(s2d[s2d < max_dist].mean())
    return {"protocol": "dtu", "accuracy": acc, "completeness": comp, "chamfer": (acc + comp) / 2,
            "n_recon": int(len(data_in_obs)), "n_gt": int(above.sum())}
