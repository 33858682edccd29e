"""eve3d.core.maps: depth maps' previews."""
import numpy as np

from eve3d.core.maps import preview_image


def test_depth_preview_shows_only_confident_depth():
    """A matcher that keeps a guess where it is not confident (mccnn, a network): the preview
    leaves those pixels black, and a far wrong guess does not flatten the others' colours."""
    depth = np.tile(np.linspace(2.0, 3.0, 40, dtype=np.float32), (10, 1))
    depth[:, :5] = 80.0  # rejected guesses
    confidence = np.ones_like(depth)
    confidence[:, :5] = 0
    shown = preview_image("depth", depth, confidence)
    assert not shown[:, :5].any()
    assert np.ptp(shown[:, 5:].astype(int), axis=1).max() > 100  # 2 → 3 still spans the colour map
    assert preview_image("depth", depth)[:, :5].any()  # without a confidence every depth shows


def test_normal_preview_colours_each_direction_and_leaves_no_normal_black():
    """Camera frame (x right, y down, z forward): a surface facing the camera (0, 0, −1) is
    blue-violet, one facing up (0, −1, 0) green, and a pixel without a normal (zero, or NaN
    where a depth had none) black."""
    normal = np.zeros((2, 3, 3), np.float32)
    normal[1, 2] = np.nan
    normal[0, 0] = (0, 0, -1)
    normal[0, 1] = (0, -1, 0)
    normal[1, 0] = (1, 0, 0)
    shown = preview_image("normal", normal)
    assert shown.dtype == np.uint8
    assert shown[0, 0].tolist() == [127, 127, 255]
    assert shown[0, 1].tolist() == [127, 255, 127]
    assert shown[1, 0].tolist() == [255, 127, 127]
    assert shown[1, 1].tolist() == shown[1, 2].tolist() == [0, 0, 0]
