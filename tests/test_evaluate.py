"""Evaluation protocols against brute-force references and known answers."""
import numpy as np
import pytest
from scipy.io import savemat

from eve3d.evaluate import cloud_metrics, evaluate_dtu, evaluate_synthetic, read_mesh
from eve3d.io import load_scene
from eve3d.surface import sample_surface
from tests.test_scene_io import dtu_scale_mat, write_dtu_layout


def brute_force_metrics(recon, gt, tau):
    d = np.linalg.norm(recon[:, None] - gt[None], axis=-1)
    d_rg, d_gr = d.min(1), d.min(0)
    p, r = np.mean(d_rg < tau), np.mean(d_gr < tau)
    return {"accuracy": d_rg.mean(), "completeness": d_gr.mean(), "chamfer": (d_rg.mean() + d_gr.mean()) / 2,
            "precision": p, "recall": r, "fscore": 2 * p * r / (p + r)}


def test_cloud_metrics_match_brute_force():
    rng = np.random.default_rng(0)
    for n, m in [(500, 700), (1000, 300)]:
        recon, gt = rng.random((n, 3)), rng.random((m, 3)) + 0.05
        ours, ref = cloud_metrics(recon, gt, 0.08), brute_force_metrics(recon, gt, 0.08)
        for key in ref:
            assert ours[key] == pytest.approx(ref[key], abs=1e-6), key


def test_mesh_against_itself_scores_perfectly(object_scene):
    m = evaluate_synthetic(object_scene.gt_mesh, object_scene.gt_mesh, object_scene)
    assert m["precision"] == 1.0 and m["recall"] == 1.0 and m["fscore"] == 1.0
    assert m["chamfer"] < m["tau"] / 3
    assert m["tau"] == pytest.approx(0.005 * object_scene.radius)


def test_dtu_protocol_on_the_ground_truth(object_scene, tmp_path):
    """A DTU-layout copy of the object scene (in 'mm', 50 mm per unit): the GT mesh scores
    a Chamfer distance of the order of the sampling density; a shifted mesh scores the shift."""
    import open3d as o3d

    scale = dtu_scale_mat()
    root = tmp_path / "scan1"
    write_dtu_layout(object_scene, root, scale)
    scene = load_scene(root)
    gt = read_mesh(object_scene.gt_mesh)
    mm = o3d.geometry.TriangleMesh(gt).transform(scale)
    rng = np.random.default_rng(0)
    stl = sample_surface(np.asarray(mm.vertices), np.asarray(mm.triangles), 300_000, rng)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(stl))
    o3d.io.write_point_cloud(str(tmp_path / "stl001_total.ply"), cloud)
    res, lo = 4.0, stl.min(0) - 8
    shape = np.ceil((stl.max(0) + 8 - lo) / res).astype(int)
    obs = np.zeros(shape, dtype=np.uint8)
    idx = np.round((stl - lo) / res).astype(int)
    obs[idx[:, 0], idx[:, 1], idx[:, 2]] = 1
    savemat(tmp_path / "ObsMask1_10.mat", {"ObsMask": obs, "BB": np.stack([lo, lo + shape * res]), "Res": res})
    savemat(tmp_path / "Plane1.mat", {"P": np.array([0, 0, 1.0, -(scale[2, 3] + 0.001 * scale[2, 2])])})
    args = (scene, tmp_path / "stl001_total.ply", tmp_path / "ObsMask1_10.mat", tmp_path / "Plane1.mat")
    exact = evaluate_dtu(object_scene.gt_mesh, *args, density=0.5)
    assert exact["chamfer"] < 0.5 and exact["n_recon"] > 10_000
    shifted = o3d.geometry.TriangleMesh(gt).translate([0, 0, 0.02])  # 1 mm in DTU units
    o3d.io.write_triangle_mesh(str(tmp_path / "shifted.ply"), shifted)
    moved = evaluate_dtu(tmp_path / "shifted.ply", *args, density=0.5)
    # Horizontal surfaces move by the full 1 mm, vertical ones along themselves: the accuracy
    # grows by a large part of the shift and never by more than the shift.
    assert exact["accuracy"] + 0.3 < moved["accuracy"] < exact["accuracy"] + 1.0
