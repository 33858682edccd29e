"""Virtual stereo: right cameras, and the ``sgbm`` disparity backend with its left–right check
and optional WLS filtering (opencv-contrib's ``ximgproc``).

The right camera of a view has the same rotation and intrinsics, its centre moved by the
baseline B along the camera's own x axis, so a point at depth Z appears d = fx·B/Z pixels
further left in the right image (x_right = x_left − d) and Z = fx·B/d.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.fileio import atomic_dir, read_image, write_image
from eve3d.maps import save_maps
from eve3d.scene import Camera, Eve3dError, Scene


def right_camera(cam: Camera, baseline: float) -> Camera:
    """``cam`` moved by ``baseline`` along its x axis (same R and K): t_r = t − (B, 0, 0)."""
    return replace(cam, t=cam.t - np.array([baseline, 0.0, 0.0]), image_path=None, mask_path=None)


@dataclass
class SgbmSettings:
    """OpenCV StereoSGBM (MODE_SGBM_3WAY; P1 = 8·3·b², P2 = 32·3·b², DESIGN §6)."""

    block_size: int = 5
    max_disparity: float | None = None
    """Largest disparity searched (rounded up to a multiple of 16); None = from the depth range."""
    uniqueness: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    lr_threshold: float = 1.0
    """Left–right check: keep pixels whose two disparities differ by at most this (px)."""
    min_texture: float = 0.5
    """Pixels whose grey-level standard deviation over the block (0–255 scale) is below this
    are not confident: SGM's path aggregation fills flat regions (an empty black background)
    with disparities that pass the left–right check but mean nothing."""
    wls: bool = False
    """Edge-aware WLS filtering of the disparity (dense); the confidence becomes the filter's
    own confidence map / 255 (its left–right check, lowered near depth edges)."""
    wls_lambda: float = 8000.0
    wls_sigma: float = 1.5


def _matcher(num_disparities: int, s: SgbmSettings):
    import cv2

    b = s.block_size
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=b, P1=8 * 3 * b * b,
                                 P2=32 * 3 * b * b, disp12MaxDiff=-1, uniquenessRatio=s.uniqueness,
                                 speckleWindowSize=s.speckle_window, speckleRange=s.speckle_range,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


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


def sgbm_disparity(left: np.ndarray, right: np.ndarray, max_disparity: float,
                   s: SgbmSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Disparity of the left image (float32, px; 0 where invalid) and its confidence (float32
    in [0, 1]): the left–right check against ximgproc's right matcher, or the WLS filter's
    confidence map, in both cases gated by texture."""
    import cv2

    s = s or SgbmSettings()
    num = int(np.ceil(max(max_disparity, 16) / 16.0)) * 16
    sgbm = _matcher(num, s)
    right_matcher = cv2.ximgproc.createRightMatcher(sgbm)
    raw_l, raw_r = sgbm.compute(left, right), right_matcher.compute(right, left)  # 1/16 px; right ≤ 0
    textured = local_std(left, s.block_size) >= s.min_texture
    if s.wls:
        wls = cv2.ximgproc.createDisparityWLSFilter(sgbm)
        wls.setLambda(s.wls_lambda)
        wls.setSigmaColor(s.wls_sigma)
        disp = wls.filter(raw_l, left, disparity_map_right=raw_r).astype(np.float32) / 16.0
        confidence = wls.getConfidenceMap().astype(np.float32) / 255.0
    else:
        disp = raw_l.astype(np.float32) / 16.0
        confidence = left_right_consistent(disp, -raw_r.astype(np.float32) / 16.0, s.lr_threshold)
    return np.maximum(disp, 0).astype(np.float32), np.where(textured & (disp > 0), confidence, 0).astype(np.float32)


def local_std(image: np.ndarray, size: int) -> np.ndarray:
    """Grey-level standard deviation over a ``size``×``size`` window (0–255 scale)."""
    import cv2

    grey = (image.mean(-1) if image.ndim == 3 else image).astype(np.float32)
    mean = cv2.blur(grey, (size, size))
    return np.sqrt(np.maximum(cv2.blur(grey * grey, (size, size)) - mean * mean, 0))


PAIRS_FILE = "pairs.json"


def render_right_views(scene: Scene, model_path: Path, out_dir: Path, baseline_factor: float = 0.07,
                       backend: str = "auto") -> dict:
    """``stereo_render``: the right view of every camera rendered by the pre-trained model
    (``right/{view}.png``), and ``pairs.json``: the baseline and, per view, the largest
    disparity to search (from the rendered depth's 1st percentile, with a 25 % margin)."""
    import torch

    from eve3d.gaussians import GaussianModel
    from eve3d.render import render

    model = GaussianModel.load_ply(model_path)
    baseline = baseline_factor * scene.radius
    p = model.params
    info = {"baseline": baseline, "baseline_factor": baseline_factor, "model": str(model_path), "views": {}}
    with atomic_dir(out_dir) as tmp, torch.no_grad():
        for cam in tqdm(scene.cameras, desc="rendering right views", unit="view"):
            right = right_camera(cam, baseline)
            centre = torch.tensor(right.center, dtype=torch.float32)
            out = render(p["means"], p["quats"], model.scales, model.opacities, model.colors(centre), right,
                         backend=backend, antialiased=True)
            write_image(tmp / "right" / f"{cam.view_id}.png",
                        (out.rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
            depth = out.depth_expected[out.alpha > 0.5].numpy()
            z_near = float(np.percentile(depth, 1)) if len(depth) else 0.1 * scene.radius
            info["views"][cam.view_id] = {"max_disparity": 1.25 * cam.fx * baseline / max(z_near, 1e-6)}
        (tmp / PAIRS_FILE).write_text(json.dumps(info, indent=2))
    return info


def stereo_priors(scene: Scene, stereo_dir: Path, out_dir: Path,
                  matcher: Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]],
                  name: str, preview: bool = True) -> None:
    """``stereo_depth`` for a disparity backend: ``matcher(left, right, max_disparity)`` gives
    the left disparity and its confidence; depth Z = fx·B/d and normals from the depth are
    written for every view (``{view}.npz`` and PNG previews)."""
    import torch

    from eve3d.losses import depth_to_normal
    from eve3d.render.projection import CameraTensors

    pairs_path = stereo_dir / PAIRS_FILE
    if not pairs_path.exists():
        raise Eve3dError(f"{pairs_path}: missing; run `eve3d stereo-render` first")
    pairs = json.loads(pairs_path.read_text())
    baseline = float(pairs["baseline"])
    with atomic_dir(out_dir) as tmp:
        for cam in tqdm(scene.cameras, desc=name, unit="view"):
            if cam.view_id not in pairs["views"]:
                raise Eve3dError(f"{pairs_path}: no right view for {cam.view_id}")
            left = read_image(cam.image_path)
            right = read_image(stereo_dir / "right" / f"{cam.view_id}.png")
            if right.shape != left.shape:
                raise Eve3dError(f"{stereo_dir / 'right' / cam.view_id}.png: {right.shape[1]}×{right.shape[0]}, "
                                 f"the photo is {left.shape[1]}×{left.shape[0]}")
            disp, confidence = matcher(left, right, pairs["views"][cam.view_id]["max_disparity"])
            depth = np.where(disp > 0, cam.fx * baseline / np.maximum(disp, 1e-6), 0).astype(np.float32)
            normal = depth_to_normal(torch.from_numpy(depth), CameraTensors.from_camera(cam)).numpy()
            save_maps(tmp / f"{cam.view_id}.npz", preview=preview, depth=depth,
                      confidence=confidence.astype(np.float32), normal=normal)


def sgbm_priors(scene: Scene, stereo_dir: Path, out_dir: Path, settings: SgbmSettings | None = None,
                preview: bool = True) -> None:
    """``stereo_depth --backend sgbm``."""
    stereo_priors(scene, stereo_dir, out_dir, lambda l, r, m: sgbm_disparity(l, r, m, settings), "SGBM", preview)
