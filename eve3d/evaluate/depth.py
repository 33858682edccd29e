"""Depth maps against the exact depth (a folder of ``oracle`` maps of the same views).

A reconstruction can be off in two ways that a Chamfer distance mixes: noise, and a *bias*
(a surface consistently too near or too far). With τ at 0.25 % of the scene's diagonal, a
depth 1 % off in one direction puts a whole surface outside τ whatever its detail, so the
median *signed* relative error is reported beside the unsigned one.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import FUSABLE_KEYS, depth_at, fusable, load_maps, map_camera, same_aspect
from eve3d.core.settings import MeshSettings
from eve3d.core.settings_stereo import StereoSettings

WEAK_TEXTURE = 2.0
"""Grey levels (0–255): a pixel whose photo varies less than this (standard deviation over the
matcher's window, ``stereo.block_size``) is *weakly textured*, where a photometric matcher has
little to match and a learned one may still guess."""


def weak_texture(images: Path, view: str, width: int, height: int, window: int) -> np.ndarray:
    """Which pixels of ``view``'s photo in ``images``, at ``width``×``height``, are weakly
    textured (:data:`WEAK_TEXTURE`)."""
    import cv2

    from eve3d.priors.matching import local_std

    files = sorted(images.glob(f"{view}.*"))
    if not files:
        raise Eve3dError(f"{images}: no photo of view {view} to find its weakly textured pixels")
    photo = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE)
    if photo is None:
        raise Eve3dError(f"{files[0]}: not a readable image")
    return local_std(cv2.resize(photo, (width, height), interpolation=cv2.INTER_AREA), window) < WEAK_TEXTURE


def depth_accuracy(maps_dir: Path, exact_dir: Path, label: str = "",
                   min_confidence: float = MeshSettings.min_confidence, images: Path | None = None,
                   window: int = StereoSettings.block_size) -> dict:
    """Relative depth error (D − D_exact) / D_exact of the maps in ``maps_dir`` on their
    confident pixels (confidence ≥ ``min_confidence``, the pixels a mesh fuses: a prior's
    M^c, a rendered depth's alpha; every pixel of a map without confidence) where the
    exact depth is known: its median (signed, positive = too far), the median of its
    absolute value, the density (those pixels / pixels with exact depth) and the shares
    off by more than 5 % and 10 % ("confident and wrong"), and ``on_empty``: the share of
    the pixels without a surface (an empty background, the sky) that have a confident depth
    (None where every pixel has a surface). For a rendered depth, whose confidence is its
    alpha, that is the share of empty pixels it covers: floaters, which a TSDF meshes.
    With the photos (``images``), also the density and median error on the weakly textured
    pixels with a surface (:func:`weak_texture` over ``window``): ``weak_density``,
    ``weak_signed_error``, ``weak_rel_error`` and ``weak_share`` (their share of the pixels with a surface)."""
    maps_dir, exact_dir = Path(maps_dir), Path(exact_dir)
    references = sorted(exact_dir.glob("*.npz"))
    if not references:
        raise Eve3dError(f"{exact_dir}: no exact depth maps (*.npz) to score against")
    errors, confident, known, empty, filled = [], 0, 0, 0, 0
    weak_errors, weak_known = [], 0
    for ref_path in references:
        path = maps_dir / ref_path.name
        if not path.exists():
            raise Eve3dError(f"{path}: missing (the exact depth has this view)")
        ref, maps = load_maps(ref_path, FUSABLE_KEYS), load_maps(path, FUSABLE_KEYS)
        for file, m in ((ref_path, ref), (path, maps)):
            if "depth" not in m:
                raise Eve3dError(f"{file}: no 'depth' array (it has {', '.join(load_maps(file)) or 'none'})")
        h, w = ref["depth"].shape
        if not same_aspect(maps["depth"].shape, w, h):
            raise Eve3dError(f"{path}: depth is {maps['depth'].shape[::-1]}, the exact depth "
                             f"{ref['depth'].shape[::-1]}: maps of different shapes cannot be compared")
        # a map made at another size (priors at the pretrain's) is scored at the exact depth's
        maps = {k: depth_at(v, w, h) for k, v in maps.items()}
        has, fused = ref.get("confidence", ref["depth"]) > 0, fusable(maps, min_confidence)
        use = has & fused
        errors.append((maps["depth"][use] - ref["depth"][use]) / ref["depth"][use])
        confident, known = confident + int(use.sum()), known + int(has.sum())
        empty += int((~has).sum())
        filled += int((~has & fused).sum())
        if images is not None:
            weak = weak_texture(images, ref_path.stem, w, h, window)
            weak_errors.append(errors[-1][weak[use]])
            weak_known += int((has & weak).sum())
    err = np.concatenate(errors)  # float32, as the maps: a float64 copy of every pixel would double it
    del errors

    def stat(f):  # None: no pixel to score, valid JSON
        return float(f(err)) if len(err) else None

    # np.float64 thresholds: a Python float would be compared in float32
    return {"data": label or str(maps_dir), "median_signed_error": stat(median),
            "median_rel_error": stat(lambda e: median(np.abs(e))), "density": confident / max(known, 1),
            "wrong_5": stat(lambda e: np.count_nonzero(np.abs(e) > np.float64(0.05)) / len(e)),
            "wrong_10": stat(lambda e: np.count_nonzero(np.abs(e) > np.float64(0.10)) / len(e)),
            "on_empty": filled / empty if empty else None, **_weak_figures(weak_errors, weak_known, known)}


def _weak_figures(errors: list[np.ndarray], weak: int, known: int) -> dict:
    """The weakly textured pixels' share, density and median signed and absolute error (none
    without photos)."""
    if not errors:
        return {}
    err = np.concatenate(errors)
    return {"weak_share": weak / max(known, 1), "weak_density": len(err) / max(weak, 1),
            "weak_signed_error": float(median(err)) if len(err) else None,
            "weak_rel_error": float(median(np.abs(err))) if len(err) else None}


def median(values: np.ndarray) -> float:
    """``np.median`` of ``values`` taken in float64 (the mean of the two middle values in
    double precision), without a float64 copy of them: a partition of the values as they are."""
    n = len(values)
    if np.isnan(values).any():
        return float("nan")
    middle = [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]
    part = np.partition(values, middle)[middle]
    return float(part[0]) if n % 2 else (float(part[0]) + float(part[1])) / 2


def prior_agreement(scene, maps_dir: Path, neighbours: int = 2, stride: int = 4,
                    min_confidence: float = MeshSettings.min_confidence) -> dict:
    """Without ground truth: how far neighbouring views' depth maps agree. Every
    ``stride``-th confident pixel of a view is back-projected and projected into each of its
    ``neighbours`` (``eve3d.gaussians.neighbours``; :func:`eve3d.gaussians.geometry.reproject`);
    where it lands on a confident pixel of the neighbour, the relative difference
    |z − D_n| / D_n between its depth there and the neighbour's map counts. Returns the median
    of those differences, the share over 5 %, the density (confident / all pixels) and how
    many pixels were compared. A surface seen by both views agrees; a wrong depth in either
    does not (occlusions count against too)."""
    import torch

    from eve3d.gaussians.geometry import CameraStack, reproject
    from eve3d.gaussians.neighbours import select_neighbours
    from eve3d.gaussians.render.projection import CameraTensors

    maps_dir = Path(maps_dir)
    views = []
    for cam in scene.cameras:
        path = maps_dir / f"{cam.view_id}.npz"
        if not path.exists():
            raise Eve3dError(f"{path}: missing (the scene has view {cam.view_id})")
        m = load_maps(path)
        depth = np.where(fusable(m, min_confidence), m["depth"], 0)
        views.append((map_camera(cam, depth.shape, path), depth))
    tensors = [CameraTensors.from_camera(cam, torch.float64) for cam, _ in views]
    diffs, confident, pixels = [], 0, 0
    for (cam, depth), ref, near in zip(views, tensors, select_neighbours(scene, neighbours)):
        confident, pixels = confident + int((depth > 0).sum()), pixels + depth.size
        if not near:
            continue
        uv, z = reproject(torch.from_numpy(depth.astype(np.float64)), ref, CameraStack([tensors[j] for j in near]))
        picked = torch.zeros(depth.shape, dtype=torch.bool)
        picked[::stride, ::stride] = torch.from_numpy(depth[::stride, ::stride] > 0)
        for j, uv_j, z_j in zip(near, uv[:, picked.reshape(-1)].numpy(), z[:, picked.reshape(-1)].numpy()):
            other, their = views[j]
            inside = other.in_image(uv_j, z_j)
            px = np.floor(uv_j[inside]).astype(int)
            d = their[px[:, 1], px[:, 0]]
            ok = d > 0
            diffs.append(np.abs(z_j[inside][ok] - d[ok]) / d[ok])
    diff = np.concatenate(diffs) if diffs else np.zeros(0)
    return {"data": str(maps_dir), "density": confident / max(pixels, 1),
            "median_disagreement": float(np.median(diff)) if len(diff) else None,
            "disagree_5": float((diff > 0.05).mean()) if len(diff) else None, "compared": int(len(diff))}
