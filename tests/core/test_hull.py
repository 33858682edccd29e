"""eve3d.core.hull: the measured scene's hull, the rays and pixels that miss it, and whether the
cameras look out from within the scene."""
import numpy as np

from eve3d.core.hull import looks_out, measured_hull, misses
from eve3d.core.scene import Camera, Scene, look_at

CUBE = np.array([[1.0, 0, 0, -1], [-1, 0, 0, -1], [0, 1, 0, -1], [0, -1, 0, -1], [0, 0, 1, -1], [0, 0, -1, -1]])
"""The cube [−1, 1]³ as half-spaces n·x + b ≤ 0."""


def test_rays_miss_a_convex_hull_as_slab_tests_say():
    origin = np.array([0.0, 0.0, 5.0])
    directions = np.array([[0, 0, -1], [0.24, 0, -1], [0.2, 0.2, -1], [0, 0, 1], [1, 0, 0], [0.3, 0.3, -1]])
    # down through it; through its top just inside the edge (x = 0.25 · 4 would touch it);
    # through its top towards a corner; up, away from it; sideways, above it; past its corner
    assert misses(CUBE, origin, directions).tolist() == [False, False, False, True, True, True]
    assert misses(CUBE, origin, np.array([[0.26, 0, -1], [0.0, 0.26, -1]])).tolist() == [True, True]
    inside = np.random.default_rng(0).normal(size=(100, 3))  # from inside, every ray meets it
    assert not misses(CUBE, np.array([0.2, -0.3, 0.1]), inside).any()


def ring(n=12, radius=3.0, height=1.5):
    """Cameras around the origin looking at it, z up (an object capture)."""
    return [Camera(f"{i}.png", 64, 48, np.diag([50.0, 50, 1]),
                   *look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), np.zeros(3), np.array([0, 0, 1.0])))
            for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False))]


def box_points(half, n=2000, seed=0):
    """Points on the faces of the box [−half, half]."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, size=(n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(p[np.arange(n), axis])
    return p * half


def test_cameras_around_an_object_look_in_and_from_inside_a_room_look_out():
    obj = Scene(None, ring(), points=box_points(np.array([1.0, 1.0, 0.5])))
    assert not looks_out(obj)
    room_cams = [Camera(f"{i}.png", 64, 48, np.diag([50.0, 50, 1]),
                        *look_at(np.array([0.1 * np.cos(3 * a), 0.1 * np.sin(2 * a), 1.5]),
                                 np.array([3 * np.cos(a), 3 * np.sin(a), 1.2]), np.array([0, 0, 1.0])))
                 for i, a in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False))]
    room = Scene(None, room_cams, points=box_points(np.array([3.0, 2.5, 1.3])) + [0, 0, 1.3])
    assert looks_out(room)
    assert measured_hull(room, 0.1) is None  # nothing lies beyond a room seen from inside
    facade = [Camera(f"{i}.png", 64, 48, np.diag([50.0, 50, 1]), np.eye(3), -np.array([x, 0.0, 0.0]))
              for i, x in enumerate(np.linspace(-1, 1, 8))]  # parallel axes never meet
    assert not looks_out(Scene(None, facade, points=box_points(np.array([2.0, 1.0, 0.1])) + [0, 0, 3]))


def test_the_hull_holds_the_points_grown_by_its_margin_and_leaves_out_far_outliers():
    points = np.vstack([box_points(np.array([1.0, 1.0, 0.5])), [[40.0, 3, 2]]])  # one far outlier
    scene = Scene(None, ring(), points=points)
    hull = measured_hull(scene, 0.2)
    eq = hull.equations
    inside = eq[:, :3] @ np.array([[1.15, 0, 0], [0, 0, 0.55], [1.25, 0, 0], [40, 3, 2]]).T + eq[:, 3:4]
    assert (inside <= 1e-9).all(0).tolist() == [True, True, False, False]
    # from a camera of the ring: a ray at the box meets it, one over it to the sky does not
    cam = ring()[0]
    up = np.array([0.0, 0, 1])
    assert misses(eq, cam.center, np.array([-cam.center, -cam.center + 3 * up])).tolist() == [False, True]


def test_the_pixels_that_miss_the_hull_are_those_whose_rays_do():
    """``Hull.missed`` rasterises the hull's projected outline; the rays through the pixel
    centres (``misses``) say the same, from outside, from a camera with corners of the hull
    behind it, and from inside (no pixel misses)."""
    hull = measured_hull(Scene(None, ring(), points=box_points(np.array([1.0, 1.0, 0.5]))), 0.1)
    beside = Camera("b.png", 64, 48, np.diag([50.0, 50, 1]),  # half the hull behind it
                    *look_at(np.array([0.0, 1.4, 0.3]), np.array([3.0, 1.0, 0.3]), np.array([0, 0, 1.0])))
    inner = Camera("i.png", 64, 48, np.diag([50.0, 50, 1]),
                   *look_at(np.array([0.2, 0.1, 0.1]), np.array([3.0, 0, 0.3]), np.array([0, 0, 1.0])))
    for cam in ring() + [beside]:
        cam.K[:2, 2] = [32, 24]
        missed = hull.missed(cam)
        assert np.array_equal(missed, misses(hull.equations, cam.center, cam.pixel_rays()))
        assert 0.05 < missed.mean() < 0.95
    assert not hull.missed(inner).any()


def test_with_two_view_points_the_hull_takes_those_beside_the_reliable_ones_and_not_isolated_ones():
    """A box seen in three views or more, a rim of two-view points just beyond it (a floor's
    far edge that SfM saw less often) and a two-view point far from everything: the hull of
    the reliable points leaves the rim out; with ``two_view`` it takes the rim in and still
    leaves the far point out."""
    box = box_points(np.array([1.0, 1.0, 0.5]), n=4000)
    rim = np.array([[1.04, y, -0.5] for y in np.linspace(-1, 1, 60)])  # 0.034 apart, 0.04 beside the box's face
    points = np.vstack([box, rim, [[1.8, 0.0, 0.0]]])
    views = [np.arange(3)] * len(box) + [np.arange(2)] * (len(rim) + 1)
    scene = Scene(None, ring(), points=points, point_views=views)
    probes = np.array([[1.03, 0.5, -0.5], [1.5, 0, 0]]).T  # on the rim; towards the far point
    for two_view, inside_expected in ((False, [False, False]), (True, [True, False])):
        eq = measured_hull(scene, 0.0, two_view=two_view).equations
        assert ((eq[:, :3] @ probes + eq[:, 3:4]) <= 1e-9).all(0).tolist() == inside_expected
