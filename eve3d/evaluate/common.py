"""What the protocols share: distances, precision/recall/F-score, error maps."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.chunking import chunks
from eve3d.core.colormap import hot_r
from eve3d.core.errors import Eve3dError


GIVEN_TAU = "given (evaluate.tau)"
"""``tau_rule`` of a τ the user set."""


def nearest_distances(query: np.ndarray, reference: np.ndarray, upper_bound: float = np.inf,
                      chunk: int | None = None) -> np.ndarray:
    """Distance from each query point to its nearest reference point; ``inf`` where none is
    closer than ``upper_bound``. A finite bound keeps the search short for points far from
    a dense reference (floaters), which otherwise visit most of the tree. Queried ``chunk``
    points at a time (:mod:`eve3d.core.chunking`)."""
    if not len(reference):
        return np.full(len(query), np.inf)
    from scipy.spatial import cKDTree  # here: every command imports the protocols, only scoring needs scipy

    tree = cKDTree(reference)
    out = np.empty(len(query))
    for part in chunks(len(query), chunk):
        out[part] = tree.query(query[part], k=1, distance_upper_bound=upper_bound, workers=-1)[0]
    return out


def mesh_distances(mesh, points: np.ndarray, chunk: int | None = None) -> np.ndarray:
    """Exact unsigned distance from each point to the nearest triangle of ``mesh`` (open3d's
    BVH point query), in chunks so memory stays bounded."""
    import open3d as o3d

    # open3d works in float32: move the mesh's centre to the origin first, so that large
    # (e.g. georeferenced) coordinates keep their precision.
    # Only the positions and triangles go in (a copy of the whole mesh, colours and normals
    # too, was 1.5 GB of a 26-million-triangle mesh).
    centre = np.asarray(mesh.get_axis_aligned_bounding_box().get_center())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((np.asarray(mesh.vertices) - centre).astype(np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.triangles).astype(np.uint32)))
    out = np.empty(len(points))
    for part in chunks(len(points), chunk):
        out[part] = scene.compute_distance(o3d.core.Tensor(np.ascontiguousarray(points[part] - centre,
                                                                               dtype=np.float32))).numpy()
    return out


def fscore(precision: float, recall: float) -> float:
    return 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0


def distance_metrics(d_recon_to_gt: np.ndarray, d_gt_to_recon: np.ndarray, tau: float) -> dict[str, float | None]:
    """Accuracy (mean recon→GT), completeness (mean GT→recon), Chamfer (their mean),
    precision and recall at ``tau`` and the F-score. A side without points scores
    precision/recall 0 and a distance of None (JSON has no infinity)."""
    precision = float(np.mean(d_recon_to_gt < tau)) if len(d_recon_to_gt) else 0.0
    recall = float(np.mean(d_gt_to_recon < tau)) if len(d_gt_to_recon) else 0.0
    accuracy = float(np.mean(d_recon_to_gt)) if len(d_recon_to_gt) else None
    completeness = float(np.mean(d_gt_to_recon)) if len(d_gt_to_recon) else None
    chamfer = None if accuracy is None or completeness is None else (accuracy + completeness) / 2
    return {"accuracy": accuracy, "completeness": completeness, "chamfer": chamfer,
            "precision": precision, "recall": recall, "fscore": fscore(precision, recall)}


COLOUR_RANGE = 3.0
"""Error maps colour distances from 0 (white) to 3τ and beyond (black), as the T&T toolbox."""
ERROR_MAP_POINTS = 200_000
"""Points written per error map at most (a uniform subset of those scored): enough to see
where a surface is off, 5 MB per file."""
def write_error_maps(folder: Path, recon: np.ndarray, recon_distances: np.ndarray, gt: np.ndarray,
                     gt_distances: np.ndarray, top: float) -> dict:
    """``precision.ply`` (our scored points) and ``recall.ply`` (the GT's) in ``folder``,
    coloured by distance to the other side from white (0) to black (``top`` and beyond),
    written atomically; at most :data:`ERROR_MAP_POINTS` of each. Returns the metrics'
    record of the scale (``error_map_top``), for a viewer's colour bar."""
    import open3d as o3d

    from eve3d.core.fileio import atomic_path

    rng = np.random.default_rng(0)
    for name, points, distances in (("precision", recon, recon_distances), ("recall", gt, gt_distances)):
        keep = np.sort(rng.permutation(len(points))[:ERROR_MAP_POINTS])
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points[keep], np.float64)))
        cloud.colors = o3d.utility.Vector3dVector(hot_r(np.minimum(distances[keep], top) / top))
        with atomic_path(Path(folder) / f"{name}.ply") as tmp:
            if not o3d.io.write_point_cloud(str(tmp), cloud):
                raise Eve3dError(f"{folder}/{name}.ply: could not write the point cloud")
    return {"error_map_top": float(top)}
