"""eve3d.core.raycast: exact depth, normals and visibility of a mesh seen by a camera."""
import numpy as np

from eve3d.core.raycast import MeshRaycaster, seen_counts
from tests.helpers import tilted_plane


def test_a_tilted_plane_gives_its_exact_depth_and_a_normal_facing_the_camera():
    cam, mesh, exact = tilted_plane()
    hits = MeshRaycaster([mesh]).cast(cam)
    left = exact > 0
    assert left[:, :20].all() and not left[:, 20:].any()
    np.testing.assert_allclose(hits.depth, exact, rtol=1e-5)  # float32 rays
    assert np.array_equal(hits.valid, left) and np.all(hits.geometry[left] == 0) and np.all(hits.triangle[~left] == -1)
    np.testing.assert_allclose(hits.normal[left], np.broadcast_to([0.5, 0, -1] / np.linalg.norm([0.5, 0, -1]),
                                                                  (left.sum(), 3)), atol=1e-6)
    np.testing.assert_allclose(hits.points[left][:, 2], 2 + hits.points[left][:, 0] / 2, atol=1e-5)
    assert not hits.normal[~left].any()


def test_a_point_behind_the_surface_or_outside_the_image_is_not_seen():
    cam, mesh, _ = tilted_plane()
    caster = MeshRaycaster([mesh])
    on = np.array([-0.5, 0.1, 1.75])  # on the plane (z = 2 + x/2)
    points = np.array([0.9 * on, on, 1.5 * on, [2.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    assert seen_counts(caster, [cam], points).tolist() == [1, 1, 0, 0, 0]
    assert seen_counts(caster, [cam, cam], points, stop_at=1).tolist() == [1, 1, 0, 0, 0]
    assert seen_counts(caster, [cam, cam], points).tolist() == [2, 2, 0, 0, 0]
