"""What every stereo backend shares: the left–right check, the right image's own disparity
from a left-image matcher, and the local texture measure of the confidence checks."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np


def mirrored(matcher: Callable[[np.ndarray, np.ndarray], np.ndarray], left: np.ndarray,
             right: np.ndarray) -> np.ndarray:
    """The right image's own disparity from a left-image matcher (a stereo network has no
    right matcher): mirroring both images turns the right view into a left view."""
    flip = lambda im: np.ascontiguousarray(im[:, ::-1])  # noqa: E731
    return np.ascontiguousarray(matcher(flip(right), flip(left))[:, ::-1])


def left_right_consistent(disp_l: np.ndarray, disp_r: np.ndarray, threshold: float) -> np.ndarray:
    """Left pixels whose disparity the right image's disparity confirms within ``threshold`` px."""
    w = disp_l.shape[1]
    x = np.arange(w)[None, :] - disp_l  # where each left pixel lands in the right image
    back = np.take_along_axis(disp_r, np.clip(np.round(x).astype(int), 0, w - 1), axis=1)
    return (disp_l > 0) & (x >= 0) & (back > 0) & (np.abs(back - disp_l) <= threshold)


def local_std(image: np.ndarray, size: int) -> np.ndarray:
    """Grey-level standard deviation over a ``size``×``size`` window (0–255 scale)."""
    import cv2

    grey = (image.mean(-1) if image.ndim == 3 else image).astype(np.float32)
    mean = cv2.blur(grey, (size, size))
    return np.sqrt(np.maximum(cv2.blur(grey * grey, (size, size)) - mean * mean, 0))
