"""eve3d.gaussians.neighbours: each view's neighbours for the multi-view losses, scored by triangulation angle."""
import numpy as np

from eve3d.core.scene import Camera, Scene
from eve3d.gaussians.neighbours import neighbour_scores, select_neighbours, triangulation_score


def _cameras(xs, flipped=()):
    """Cameras at (x, 0, 0) looking down +z; those in ``flipped`` look down −z."""
    K = np.array([[50.0, 0, 20], [0, 50, 15], [0, 0, 1]])
    back = np.diag([-1.0, 1, -1])  # half a turn about y
    return [Camera(f"{i}.png", 40, 30, K, back if i in flipped else np.eye(3),
                   -(back if i in flipped else np.eye(3)) @ np.array([x, 0.0, 0.0])) for i, x in enumerate(xs)]


def test_the_score_peaks_at_five_degrees_and_falls_slower_above():
    assert triangulation_score(np.array([5.0]))[0] == 1.0
    np.testing.assert_allclose(triangulation_score(np.array([3.0, 7.0, 15.0, 25.0])),
                               [np.exp(-2), np.exp(-4 / 200), np.exp(-100 / 200), np.exp(-400 / 200)])


def test_neighbours_share_points_at_a_useful_angle_or_else_are_near():
    """One point 10 ahead seen by three cameras on a line: the pairs score η of the angle
    between their rays; each view's best neighbour follows. Without points the nearest
    centre among cameras facing the same way stands in."""
    xs = (0.0, 0.875, 3.0)
    point = np.array([0.0, 0.0, 10.0])
    scene = Scene(None, _cameras(xs), points=point[None], point_views=[np.array([0, 1, 2])])
    angle = np.degrees(np.arctan(np.array(xs) / 10))  # each ray's angle to the z axis, all in the xz plane
    theta = np.abs(angle[:, None] - angle[None])
    expected = triangulation_score(theta)
    np.fill_diagonal(expected, 0)
    np.testing.assert_allclose(neighbour_scores(scene), expected, rtol=1e-9)
    assert expected[0, 1] > expected[1, 2] > expected[0, 2] > 0.4  # 5.0°, 11.7°, 16.7°
    assert select_neighbours(scene, 1) == [[1], [0], [1]] and select_neighbours(scene, 2) == [[1, 2], [0, 2], [1, 0]]
    bare = Scene(None, _cameras((0.0, 0.1, 0.5, 2.0), flipped=(1,)))
    assert select_neighbours(bare, 2) == [[2, 3], [], [0, 3], [2, 0]]  # camera 1 faces the other way
