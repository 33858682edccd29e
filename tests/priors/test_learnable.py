"""eve3d.priors.learnable: the priors inside training, resampled to the training size."""
import numpy as np

from eve3d.priors.learnable import resample_prior


def test_resampling_does_not_mix_valid_and_invalid_depths():
    depth = np.array([[2.0, 2.0, 4.0, 0.0], [2.0, 0.0, 0.0, 0.0]], np.float32)
    conf = np.array([[1, 1, 1, 0], [1, 1, 0, 0]], np.float32)
    small, small_conf = resample_prior(depth, conf, 2, 1)
    # left block: 3 valid depths of 2 → 2 (not 1.5 from the zero); right: 1 valid of 4 → invalid
    assert small.tolist() == [[2.0, 0.0]] and small_conf.tolist() == [[1.0, 0.0]]
