"""eve3d.priors.matching: what the stereo backends share (the left–right check, mirroring, the texture measure)."""
import numpy as np

from eve3d.priors.matching import left_right_consistent, local_std, mirrored


def test_the_left_right_check_keeps_what_the_right_disparity_confirms():
    disp_l = np.full((3, 10), 4.0)
    disp_r = np.full((3, 10), 4.0)
    kept = left_right_consistent(disp_l, disp_r, 1.0)
    assert np.array_equal(kept, np.tile(np.arange(10) >= 4, (3, 1)))  # x − d < 0 lands outside the right image
    disp_r[:, 3] = 5.5  # where x = 7 lands: 1.5 px off
    assert not left_right_consistent(disp_l, disp_r, 1.0)[:, 7].any()
    assert left_right_consistent(disp_l, disp_r, 1.5)[:, 7].all()
    disp_l[0, 8] = 0  # no match: never kept
    assert not left_right_consistent(disp_l, disp_r, 1.5)[0, 8]


def test_mirroring_turns_the_right_view_into_a_left_view():
    left = np.arange(12.0).reshape(3, 4)
    right = left * 10
    seen = []

    def matcher(a, b):  # records what it is given, returns its left image's column index
        seen.append((a.copy(), b.copy()))
        return np.tile(np.arange(a.shape[1], dtype=float), (a.shape[0], 1))

    out = mirrored(matcher, left, right)
    assert np.array_equal(seen[0][0], right[:, ::-1]) and np.array_equal(seen[0][1], left[:, ::-1])
    assert np.array_equal(out, np.tile([3.0, 2, 1, 0], (3, 1))) and out.flags["C_CONTIGUOUS"]


def test_local_std_is_the_windows_grey_level_deviation():
    flat = np.full((9, 9, 3), 77, np.uint8)
    assert np.abs(local_std(flat, 5)).max() < 1e-3
    stripes = np.tile(np.array([0, 255] * 5, np.uint8), (9, 1))  # columns alternate 0, 255
    std = local_std(stripes, 3)[:, 1:-1]  # away from the border: windows of {0, 255, 0} or {255, 0, 255}
    np.testing.assert_allclose(std, 255 * np.sqrt(2) / 3, rtol=1e-4)
