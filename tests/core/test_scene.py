"""eve3d.core.scene: a scene's centre and radius, the similarity fit, SfM's isolated points."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eve3d.core.scene import Camera, Scene, similarity_fit


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

