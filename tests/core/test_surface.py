"""eve3d.core.surface: points sampled uniformly over a mesh's area."""
import numpy as np

from eve3d.core.surface import sample_surface


def test_samples_lie_on_the_triangles_in_proportion_to_their_area():
    """A unit square (two triangles of area 1/2) beside a triangle of area 2 at z = 1: a
    third of the samples on the square, uniform over it; the same seed, the same points;
    a mesh without area, none."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [3, 0, 1], [5, 0, 1], [3, 2, 1]], float)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    points = sample_surface(vertices, triangles, 20_000, np.random.default_rng(0))
    on_square = points[:, 2] == 0
    assert points.shape == (20_000, 3) and np.all(on_square | np.isclose(points[:, 2], 1, rtol=0, atol=1e-12))
    assert abs(on_square.mean() - 1 / 3) < 0.01
    square = points[on_square]
    assert square[:, :2].min() >= 0 and square[:, :2].max() <= 1
    assert abs((square[:, 0] < 0.5).mean() - 0.5) < 0.03 and abs((square[:, 1] > square[:, 0]).mean() - 0.5) < 0.03
    big = points[~on_square]  # inside the triangle (3,0), (5,0), (3,2): x ≥ 3, y ≥ 0, x + y ≤ 5
    assert big[:, 0].min() >= 3 and big[:, 1].min() >= 0 and (big[:, 0] + big[:, 1]).max() <= 5 + 1e-12
    assert np.array_equal(points, sample_surface(vertices, triangles, 20_000, np.random.default_rng(0)))
    flat = sample_surface(np.zeros((3, 3)), np.array([[0, 1, 2]]), 10, np.random.default_rng(0))
    assert flat.shape == (0, 3)
