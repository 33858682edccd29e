"""The error maps' colours: matplotlib's ``hot_r`` without matplotlib (white at 0, through
yellow and red, to black at 1), and its inverse, so that a viewer can read the distance
fraction back from a coloured ``precision.ply`` / ``recall.ply``."""
from __future__ import annotations

import numpy as np

_HOT = ((0.0, 0.365079, 1.0), (0.0416, 1.0, 1.0),                 # red
        (0.0, 0.365079, 0.746032, 1.0), (0.0, 0.0, 1.0, 1.0),      # green
        (0.0, 0.746032, 1.0), (0.0, 0.0, 1.0))                     # blue
"""``hot``'s piecewise-linear channels: (positions, values) of red, green and blue."""


def hot_r(x: np.ndarray) -> np.ndarray:
    """``hot_r`` (N,) → RGB (N, 3): ``hot``'s channels, reversed, read from a 256-entry
    table as matplotlib does."""
    x = np.asarray(x, dtype=np.float64)
    index = np.clip(np.floor(np.nan_to_num(x, nan=0.0) * 256), 0, 255)
    u = 1.0 - index / 255.0   # reversed map: hot at 1 - x
    return np.stack([np.interp(u, _HOT[2 * c], _HOT[2 * c + 1]) for c in range(3)], axis=-1)


def hot_r_fraction(rgb: np.ndarray) -> np.ndarray:
    """The inverse of :func:`hot_r` on its colours: RGB (N, 3) → x in [0, 1], the middle of
    the table's entry (within half of its 1/256 step). Each of hot's ramps moves one channel,
    so the first channel still below 1 says where along ``hot`` a colour lies."""
    (r_at, r_val), (g_at, _), (b_at, _) = (_HOT[0], _HOT[1]), (_HOT[2], _HOT[3]), (_HOT[4], _HOT[5])
    r, g, b = np.clip(np.asarray(rgb, dtype=np.float64), 0, 1).T
    u = np.where(b > 0, b_at[1] + b * (1 - b_at[1]),
                 np.where(g > 0, g_at[1] + g * (g_at[2] - g_at[1]),
                          np.clip((r - r_val[0]) / (1 - r_val[0]), 0, 1) * r_at[1]))
    index = np.clip(np.rint(255 * (1.0 - u)), 0, 255)  # the table's entry: hot_r reads x in [i/256, (i+1)/256)
    return (index + 0.5) / 256
