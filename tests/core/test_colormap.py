"""eve3d.core.colormap: the error maps' colour table."""
import numpy as np

from eve3d.core.colormap import hot_r


def test_hot_r_colours():
    rgb = hot_r(np.array([0.0, 0.5, 1.0, 7.0]))
    assert np.allclose(rgb[0], 1.0) and np.allclose(rgb[2], [0.0416, 0, 0]) and np.allclose(rgb[3], rgb[2])
    assert rgb[1, 0] == 1.0 and 0.3 < rgb[1, 1] < 0.4 and rgb[1, 2] == 0.0   # orange at the middle
