"""The ``oracle`` depth source: exact depth of a scene with a known mesh, by ray casting.
An upper bound for every stereo backend, and, with the errors of ``stereo.oracle``
(:class:`~eve3d.core.settings_stereo.Degradation`), a prior of known quality: noise,
outliers, a depth on the empty background, a bias on weak texture, holes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir
from eve3d.core.maps import save_maps
from eve3d.core.raycast import MeshRaycaster
from eve3d.core.scene import Scene
from eve3d.core.settings_stereo import Degradation, StereoSettings

WEAK_LEVEL = 2.0
"""Grey-level standard deviation over 5×5 px below which ``weak_bias`` applies (the weak
texture of ``eve3d.evaluate.depth``)."""


def priors_from_mesh(scene: Scene, out_dir: Path, mesh: Path | None = None, preview: bool = True,
                     settings: StereoSettings | None = None) -> None:
    """Write ``{view}.npz`` (depth, confidence = 1 where the ray hits, camera-space normal),
    with the errors of ``settings.oracle`` when it names any."""
    mesh = mesh or scene.gt_mesh
    if mesh is None:
        raise Eve3dError(f"{scene.root}: the oracle depth source needs a ground-truth mesh (none is known for this scene)")
    errors = settings.oracle if settings is not None else Degradation()
    caster = MeshRaycaster.from_file(mesh)
    with atomic_dir(out_dir) as tmp:
        for index, cam in enumerate(tqdm(scene.cameras, desc="oracle depth", unit="view")):
            hits = caster.cast(cam)
            normal_cam = hits.normal @ cam.R.T
            depth, confidence = hits.depth, hits.valid.astype(np.float32)
            if errors != Degradation():
                from eve3d.core.photos import read_view

                depth, confidence = degraded(depth, read_view(cam), errors, np.random.default_rng([errors.seed, index]))
            save_maps(tmp / f"{cam.view_id}.npz", preview=preview, depth=depth.astype(np.float32),
                      confidence=confidence, normal=normal_cam)


def degraded(depth: np.ndarray, photo: np.ndarray, errors: Degradation, rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray]:
    """The exact ``depth`` (H, W; 0 = no surface) of a view and its confidence, with
    ``errors`` made by ``rng`` (``photo``: the view, for the weak texture)."""
    import cv2

    from eve3d.priors.matching import local_std

    surface = depth > 0
    out = depth.astype(np.float64).copy()
    weak = local_std(cv2.resize(photo, depth.shape[::-1], interpolation=cv2.INTER_AREA), 5) < WEAK_LEVEL
    if errors.noise:
        out *= 1 + errors.noise * smooth_field(depth.shape, rng, errors.scale)
    if errors.weak_bias:
        out[weak] *= 1 + errors.weak_bias
    if errors.outliers:
        wrong = patches(surface, errors.outliers, rng, errors.scale)
        sign = np.where(rng.random(depth.shape) < 0.5, -1.0, 1.0)
        out[wrong] *= 1 + sign[wrong] * rng.uniform(0.05, 0.15, depth.shape)[wrong]
    confident = surface & ~patches(surface, errors.holes, rng, errors.scale)
    confident &= ~patches(surface & weak, errors.weak_holes, rng, errors.scale)
    if errors.empty and (~surface).any() and surface.any():
        # each empty pixel's nearest surface pixel, and the nearest first
        distance, nearest = cv2.distanceTransformWithLabels((~surface).astype(np.uint8), cv2.DIST_L2, 5,
                                                            labelType=cv2.DIST_LABEL_PIXEL)
        source = np.zeros(nearest.max() + 1, np.int64)
        source[nearest[surface]] = np.flatnonzero(surface)
        empty = np.flatnonzero(~surface)
        filled = empty[np.argsort(distance.ravel()[empty], kind="stable")[:round(errors.empty * len(empty))]]
        out.ravel()[filled] = out.ravel()[source[nearest.ravel()[filled]]]
        confident.ravel()[filled] = True
    return np.where(confident | surface, out, 0), confident.astype(np.float32)


def smooth_field(shape: tuple[int, int], rng: np.random.Generator, scale: int) -> np.ndarray:
    """Gaussian noise correlated over about ``scale`` px, of unit standard deviation."""
    import cv2

    field = cv2.GaussianBlur(rng.standard_normal(shape), (0, 0), scale / 4) if scale > 1 else rng.standard_normal(shape)
    return field / max(field.std(), 1e-12)


def patches(where: np.ndarray, share: float, rng: np.random.Generator, scale: int) -> np.ndarray:
    """About ``share`` of the ``where`` pixels, in blobs some ``scale`` px across."""
    if share <= 0 or not where.any():
        return np.zeros_like(where)
    field = smooth_field(where.shape, rng, scale)
    return where & (field > np.quantile(field[where], 1 - share))
