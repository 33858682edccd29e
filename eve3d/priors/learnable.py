"""The stereo priors as the joint stage uses them: D*, M^c and the prior normal of every
training view at the training resolution, and the learnable priors D̂ (DESIGN §3).

D̂ is stored as log-depth, one parameter per view with its own Adam: a step of size lr
changes a depth by the same *fraction* whatever the scene's scale (1e-4 = 0.01 %), and an
optimiser that only steps the maps a training step used leaves every other view's D̂ and
its moments exactly as they were.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps, preview_image, same_aspect
from eve3d.core.scene import Camera


@dataclass
class Priors:
    """Per view of the scene, maps (H, W) at its training size (views may differ in size:
    portrait and landscape photos)."""

    depth: list[torch.Tensor]
    """D*, camera z; 0 where the stereo stage gave no depth."""
    confidence: list[torch.Tensor]
    """M^c (bool), updated during training by the multi-view check."""
    normal: list[torch.Tensor]
    """(H, W, 3) N_prior of D* (camera space, facing the camera; 0 where undefined)."""
    digest: str
    """SHA-256 of the prior files: a checkpoint trained on other priors is not resumed."""


def confident(depth: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """A prior's confident pixels, its M^c: a positive depth whose confidence is over one half
    (a confidence without a depth is none)."""
    return (confidence > 0.5) & (depth > 0)


def resample_prior(depth: np.ndarray, confidence: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Depth and confidence at another size without mixing valid and invalid depths: a
    pixel's depth is the area mean of the *valid* depths under it, and it is valid only
    when valid depths cover at least half of it (confident likewise)."""
    import cv2

    if depth.shape == (height, width):
        return depth.astype(np.float32), confidence.astype(np.float32)
    valid = (depth > 0).astype(np.float32)

    def area(a):
        return cv2.resize(a.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)

    cover = area(valid)
    mean = area(depth * valid) / np.maximum(cover, 1e-6)
    keep = cover >= 0.5
    conf = area(confident(depth, confidence)) >= 0.5
    return np.where(keep, mean, 0).astype(np.float32), (conf & keep).astype(np.float32)


def load_priors(folder: Path, cameras: list[Camera], training: list[Camera], device: torch.device,
                normal_span: int = 1) -> Priors:
    """The priors of every camera (``{folder}/{view}.npz``, at any scale of its size) resampled
    to its training camera's size, with normals from the resampled depth (finite
    differences over ±``normal_span`` pixels). A missing or mis-sized map is an error naming
    the file; so are priors without a confident pixel in any view. A view without one (a
    blank wall or ceiling: the stereo matches nothing) is named in a warning; it trains
    without prior terms unless the multi-view check confirms some of its depths."""
    from eve3d.gaussians.geometry import depth_to_normal
    from eve3d.gaussians.render.projection import CameraTensors

    folder = Path(folder)
    if not folder.is_dir():
        raise Eve3dError(f"{folder}: no priors folder (run the stereo stage: `eve3d stereo-render`, then "
                         f"`eve3d stereo-depth`)")
    digest = hashlib.sha256()
    depths, confs, normals, blank = [], [], [], []
    for full, cam in zip(cameras, training):
        path = folder / f"{cam.view_id}.npz"
        if not path.is_file():
            raise Eve3dError(f"{path}: missing prior for view {cam.view_id}")
        digest.update(path.read_bytes())
        maps = load_maps(path)
        if "depth" not in maps or "confidence" not in maps:
            raise Eve3dError(f"{path}: a prior needs 'depth' and 'confidence' maps, it has {', '.join(maps)}")
        depth, conf = maps["depth"], maps["confidence"]
        if conf.shape != depth.shape or not same_aspect(depth.shape, full.width, full.height):
            raise Eve3dError(f"{path}: maps are {depth.shape[1]}×{depth.shape[0]}, view {cam.view_id} is "
                             f"{full.width}×{full.height} (or a scale of it)")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0)
        depth, conf = resample_prior(depth, conf, cam.width, cam.height)
        if not confident(depth, conf).any():
            blank.append(cam.view_id)
        d = torch.from_numpy(depth)
        depths.append(d)
        confs.append(torch.from_numpy(confident(depth, conf)))
        normals.append(depth_to_normal(d, CameraTensors.from_camera(cam), normal_span))
    if len(blank) == len(training):
        raise Eve3dError(f"{folder}: no confident prior depth in any view (every pixel invalid or unconfident)")
    if blank:
        from eve3d.core.photos import warn

        warn(f"{folder}: {len(blank)} of {len(training)} views have no confident prior depth (nothing the "
             f"stereo could match: a blank wall, no overlap); they train without prior terms, but where the "
             f"multi-view check confirms a depth they have: "
             f"{', '.join(blank[:10])}{', …' if len(blank) > 10 else ''}")

    def on(maps):
        return [m.to(device) for m in maps]

    return Priors(on(depths), on(confs), on(normals), digest.hexdigest()[:16])


def filled_log_depth(depth: torch.Tensor, blank: float) -> torch.Tensor:
    """log D* with every invalid pixel given its nearest valid pixel's depth, or ``blank``
    everywhere in a view without a valid pixel: the start of D̂ (L_pull moves the
    unconfident pixels toward the rendered depth)."""
    from scipy.ndimage import distance_transform_edt

    d = depth.cpu().numpy()
    if not (d > 0).any():
        return torch.full_like(depth, float(np.log(blank)))
    _, (rows, cols) = distance_transform_edt(d <= 0, return_indices=True)
    return torch.from_numpy(np.log(d[rows, cols])).to(depth.device)


def prior_points(priors: Priors, cameras: list[Camera], images: list[torch.Tensor], views: list[int], count: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points drawn uniformly among the confident prior pixels of ``views``,
    back-projected to the world, with the photos' colours (Eve3D's initialisation)."""
    points, colours = [], []
    for i in views:
        conf = (priors.confidence[i] & (priors.depth[i] > 0)).cpu().numpy()
        world = cameras[i].backproject(priors.depth[i].cpu().numpy())
        points.append(world[conf])
        colours.append(images[i].cpu().numpy()[conf])
    points, colours = np.concatenate(points), np.concatenate(colours)
    if len(points) < 4:
        raise Eve3dError("the priors have fewer than 4 confident pixels over the training views")
    pick = rng.choice(len(points), size=min(count, len(points)), replace=False)
    return points[pick], colours[pick]


def comparison_preview(*depths: np.ndarray) -> np.ndarray:
    """Depth maps side by side under one colour scale (e.g. D* | D̂ | rendered D)."""
    return preview_image("depth", np.concatenate(depths, axis=1))
