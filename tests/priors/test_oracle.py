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


def test_degraded_priors_have_the_errors_they_are_given():
    """Each error of ``stereo.oracle`` alone, on a depth map with an empty quarter and a plain
    band in its photo, measured back: the noise's median error is 0.674 σ (a normal's), the
    outliers' share of pixels off by over 5 %, the empty pixels given the nearest surface's depth
    (those nearest first), the bias on the plain band only, the holes' share of the surface, and of the plain band alone;
    and no error at all leaves the exact depth."""
    from eve3d.core.settings_stereo import Degradation
    from eve3d.priors.oracle import degraded

    h, w = 120, 160
    depth = np.tile(np.linspace(2.0, 3.0, w), (h, 1))
    depth[:40, 100:] = 0  # no surface: a sky
    photo = np.random.default_rng(1).integers(0, 255, (h, w, 3)).astype(np.uint8)
    photo[60:90] = 128  # plain
    surface, plain = depth > 0, np.zeros((h, w), bool)
    plain[62:88] = True  # away from the band's textured border

    def run(**errors):
        return degraded(depth, photo, Degradation(**errors), np.random.default_rng(0))

    out, conf = run()
    assert np.array_equal(out, depth) and np.array_equal(conf, surface.astype(np.float32))
    rel = (run(noise=0.01)[0] - depth)[surface] / depth[surface]
    assert np.median(np.abs(rel)) == pytest.approx(0.00674, rel=0.1)
    rel = np.abs(run(outliers=0.1)[0] - depth)[surface] / depth[surface]
    assert np.mean(rel > 0.05) == pytest.approx(0.1, abs=0.01) and rel.max() <= 0.15 + 1e-9
    out, conf = run(empty=0.25)
    filled = (conf > 0) & ~surface
    assert filled.sum() == round(0.25 * (~surface).sum())
    assert np.all(out[filled] >= 2.6) and filled[39, 100] and not filled[0, 159]  # beside the edge, not far
    rel = (run(weak_bias=-0.02)[0] - depth)[surface] / depth[surface]
    assert np.allclose(rel[plain[surface]], -0.02) and np.mean(rel[~plain[surface]] == 0) > 0.7
    out, conf = run(holes=0.2)
    assert (conf[surface] == 0).mean() == pytest.approx(0.2, abs=0.01) and np.array_equal(out, depth)
    out, conf = run(weak_holes=0.5)
    assert (conf[plain] == 0).mean() == pytest.approx(0.5, abs=0.05) and (conf[surface & ~plain] == 0).mean() < 0.1
