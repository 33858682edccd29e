"""Virtual stereo: right cameras, SGBM with its left–right check, depth from disparity."""
import json

import numpy as np
import pytest

from eve3d.bench import stereo_motorcycle
from eve3d.maps import load_maps
from eve3d.scene import Camera, Eve3dError, Scene
from eve3d.stereo import PAIRS_FILE, SgbmSettings, right_camera, sgbm_disparity, sgbm_priors


def test_right_camera_gives_disparity_fx_b_over_z():
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    angle = np.radians(30)
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    left = Camera("a.png", 320, 240, K, R, np.array([0.1, -0.2, 0.3]))
    right = right_camera(left, 0.25)
    assert np.allclose(right.R, left.R) and np.allclose(right.K, left.K)
    assert np.allclose(right.center - left.center, 0.25 * left.R[0])  # along the camera's own x axis
    points = np.random.default_rng(0).normal(size=(50, 3)) + left.center + 4 * left.R[2]
    (uv_l, z), (uv_r, _) = left.project(points), right.project(points)
    assert np.allclose(uv_l[:, 0] - uv_r[:, 0], 300 * 0.25 / z) and np.allclose(uv_l[:, 1], uv_r[:, 1])


def test_sgbm_on_motorcycle_meets_the_bar():
    r = stereo_motorcycle()
    print(r)
    assert r["density"] >= 0.80 and r["bad2"] <= 8.0


def shifted_pair(disparity: int, h: int = 96, w: int = 128):
    rng = np.random.default_rng(1)
    import cv2

    tex = cv2.resize(rng.integers(0, 255, (h // 4, (w + disparity) // 4, 3)).astype(np.uint8),
                     (w + disparity, h), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, disparity:])  # x_right = x_left − d


def test_sgbm_recovers_a_constant_disparity_and_rejects_flat_regions():
    left, right = shifted_pair(8)
    left[:, 90:] = right[:, 90:] = 0  # a flat black band: nothing to match
    disp, confidence = sgbm_disparity(left, right, 32)
    core = confidence[:, 40:80] >= 0.5
    assert core.mean() > 0.9 and np.allclose(disp[:, 40:80][core], 8, atol=0.1)
    assert not confidence[:, 100:].any()


def test_wls_fills_the_disparity_and_keeps_it():
    """WLS gives a value to pixels that the left–right check rejects, keeps the constant
    disparity where it is confident, and its confidence still ignores the flat band."""
    left, right = shifted_pair(8)
    left[:, 90:] = right[:, 90:] = 0
    raw, raw_conf = sgbm_disparity(left, right, 32)
    disp, confidence = sgbm_disparity(left, right, 32, SgbmSettings(wls=True))
    core = confidence[:, 40:80] >= 0.5
    assert core.mean() > 0.9 and np.allclose(disp[:, 40:80][core], 8, atol=0.1)
    assert (disp[:, :90] > 0).mean() > (raw[:, :90] > 0).mean()
    assert not confidence[:, 100:].any() and 0 <= confidence.min() and confidence.max() <= 1


def stereo_scene(tmp_path, disparity: int, baseline: float = 0.5):
    """One view (fx = 100) and its right view, a constant-disparity textured pair; the pair
    file is written only on request (see the test of its absence)."""
    import cv2

    left, right = shifted_pair(disparity)
    cv2.imwrite(str(tmp_path / "v.png"), left[..., ::-1])
    (tmp_path / "stereo/right").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "stereo/right/v.png"), right[..., ::-1])
    K = np.array([[100.0, 0, 64], [0, 100, 48], [0, 0, 1]])
    scene = Scene(tmp_path, [Camera("v.png", 128, 96, K, np.eye(3), np.zeros(3), image_path=tmp_path / "v.png")])
    pairs = {"baseline": baseline, "views": {"v": {"max_disparity": 3 * disparity}}}
    return scene, lambda: (tmp_path / "stereo" / PAIRS_FILE).write_text(json.dumps(pairs))


def test_sgbm_priors_write_depth_fx_b_over_d(tmp_path):
    scene, write_pairs = stereo_scene(tmp_path, 10)
    with pytest.raises(Eve3dError, match="pairs.json: missing"):
        sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    write_pairs()
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.5
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 100 * 0.5 / 10, rtol=1e-3)
    assert (tmp_path / "priors/v.depth.png").exists() and (tmp_path / "priors/v.confidence.png").exists()
