"""eve3d.tools.bench.evaluate: the meshes it times the scoring on, and its arguments."""
import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.tools.bench.evaluate import floater_mesh, format_evaluate_table, run_bench_evaluate


def test_floater_mesh_is_the_subdivided_gt_and_its_floaters_in_the_air():
    import open3d as o3d

    gt = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 0.05)  # a table top: z in [0, 0.05]
    mesh = floater_mesh(gt, 100, 2, np.random.default_rng(0))
    assert len(mesh.triangles) == 16 * len(gt.triangles) + 100  # each subdivision splits a triangle in 4
    floaters = np.asarray(mesh.vertices)[-300:]
    assert floaters[:, 2].min() > 0.05  # above the table
    rows = [{"mesh": "GT + floaters", "triangles": len(mesh.triangles), "seconds": 1.5, "peak_mb": 300,
             "precision": 0.5, "recall": 1.0, "fscore": 0.6667}]
    assert format_evaluate_table(rows).splitlines()[-1].split() == ["GT", "+", "floaters", "292", "1.5", "300",
                                                                    "0.5000", "1.0000", "0.6667"]


def test_meshes_without_their_scene_and_gt_are_refused():
    with pytest.raises(Eve3dError, match="--meshes needs --scene"):
        run_bench_evaluate(["results/s/pgsr/mesh.ply"])
