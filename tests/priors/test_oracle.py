"""eve3d.priors.oracle: the exact depth of a scene with a known mesh."""
import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps
from eve3d.core.scene import Scene
from eve3d.priors.oracle import priors_from_mesh
from tests.helpers import tilted_plane


def test_oracle_maps_are_the_meshs_depth_confident_where_the_rays_hit(tmp_path):
    cam, _, exact = tilted_plane(tmp_path / "gt.ply")
    scene = Scene(tmp_path, [cam], gt_mesh=tmp_path / "gt.ply")
    priors_from_mesh(scene, tmp_path / "oracle", preview=False)
    maps = load_maps(tmp_path / "oracle/v.npz")
    assert set(maps) == {"depth", "confidence", "normal"} and maps["depth"].dtype == np.float32
    np.testing.assert_allclose(maps["depth"], exact, rtol=1e-5)
    assert np.array_equal(maps["confidence"], (exact > 0).astype(np.float32))
    n = np.array([0.5, 0, -1]) / np.linalg.norm([0.5, 0, -1])  # camera frame = world frame here
    np.testing.assert_allclose(maps["normal"][exact > 0], np.broadcast_to(n, ((exact > 0).sum(), 3)), atol=1e-6)
    with pytest.raises(Eve3dError, match="the oracle depth source needs a ground-truth mesh"):
        priors_from_mesh(Scene(tmp_path, [cam]), tmp_path / "none")
    assert not (tmp_path / "none").exists()
