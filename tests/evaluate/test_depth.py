"""eve3d.evaluate.depth: depth maps scored against the exact depth, the error signed (issue 19)."""
import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import save_maps
from eve3d.evaluate.depth import depth_accuracy


def test_depth_accuracy_signs_the_error(tmp_path):
    """Too near is negative (and its absolute value positive); the median ignores a minority
    of gross errors; unconfident pixels and pixels without exact depth are left out."""
    exact = np.full((20, 30), 2.0, np.float32)
    exact[:, :3] = 0  # no exact depth there (a miss)
    depth = exact * 0.99
    depth[:4] = 5.0  # 20 % of the rows grossly wrong, too far
    confidence = np.ones_like(exact)
    confidence[:, -3:] = 0
    save_maps(tmp_path / "exact" / "a.npz", preview=False, depth=exact, confidence=(exact > 0).astype(np.float32))
    save_maps(tmp_path / "maps" / "a.npz", preview=False, depth=depth, confidence=confidence)
    acc = depth_accuracy(tmp_path / "maps", tmp_path / "exact")
    assert acc["median_signed_error"] == pytest.approx(-0.01, rel=1e-4)
    assert acc["median_rel_error"] == pytest.approx(0.01, rel=1e-4)
    assert acc["density"] == pytest.approx(24 / 27)
    assert acc["wrong_10"] == pytest.approx(4 / 20)
    save_maps(tmp_path / "squeezed" / "a.npz", preview=False, depth=exact[::2], confidence=confidence[::2])
    with pytest.raises(Eve3dError, match="maps of different shapes"):
        depth_accuracy(tmp_path / "squeezed", tmp_path / "exact")
    # a map at half the size (priors matched at the pretrain's size) is scored at the exact depth's size
    half = depth[::2, ::2]
    save_maps(tmp_path / "half" / "a.npz", preview=False, depth=half, confidence=confidence[::2, ::2])
    small = depth_accuracy(tmp_path / "half", tmp_path / "exact")
    # nearest resampling moves the unconfident columns' edge by up to a pixel
    assert small["median_signed_error"] == pytest.approx(-0.01, rel=1e-4) and small["density"] == pytest.approx(24 / 27, abs=0.01)
    save_maps(tmp_path / "no_depth" / "a.npz", preview=False, confidence=confidence)
    with pytest.raises(Eve3dError, match="no 'depth' array"):
        depth_accuracy(tmp_path / "no_depth", tmp_path / "exact")
    save_maps(tmp_path / "none" / "a.npz", preview=False, depth=depth, confidence=0 * confidence)
    assert depth_accuracy(tmp_path / "none", tmp_path / "exact")["median_signed_error"] is None  # nothing to score


def test_depth_accuracy_on_weak_texture(tmp_path):
    """With the photos, the weakly textured pixels (a flat grey half) are scored on their own:
    their share of the surface, how many have a depth, and their error."""
    import cv2

    exact = np.full((20, 40), 2.0, np.float32)
    photo = np.full((20, 40), 128, np.uint8)
    photo[:, 20:] = np.random.default_rng(0).integers(0, 255, (20, 20))  # textured right half
    depth = exact * 1.01
    depth[:, 20:] = exact[:, 20:] * 0.98
    confidence = np.ones_like(exact)
    confidence[:, :10] = 0  # half of the flat half has no depth
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "a.png"), photo)
    save_maps(tmp_path / "exact" / "a.npz", preview=False, depth=exact, confidence=np.ones_like(exact))
    save_maps(tmp_path / "maps" / "a.npz", preview=False, depth=depth, confidence=confidence)
    acc = depth_accuracy(tmp_path / "maps", tmp_path / "exact", images=tmp_path / "images", window=5)
    # the 5 px window reaches 2 px into the textured half from the flat one
    assert acc["weak_share"] == pytest.approx(18 / 40)
    assert acc["weak_density"] == pytest.approx(8 / 18)
    assert acc["weak_rel_error"] == pytest.approx(0.01, rel=1e-4)
    assert "weak_share" not in depth_accuracy(tmp_path / "maps", tmp_path / "exact")
    with pytest.raises(Eve3dError, match="no photo of view a"):
        depth_accuracy(tmp_path / "maps", tmp_path / "exact", images=tmp_path)


def test_median_without_a_float64_copy_is_numpys():
    """depth_accuracy's median of float32 errors equals np.median of their float64 copy."""
    from eve3d.evaluate.depth import median

    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 10_000, 10_001):
        x = (rng.normal(size=n) * 1e-3).astype(np.float32)
        assert median(x) == float(np.median(x.astype(np.float64)))
    assert np.isnan(median(np.array([1.0, np.nan], np.float32)))
