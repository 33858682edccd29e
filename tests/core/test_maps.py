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
