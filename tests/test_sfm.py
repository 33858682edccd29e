"""SfM on a generated object scene given as images only."""
import numpy as np
import pytest

from eve3d.core.io import load_scene
from eve3d.core.io.colmap import read_colmap
from eve3d.core.scene import similarity_fit
from eve3d.synth import generate
from tests.helpers import TINY_START, run_cli


@pytest.mark.slow
def test_sfm_registers_every_view_and_recovers_the_poses(tmp_path):
    # the sparse points are hidden under gt/ and unused: exact samples spare SIFT on the known poses
    data = generate("object", tmp_path / "data", views=32, width=640, height=480, images_only=True,
                    surface_samples=TINY_START)
    assert not (data / "sparse").exists()
    result = run_cli("sfm", data, tmp_path / "sfm")
    assert result.returncode == 0, result.stderr[-2000:]
    est = load_scene(tmp_path / "sfm")
    truth = read_colmap(data / "gt" / "sparse" / "0", data / "images")
    assert sorted(c.name for c in est.cameras) == sorted(c.name for c in truth.cameras)
    assert all(c.K[0, 1] == 0 for c in est.cameras)  # undistorted to PINHOLE
    E = np.array([est.camera(c.view_id).center for c in truth.cameras])
    G = np.array([c.center for c in truth.cameras])
    s, R, t = similarity_fit(E, G)
    err = np.linalg.norm(s * E @ R.T + t - G, axis=1) / truth.radius
    print(f"camera centre error / scene radius: max {err.max():.4f}, mean {err.mean():.4f}")
    # Single-threaded (the default), SfM is bit-reproducible: measured max 0.65 %, mean 0.25 %.
    assert err.max() < 0.01


def test_generated_scenes_start_from_points_sfm_triangulates(object_dataset):
    """A generated scene's sparse points are what a user's SfM gives with known poses
    (features matched and triangulated by pycolmap), not samples of the GT surface: most lie
    on the surface, some do not, every point is seen by two views or more and projects
    near its features, and the poses are the generator's, untouched."""
    import open3d as o3d

    scene = load_scene(object_dataset)
    gt = o3d.t.geometry.RaycastingScene()
    gt.add_triangles(o3d.t.io.read_triangle_mesh(str(object_dataset / "gt" / "mesh.ply")))
    distance = gt.compute_distance(o3d.core.Tensor(scene.points.astype(np.float32))).numpy()
    print(f"{len(scene.points)} points; distance to the GT surface: median {np.median(distance):.4f}, "
          f"within 1 cm {np.mean(distance < 0.01):.2f}, beyond 10 cm {np.mean(distance > 0.1):.2f}")
    assert len(scene.points) > 1000
    assert np.median(distance) < 0.01 and 0.5 < np.mean(distance < 0.01) < 0.95  # outliers and all
    assert all(len(v) >= 2 for v in scene.point_views)
    colmap = read_colmap(object_dataset / "sparse" / "0", object_dataset / "images")
    assert [c.center.round(9).tolist() for c in colmap.cameras] == [c.center.round(9).tolist() for c in scene.cameras]
