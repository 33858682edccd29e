"""eve3d.evaluate.common: mesh distances against a brute-force reference, the distance metrics' formulas."""
import numpy as np
import pytest

from eve3d.evaluate.common import distance_metrics, mesh_distances


def point_triangle_distance(p, a, b, c):
    """Brute-force reference: the distance from p (N,3) to triangle abc, by projecting onto
    the plane when the foot lies inside, else the nearest of the three edges."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    foot = p - ((p - a) @ n)[:, None] * n
    inside = np.ones(len(p), dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.cross(v - u, foot - u) @ n >= 0
    best = np.where(inside, np.abs((p - a) @ n), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        t = np.clip((p - u) @ (v - u) / ((v - u) @ (v - u)), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (u + t[:, None] * (v - u)), axis=1))
    return best


def test_mesh_distances_match_brute_force_point_to_triangle():
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_torus(0.5, 0.2, radial_resolution=12, tubular_resolution=8)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (400, 3))
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    ref = np.min([point_triangle_distance(pts, *v[tri]) for tri in f], axis=0)
    assert np.allclose(mesh_distances(mesh, pts), ref, atol=2e-6)


def test_distance_metrics_formulas():
    m = distance_metrics(np.array([0.1, 0.3, 0.5, 0.7]), np.array([0.1, 0.2]), tau=0.4)
    assert m["precision"] == 0.5 and m["recall"] == 1.0 and m["fscore"] == pytest.approx(2 / 3)
    assert m["accuracy"] == pytest.approx(0.4) and m["chamfer"] == pytest.approx(0.275)
    empty = distance_metrics(np.zeros(0), np.array([0.1]), tau=0.4)
    assert empty["precision"] == 0 and empty["accuracy"] is None and empty["fscore"] == 0
