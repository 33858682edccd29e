"""Scene I/O: COLMAP round trips, DTU camera decomposition, format detection."""
import shutil
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eve3d.core.io import load_scene
from eve3d.core.io.colmap import read_colmap, write_colmap
from eve3d.core.io.dtu import decompose_projection
from eve3d.core.scene import Camera, Scene, similarity_fit
from eve3d.tools.standin import dtu_scale_mat, write_dtu_layout


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_round_trip_is_exact(object_scene, tmp_path, binary):
    model = tmp_path / "sparse"
    write_colmap(object_scene, model, binary=binary)
    back = read_colmap(model, object_scene.root / "images")
    assert [c.name for c in back.cameras] == [c.name for c in object_scene.cameras]
    for a, b in zip(object_scene.cameras, back.cameras):
        assert np.array_equal(a.K, b.K) and (a.width, a.height) == (b.width, b.height)
        # COLMAP stores R as a quaternion: R comes back to the rounding of that conversion.
        assert np.abs(a.R - b.R).max() < 1e-14 and np.array_equal(a.t, b.t)
    assert np.array_equal(back.points, object_scene.points)
    assert np.array_equal(back.point_colors, object_scene.point_colors)
    assert all(np.array_equal(u, v) for u, v in zip(back.point_views, object_scene.point_views))


def test_a_model_is_read_where_open3d_is_not_installed(object_scene, tmp_path, monkeypatch):
    """The training stages read their scene on a GPU machine with pycolmap and no open3d."""
    write_colmap(object_scene, tmp_path / "sparse")
    monkeypatch.setitem(sys.modules, "open3d", None)  # `import open3d` now raises ImportError
    back = read_colmap(tmp_path / "sparse", object_scene.root / "images")
    assert [c.name for c in back.cameras] == [c.name for c in object_scene.cameras]
    assert np.array_equal(back.points, object_scene.points)


def test_dtu_world_mat_decomposes_and_recomposes():
    rng = np.random.default_rng(1)
    for _ in range(20):
        K = np.array([[rng.uniform(500, 3000), rng.uniform(-1, 1), rng.uniform(500, 900)],
                      [0, rng.uniform(500, 3000), rng.uniform(400, 700)], [0, 0, 1]])
        R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        t = rng.normal(0, 300, 3)
        P = rng.uniform(0.1, 10) * rng.choice([-1, 1]) * (K @ np.hstack([R, t[:, None]]))
        K2, R2, t2 = decompose_projection(P)
        assert np.allclose(K2, K, rtol=1e-6, atol=1e-6)
        assert np.allclose(R2, R, atol=1e-6) and np.linalg.det(R2) > 0
        P2 = K2 @ np.hstack([R2, t2[:, None]])
        Pn = P / (np.linalg.norm(P[2, :3]) * np.sign(np.linalg.det(P[:, :3])))  # P's own scale removed
        assert np.abs(P2 - Pn).max() / np.abs(Pn).max() < 1e-6


def test_dtu_reader_recovers_normalised_cameras(object_scene, tmp_path):
    write_dtu_layout(object_scene, tmp_path / "scan1", dtu_scale_mat())
    dtu = load_scene(tmp_path / "scan1")
    assert dtu.kind == "object" and np.array_equal(dtu.to_world, dtu_scale_mat())
    for a, b in zip(object_scene.cameras, dtu.cameras):
        assert np.allclose(a.K, b.K, rtol=1e-9) and np.allclose(a.R, b.R, atol=1e-9)
        assert np.allclose(a.center, b.center, atol=1e-9)
        assert b.mask_path is not None


def test_tnt_reader_finds_ground_truth_files(object_scene, tmp_path):
    root = tmp_path / "Barn"
    shutil.copytree(object_scene.root / "images", root / "images")
    write_colmap(object_scene, root / "sparse" / "0")
    (root / "Barn.ply").write_text("ply\n")
    (root / "Barn.json").write_text("{}")
    np.savetxt(root / "Barn_trans.txt", np.eye(4))
    log = "".join(f"{i} {i} 0\n" + "\n".join(" ".join(map(str, row)) for row in np.eye(4)) + "\n"
                  for i in range(len(object_scene.cameras)))
    (root / "Barn_COLMAP_SfM.log").write_text(log)
    scene = load_scene(root)
    assert scene.extras["format"] == "tnt" and scene.extras["name"] == "Barn"
    assert len(scene.extras["gt_trajectory"]) == len(scene.cameras)
    assert np.array_equal(scene.extras["alignment"], np.eye(4))


def test_scene_radius_and_similarity_fit():
    cams = [Camera(f"{i}.png", 8, 8, np.eye(3), np.eye(3), -np.array(c)) for i, c in
            enumerate([(1, 0, 0), (-1, 0, 0), (0, 2, 0), (0, -2, 0)])]
    scene = Scene(root=None, cameras=cams)
    assert np.allclose(scene.center, 0) and scene.radius == pytest.approx(2.2)
    rng = np.random.default_rng(0)
    src = rng.normal(size=(10, 3))
    R = Rotation.random(random_state=3).as_matrix()
    s, R2, t = similarity_fit(src, 2.5 * src @ R.T + [1, 2, 3])
    assert s == pytest.approx(2.5) and np.allclose(R2, R) and np.allclose(t, [1, 2, 3])


def test_isolated_points_are_two_view_points_far_from_every_reliable_one():
    """SfM's outliers, which `train.init_drop_isolated` leaves out of the start: a two-view
    point beside the well-seen surface stays, one far from it goes; a point seen in three
    views is never isolated."""
    from eve3d.gaussians.training import initial_points

    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 10), np.linspace(0, 1, 10), [0.0]), -1).reshape(-1, 3)
    points = np.vstack([grid, [[0.5, 0.5, 0.01], [0.5, 0.5, 2.0], [3.0, 0.0, 0.0]]])
    views = [[0, 1, 2]] * 100 + [[0, 1], [0, 1], [0, 1, 2]]
    scene = Scene(None, [], points=points, point_colors=np.full((103, 3), 128.0), point_views=views)
    assert scene.isolated().nonzero()[0].tolist() == [101]
    kept, colors = initial_points(scene, 10, rng, drop_isolated=True)
    assert len(kept) == len(colors) == 102 and not np.isclose(kept, [0.5, 0.5, 2.0]).all(1).any()
    assert len(initial_points(scene, 10, rng)[0]) == 103  # the default keeps every point
