"""eve3d.evaluate: the evaluate stage (its command, τ and its rule) and its protocols a chunk at a time."""
import json

import numpy as np

from eve3d.core.fileio import read_mesh
from eve3d.core.io import load_scene
from eve3d.core.settings import EvalSettings
from eve3d.evaluate import PROTOCOLS, EvalInputs
from tests.helpers import run_cli, split_long_edges


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
