"""Stereo on real photo pairs (``stereo.pairs``: ``real``, ``both``): a view and a real
neighbour, rectified with the known poses, matched by any backend, the depth carried back to
the view. Its errors are the matcher's on two photos, not the pretrained model's, so it is a
witness that does not share the virtual right views' error.

Rectification turns both cameras to one rotation whose x axis runs from the view's centre to
the neighbour's, with one intrinsic matrix: the neighbour is then the view's right camera, a
point at rectified depth Z lies d = f·B/Z px further left in it, as in a virtual pair.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from eve3d.core.scene import Camera, Scene

MAX_TURN_DEG = 45.0
"""A neighbour's optical axis within this of the view's, and its baseline at least this far
from the view's optical axis: a pair along the line of sight has its epipole in the image and
rectifies to a stretched wedge."""
MIN_SCALE = 0.25
"""The smallest scale a pair is matched at (``stereo.real_max_disparity``)."""


def pair_candidates(scene: Scene, ranked: list[list[int]], count: int) -> list[list[int]]:
    """Per view, the first ``count`` of its ``ranked`` neighbours (best first: they share the most
    sparse points at a useful triangulation angle) that rectify well (``MAX_TURN_DEG``)."""
    cos = np.cos(np.radians(MAX_TURN_DEG))
    out = []
    for cam, near in zip(scene.cameras, ranked):
        chosen = []
        for j in near:
            other = scene.cameras[j]
            base = other.center - cam.center
            length = np.linalg.norm(base)
            if length == 0 or cam.R[2] @ other.R[2] < cos or abs(cam.R[2] @ base) / length > cos:
                continue
            chosen.append(j)
            if len(chosen) == count:
                break
        out.append(chosen)
    return out


def _resized(cam: Camera, image: np.ndarray, scale: float) -> tuple[Camera, np.ndarray]:
    """``cam`` and its ``image`` at about ``scale`` × their size, K scaled by the whole-pixel
    size's own ratios (a ratio off by a rounding would scale every depth)."""
    import cv2

    width, height = max(round(cam.width * scale), 1), max(round(cam.height * scale), 1)
    K = np.diag([width / cam.width, height / cam.height, 1.0]) @ cam.K
    return (replace(cam, K=K, width=width, height=height),
            cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA))


def _index_K(K: np.ndarray) -> np.ndarray:
    """``K`` for OpenCV, whose pixel (0, 0) is centred at 0 (ours at 0.5)."""
    K = K.copy()
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return K


MAX_GROWTH = 1.5
"""The longest a rectified frame's side may be, in the view's sides: the matcher's cost grows
with the frame."""


def _turned(cam: Camera, R: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N, 3) the rays (camera z = 1) through ``cam``'s ``pixels`` (N, 3) homogeneous, in the
    rectified frame ``R`` (world to rectified)."""
    return pixels @ np.linalg.inv(cam.K).T @ (R @ cam.R.T).T


def _corners(cam: Camera) -> np.ndarray:
    """(4, 3) ``cam``'s image corners, homogeneous."""
    w, h = cam.width, cam.height
    return np.array([[0, 0, 1], [w, 0, 1], [0, h, 1], [w, h, 1.0]])


def _frame(cam: Camera, R: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """Intrinsics (the view's focal length) and size of the rectified frame that holds the
    whole view turned by ``R`` (world to rectified): the box of its image's corners (a turn maps
    the edges to lines), within ``MAX_GROWTH`` × its sides about its centre. A frame of the
    view's own size held a third less of a room's views where the baseline runs aslant in the
    image, often their top rows (the ceiling)."""
    w, h = cam.width, cam.height
    q = _turned(cam, R, np.vstack([[w / 2, h / 2, 1], _corners(cam)]))  # the centre first
    uv = cam.fx * q[:, :2] / np.maximum(q[:, 2:], 1e-6)  # rectified, the principal point at 0
    reach = MAX_GROWTH / 2 * np.array([w, h])
    lo, hi = np.maximum(uv.min(0), uv[0] - reach), np.minimum(uv.max(0), uv[0] + reach)
    size = np.ceil(hi - lo).astype(int)
    K = np.array([[cam.fx, 0, -lo[0]], [0, cam.fx, -lo[1]], [0, 0, 1.0]])
    return K, (int(size[0]), int(size[1]))


@dataclass
class RectifiedPair:
    """A view and a neighbour resampled to one rotation ``R`` (world to rectified) and
    intrinsics ``K`` (our pixel convention), in a frame that holds the whole view (within
    ``MAX_GROWTH``; at its scale or smaller): ``left``, and ``right`` with ``margin`` more columns on the left, so
    that a match up to ``margin`` px left of the frame stays inside it; ``search``, the
    disparities to search."""

    cam: Camera
    """The view at its own size: its pixels are the ones carried back to."""
    R: np.ndarray
    K: np.ndarray
    baseline: float
    search: tuple[float, float]
    margin: int
    left: np.ndarray
    right: np.ndarray

    @classmethod
    def build(cls, cam: Camera, left: np.ndarray, other: Camera, right: np.ndarray, depths: tuple[float, float],
              max_disparity: float) -> RectifiedPair:
        """The pair of ``cam`` (photo ``left``) and ``other`` (``right``) for a scene between
        ``depths`` (near, far) from ``cam``; matched at a smaller scale where the nearest depth's
        disparity would pass ``max_disparity`` px (the matcher's cost grows with the range)."""
        import cv2

        x = other.center - cam.center
        baseline = float(np.linalg.norm(x))
        x /= baseline
        z = cam.R[2] + other.R[2]  # the mean optical axis, made perpendicular to the baseline
        z -= (z @ x) * x
        z /= np.linalg.norm(z)
        R = np.stack([x, np.cross(z, x), z])
        # a point at the view's depth Z has rectified depth Z·q_z, q_z its ray's (camera z = 1)
        # rectified z: linear over the image, so it is extreme at a corner
        # (a corner turned further than MAX_TURN_DEG from it is left to the range check)
        q_z = np.clip(_turned(cam, R, _corners(cam))[:, 2], np.cos(np.radians(MAX_TURN_DEG)), None)
        view, (near, far) = cam, depths
        widest = cam.fx * baseline / (near * q_z.min())
        scale = min(1.0, max(max_disparity / widest, MIN_SCALE))
        if scale < 1:
            cam, left = _resized(cam, left, scale)
            other, right = _resized(other, right, scale)
        search = (cam.fx * baseline / (far * q_z.max()), cam.fx * baseline / (near * q_z.min()))
        K, (width, height) = _frame(cam, R)
        margin = int(np.ceil(search[1])) + 16  # a matcher may round its range up (SGBM: to 16 px)
        K_right = K.copy()
        K_right[0, 2] += margin

        def warp(view: Camera, image: np.ndarray, K_new: np.ndarray, columns: int) -> np.ndarray:
            maps = cv2.initUndistortRectifyMap(_index_K(view.K), None, R @ view.R.T, _index_K(K_new),
                                               (columns, height), cv2.CV_32FC1)
            return cv2.remap(image, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

        return cls(view, R, K, baseline, search, margin, warp(cam, left, K, width),
                   warp(other, right, K_right, width + margin))

    def carried_back(self, disparity: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The depth (camera z) and confidence of the view's own pixels, at its own size, from
        the rectified left's disparity: each pixel's ray turned into the rectified frame, the
        nearest rectified pixel's depth f·B/d along it."""
        import cv2

        q = self.cam.pixel_rays() @ self.R.T  # in the rectified frame; each ray's camera z is 1
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K[0, 0] * q[..., 0] / q[..., 2] + self.K[0, 2] - 0.5
            v = self.K[1, 1] * q[..., 1] / q[..., 2] + self.K[1, 2] - 0.5
        z_rect = np.where(disparity > 0, self.K[0, 0] * self.baseline / np.maximum(disparity, 1e-6), 0)
        u, v = np.nan_to_num(u, nan=-1).astype(np.float32), np.nan_to_num(v, nan=-1).astype(np.float32)
        z = cv2.remap(z_rect.astype(np.float32), u, v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        c = cv2.remap(confidence.astype(np.float32), u, v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0)
        depth = np.where((z > 0) & (q[..., 2] > 0), z / q[..., 2], 0).astype(np.float32)
        return depth, np.where(depth > 0, c, 0).astype(np.float32)


def agreed_depth(depths: np.ndarray, confidences: np.ndarray, views: int, tolerance: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """One depth from the (K, H, W) depths of a view's pairs: the mean of the confident ones
    within ``tolerance`` (relative) of their median, confident (their mean confidence) where
    at least ``views`` of them and more than half of the confident ones agree so (two pairs
    that see a pixel must agree on it; one alone has its matcher's checks)."""
    ok = (confidences > 0) & (depths > 0)
    stacked = np.where(ok, depths, np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a pixel no pair matched has no median
        median = np.nanmedian(stacked, axis=0)
        agree = ok & (np.abs(depths - median) <= tolerance * median)
        count = agree.sum(0)
        depth = np.where(agree, depths, 0).sum(0) / np.maximum(count, 1)
        confidence = np.where(agree, confidences, 0).sum(0) / np.maximum(count, 1)
    keep = (count >= views) & (2 * count > ok.sum(0))
    return np.where(keep, depth, 0).astype(np.float32), np.where(keep, confidence, 0).astype(np.float32)
