"""Evaluation protocols against brute-force references and known answers."""
import json

import numpy as np
import scipy
import pytest

from eve3d.core.fileio import read_mesh
from eve3d.core.io import load_scene
from eve3d.core.raycast import MeshRaycaster, seen_counts
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings import EvalSettings
from eve3d.evaluate import PROTOCOLS, EvalInputs
from eve3d.evaluate.common import distance_metrics, hot_r, mesh_distances
from eve3d.evaluate.dtu import cull_by_masks
from eve3d.synth import object_cameras
from eve3d.tools.standin import dtu_scale_mat, write_dtu_ground_truth, write_dtu_layout
from tests.helpers import run_cli


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


def sphere_and_ground(delta: float = 0.0):
    """A sphere floating above a ground plate, every surface moved along its normal by
    ``delta`` (the sphere scaled about its centre, the plate lifted)."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.4, resolution=80)
    sphere.scale((0.4 + delta) / 0.4, center=np.zeros(3))
    sphere.translate([0.1, -0.2, 0.7])
    plate = o3d.geometry.TriangleMesh()
    plate.vertices = o3d.utility.Vector3dVector(np.array([[-1.2, -1.2, delta], [1.2, -1.2, delta],
                                                         [1.2, 1.2, delta], [-1.2, 1.2, delta]]))
    plate.triangles = o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]]))
    return sphere + plate


def test_mesh_displaced_by_delta_scores_delta(tmp_path):
    """Accuracy and completeness of a copy of the GT moved along its normals by δ equal δ;
    precision and recall switch from 0 to 1 as τ passes δ."""
    import open3d as o3d

    delta = 0.01
    o3d.io.write_triangle_mesh(str(tmp_path / "gt.ply"), sphere_and_ground())
    o3d.io.write_triangle_mesh(str(tmp_path / "moved.ply"), sphere_and_ground(delta))
    scene = Scene(root=tmp_path, cameras=object_cameras(24, 160, 120, np.random.default_rng(0)))
    protocol = PROTOCOLS["synthetic"]

    def score(**settings):
        return protocol.run(EvalInputs(scene, tmp_path / "moved.ply", tmp_path / "m.json", gt=tmp_path / "gt.ply",
                                       settings=EvalSettings(samples=200_000, **settings)))

    m = score()
    assert m["accuracy"] == pytest.approx(delta, rel=0.05) and m["completeness"] == pytest.approx(delta, rel=0.05)
    # The bottom of the sphere faces the plate, out of every camera's sight.
    assert 0.9 < m["visible_gt_fraction"] < 0.99
    assert m["tau_rule"].startswith("0.0025 x visible-GT bounding-box diagonal")
    # the error maps: every point δ from the other surface, coloured δ/3τ of the way to black
    for name, count in (("precision", m["n_recon"]), ("recall", m["n_gt"])):
        cloud = o3d.io.read_point_cloud(str(tmp_path / f"{name}.ply"))
        assert len(cloud.points) == min(count, 200_000)
        expected = hot_r(np.array([delta / (3 * m["tau"])]))[0]
        assert np.mean(np.abs(np.asarray(cloud.colors) - expected).max(axis=1) < 0.05) > 0.95
    assert score(tau=1.5 * delta)["fscore"] > 0.99 and score(tau=0.5 * delta)["fscore"] < 0.01


def test_synthetic_protocol_ignores_unseen_gt_and_crops_far_recon(tmp_path):
    """GT surface no camera sees (a box buried in the plate, a plate far behind the
    cameras) changes neither score; a reconstruction fragment outside the visible GT's box
    is cropped and reported."""
    import open3d as o3d

    gt = sphere_and_ground()
    hidden = o3d.geometry.TriangleMesh.create_box(0.3, 0.3, 0.3).translate([0.5, 0.5, -0.4])
    far = o3d.geometry.TriangleMesh.create_box(0.5, 0.5, 0.5).translate([0, 0, 30])
    o3d.io.write_triangle_mesh(str(tmp_path / "gt.ply"), gt)
    o3d.io.write_triangle_mesh(str(tmp_path / "gt_hidden.ply"), gt + hidden)
    o3d.io.write_triangle_mesh(str(tmp_path / "recon_far.ply"), gt + far)
    scene = Scene(root=tmp_path, cameras=object_cameras(24, 160, 120, np.random.default_rng(0)))
    run = lambda recon, gt_name: PROTOCOLS["synthetic"].run(EvalInputs(  # noqa: E731
        scene, tmp_path / recon, tmp_path / "m.json", gt=tmp_path / gt_name, settings=EvalSettings(samples=100_000)))
    with_hidden = run("gt.ply", "gt_hidden.ply")
    assert with_hidden["recall"] == 1.0 and with_hidden["precision"] == 1.0
    far_recon = run("recon_far.ply", "gt.ply")
    assert far_recon["precision"] == 1.0 and far_recon["crop"]["recon_area_fraction_left_out"] > 0.05


def test_evaluate_cli_writes_tau_and_its_rule(object_dataset, tmp_path):
    out = tmp_path / "metrics.json"
    r = run_cli("evaluate", "--mesh", object_dataset / "gt/mesh.ply", "--gt", object_dataset / "gt/mesh.ply",
                "--scene", object_dataset, "--out", out, "--samples", "100000")
    assert r.returncode == 0, r.stderr
    m = json.loads(out.read_text())
    assert m["protocol"] == "synthetic" and m["fscore"] == 1.0 and m["chamfer"] < 1e-5
    assert "visible-GT bounding-box diagonal" in m["tau_rule"] and f"tau = {m['tau']:.5g}" in r.stdout
    r = run_cli("evaluate", "--mesh", object_dataset / "gt/mesh.ply", "--scene", object_dataset, "--out", out,
                "--protocol", "dtu")
    assert r.returncode == 2 and "the dtu protocol needs gt, obs_mask, plane" in r.stderr
    r = run_cli("evaluate", "--mesh", object_dataset / "gt/mesh.ply", "--gt", object_dataset / "gt/mesh.ply",
                "--scene", object_dataset, "--out", out, "--tau", "-1")
    assert r.returncode == 2 and "evaluate.tau (--tau): expected a number > 0, got -1" in r.stderr


def test_dtu_culling_removes_exactly_the_vertices_outside_the_dilated_masks(tmp_path):
    """Two cameras, each with a one-pixel mask. A vertex survives when, in every image it
    falls inside, its pixel lies within the 24 px disk around that camera's mask pixel."""
    import open3d as o3d

    from eve3d.core.fileio import write_image

    w, h = 200, 150
    K = np.array([[100.0, 0, w / 2], [0, 100.0, h / 2], [0, 0, 1]])
    cams, marks = [], [(60, 50), (140, 90)]
    for i, (centre, (mx, my)) in enumerate(zip(([0, 0, -5.0], [0.5, 0, -5.0]), marks)):
        mask = np.zeros((h, w, 3), np.uint8)
        mask[my, mx] = 255
        write_image(tmp_path / f"mask{i}.png", mask)
        cams.append(Camera(f"{i}.png", w, h, K, np.eye(3), -np.array(centre), mask_path=tmp_path / f"mask{i}.png"))
    rng = np.random.default_rng(0)
    # Vertices on the z = 0 plane, projecting to pixel centres of camera 0 (camera 1's pixel
    # grid is offset by a whole number of pixels), plus some behind the cameras.
    pix = np.stack([rng.integers(-30, w + 30, 3000), rng.integers(-30, h + 30, 3000)], 1) + 0.5
    v = np.concatenate([np.c_[(pix - K[:2, 2]) / 100.0 * 5.0, np.zeros(len(pix))],
                        rng.uniform(-1, 1, (50, 3)) * [1, 1, 0] + [0, 0, -9]])
    tris = np.arange(len(v) - len(v) % 3).reshape(-1, 3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(tris))
    expected = np.ones(len(v), dtype=bool)
    for cam, (mx, my) in zip(cams, marks):
        uv, z = cam.project(v)
        px = np.floor(uv)
        inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        near = np.hypot(px[:, 0] - mx, px[:, 1] - my) <= 24  # the disk of radius 24 (skimage's disk)
        expected &= ~inside | near
    assert 30 < expected[:3000].sum() < 2500 and expected[3000:].all()
    culled = cull_by_masks(mesh, Scene(root=tmp_path, cameras=cams))
    kept_faces = expected[tris].all(axis=1)
    assert len(culled.triangles) == kept_faces.sum()
    survivors = np.unique(tris[kept_faces])
    assert np.array_equal(np.asarray(culled.vertices), v[survivors])


def split_long_edges(tri: np.ndarray, max_edge: float) -> np.ndarray:
    """Triangles (T,3,3) halved across their longest edge until no edge exceeds ``max_edge``."""
    while True:
        edges = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=-1)  # edge k: vertex k → k+1
        long = edges.max(axis=1) > max_edge
        if not long.any():
            return tri
        t, k = tri[long], edges[long].argmax(axis=1)
        a, b, c = (t[np.arange(len(t)), (k + j) % 3] for j in range(3))
        m = (a + b) / 2
        tri = np.concatenate([tri[~long], np.stack([a, m, c], 1), np.stack([m, b, c], 1)])


def test_dtu_protocol_on_the_ground_truth(object_scene, tmp_path):
    """A DTU-layout copy of the object scene (in 'mm', 50 mm per unit): the GT mesh scores
    a Chamfer distance of the order of the sampling density; a shifted mesh scores the shift."""
    import open3d as o3d

    scale = dtu_scale_mat()
    root = tmp_path / "scan1"
    write_dtu_layout(object_scene, root, scale)
    scene = load_scene(root)
    gt = read_mesh(object_scene.gt_mesh)
    files = write_dtu_ground_truth(object_scene, tmp_path, 1, scale)

    def score(mesh_path):
        return PROTOCOLS["dtu"].run(EvalInputs(scene, mesh_path, tmp_path / "m.json", gt=files["stl"],
                                               obs_mask=files["obs_mask"], plane=files["plane"],
                                               settings=EvalSettings(dtu_density=0.5)))

    # The mesh to score: the GT cut into small triangles (mask culling judges vertices),
    # keeping those whose centre some camera sees (no underside).
    tri = split_long_edges(np.asarray(gt.vertices)[np.asarray(gt.triangles)], 0.05)
    tri = tri[seen_counts(MeshRaycaster([gt]), object_scene.cameras, tri.mean(axis=1), stop_at=1) > 0]
    seen = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(tri.reshape(-1, 3)),
                                     o3d.utility.Vector3iVector(np.arange(3 * len(tri)).reshape(-1, 3)))
    o3d.io.write_triangle_mesh(str(tmp_path / "seen.ply"), seen)
    exact = score(tmp_path / "seen.ply")
    assert exact["protocol"] == "dtu" and exact["chamfer"] < 0.5 and exact["n_recon"] > 10_000
    assert len(o3d.io.read_point_cloud(str(tmp_path / "precision.ply")).points) == min(exact["n_recon"], 200_000)
    assert o3d.io.read_point_cloud(str(tmp_path / "recall.ply")).has_colors()
    # every score says which evaluator and which library versions produced it
    assert exact["evaluator"] == "eve3d.evaluate.dtu.evaluate_dtu"
    assert exact["versions"]["open3d"] == o3d.__version__ and exact["versions"]["scipy"] == scipy.__version__
    shifted = seen.translate([0, 0, 0.02])  # 1 mm in DTU units
    o3d.io.write_triangle_mesh(str(tmp_path / "shifted.ply"), shifted)
    moved = score(tmp_path / "shifted.ply")
    # Horizontal surfaces move by the full 1 mm, vertical ones along themselves: the accuracy
    # grows by a large part of the shift and never by more than the shift.
    assert exact["accuracy"] + 0.3 < moved["accuracy"] < exact["accuracy"] + 1.0


def test_protocols_score_the_same_a_chunk_at_a_time(tiny_scene, tmp_path, monkeypatch):
    """The synthetic, dtu and tnt protocols go through large clouds a chunk of points at a
    time (eve3d.core.chunking): with chunks of 1000 points (200 for the thinning's neighbour
    lists) every score equals the one from a single chunk. (open3d's threaded RANSAC and ICP
    move the T&T transform and its residual in their last digits from one run to the next,
    chunked or not.)"""
    import open3d as o3d

    from eve3d.core import chunking
    from eve3d.core.datasets import dtu_files
    from eve3d.tools.standin import write_dtu_release, write_tnt_release

    gt = read_mesh(tiny_scene.gt_mesh)
    tri = split_long_edges(np.asarray(gt.vertices)[np.asarray(gt.triangles)], 0.1) + [0.004, -0.002, 0.003]
    recon = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(tri.reshape(-1, 3)),
                                      o3d.utility.Vector3iVector(np.arange(3 * len(tri)).reshape(-1, 3)))
    o3d.io.write_triangle_mesh(str(tmp_path / "recon.ply"), recon)
    dtu_scan = write_dtu_release(tiny_scene, tmp_path / "dtu", stl_points=20_000)
    files = dtu_files(tmp_path / "dtu", dtu_scan.name)
    tnt = write_tnt_release(tiny_scene, tmp_path / "tnt", gt_points=20_000)
    cases = {"synthetic": dict(scene=tiny_scene, gt=tiny_scene.gt_mesh),
             "dtu": dict(scene=load_scene(dtu_scan), gt=files["stl"], obs_mask=files["obs_mask"], plane=files["plane"]),
             "tnt": dict(scene=load_scene(tnt))}
    settings = EvalSettings(samples=5000, dtu_density=1.0)

    def scores():
        out = {}
        for name, kw in cases.items():
            m = PROTOCOLS[name].run(EvalInputs(reconstruction=tmp_path / "recon.ply", out=tmp_path / name / "m.json",
                                               settings=settings, **kw))
            out[name] = {k: v for k, v in m.items() if k != "versions"}
        return out

    whole = scores()
    assert whole["synthetic"]["n_gt"] == 5000 and min(whole["dtu"]["n_recon"], whole["tnt"]["n_gt"]) > 3000, whole
    monkeypatch.setattr(chunking, "CHUNK", 1000)
    chunked = scores()
    for key in ("transformation", "alignment_rmse"):
        assert np.allclose(chunked["tnt"].pop(key), whole["tnt"].pop(key), rtol=0, atol=1e-9), key
    assert chunked == whole
