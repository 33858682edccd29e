"""What every stereo backend shares: the left–right check, the right image's own disparity
from a left-image matcher, the grey level and the local texture measure of the confidence
checks, and the onnxruntime session of the network backends."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np


def mirrored(matcher: Callable[[np.ndarray, np.ndarray], np.ndarray], left: np.ndarray,
             right: np.ndarray) -> np.ndarray:
    """The right image's own disparity from a left-image matcher (a stereo network has no
    right matcher): mirroring both images turns the right view into a left view."""

    def flip(im):
        return np.ascontiguousarray(im[:, ::-1])

    return np.ascontiguousarray(matcher(flip(right), flip(left))[:, ::-1])


def onnx_session(path: Path):
    """An onnxruntime session of the model at ``path``: its CUDA provider where onnxruntime has
    one, and on the CPU as many threads as ``OMP_NUM_THREADS`` says (the threads the workflow
    gives the job; onnxruntime's default, every core, otherwise). Raises what
    onnxruntime raises for a file it cannot load."""
    import onnxruntime as ort

    from eve3d.core.settings import job_threads

    options = ort.SessionOptions()
    threads = job_threads()
    if threads:
        options.intra_op_num_threads = threads
    providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in ort.get_available_providers()]
    return ort.InferenceSession(str(path), sess_options=options, providers=providers)


def left_right_consistent(disp_l: np.ndarray, disp_r: np.ndarray, threshold: float) -> np.ndarray:
    """Left pixels whose disparity the right image's disparity confirms within ``threshold`` px."""
    w = disp_l.shape[1]
    x = np.arange(w)[None, :] - disp_l  # where each left pixel lands in the right image
    back = np.take_along_axis(disp_r, np.clip(np.round(x).astype(int), 0, w - 1), axis=1)
    return (disp_l > 0) & (x >= 0) & (back > 0) & (np.abs(back - disp_l) <= threshold)


def grey(image: np.ndarray) -> np.ndarray:
    """The grey level (float32) of an RGB image, the mean of its channels; a grey image as it is."""
    return (image.mean(-1) if image.ndim == 3 else image).astype(np.float32)


def local_std(image: np.ndarray, size: int) -> np.ndarray:
    """Grey-level standard deviation over a ``size``×``size`` window (0–255 scale)."""
    import cv2

    level = grey(image)
    mean = cv2.blur(level, (size, size))
    return np.sqrt(np.maximum(cv2.blur(level * level, (size, size)) - mean * mean, 0))
