"""Per-view maps (depth, confidence, normals) as float32 ``.npz`` with PNG previews.

The ``.npz`` files are not compressed: zlib made writing a photo-sized view's maps several
times slower for a small saving in size (docs/development.md, "A capture from photos alone")."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path, write_image
from eve3d.core.scene import Camera


def save_maps(path: Path, preview: bool = True, **maps: np.ndarray) -> None:
    """Write ``path`` (.npz, float32 arrays) atomically, and ``{stem}.{key}.png`` previews."""
    arrays = {k: np.asarray(v, dtype=np.float32) for k, v in maps.items()}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    if preview:
        for key, arr in arrays.items():
            write_image(path.with_name(f"{path.stem}.{key}.png"), preview_image(key, arr, arrays.get("confidence")))


def load_maps(path: Path, keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of a map file, or only those of ``keys`` it has (the others are not
    read: a view's normals are 3× its depth)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files if keys is None or k in keys}
    except Exception as e:
        raise Eve3dError(f"{path}: cannot read map file ({e})") from None


FUSABLE_KEYS = ("depth", "confidence", "sky")
"""What :func:`fusable` reads of a map file (not its normals)."""


def fusable(maps: dict[str, np.ndarray], min_confidence: float) -> np.ndarray:
    """(H, W) bool: the pixels of a view's maps that a mesh fuses, and that the depth scores
    count: a positive depth whose confidence, where the maps have one, is at least
    ``min_confidence`` (``mesh.min_confidence``), and that the maps' ``sky`` does not mark."""
    depth = maps["depth"]
    confident = maps["confidence"] >= min_confidence if "confidence" in maps else np.ones(depth.shape, bool)
    if "sky" in maps:  # what the environment at infinity explains (eve3d.joint.export_depths)
        confident &= maps["sky"] < 0.5
    return confident & (depth > 0)


def same_aspect(shape: tuple[int, ...], width: int, height: int) -> bool:
    """Whether a map of ``shape`` (H, W, ...) is a ``width``×``height`` image at some scale
    (to a pixel of rounding), so it can be resampled to that size."""
    h, w = shape[:2]
    return abs(h * width / w - height) <= 1 + width / w


def map_camera(cam: Camera, shape: tuple[int, ...], path: Path) -> Camera:
    """``cam`` at the size of a map of ``shape`` (H, W, ...) read from ``path``; an error naming
    the file when the map is not the view at any scale."""
    h, w = shape[:2]
    if not same_aspect(shape, cam.width, cam.height):
        raise Eve3dError(f"{path}: depth is {w}×{h}, view is {cam.width}×{cam.height} (or a scale of it)")
    return cam if w == cam.width else cam.scaled(w / cam.width)


def depth_at(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """A depth map at another size, nearest sample (no depths of two surfaces mixed)."""
    import cv2

    if depth.shape[:2] == (height, width):
        return depth
    return cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST)


def preview_image(key: str, arr: np.ndarray, confidence: np.ndarray | None = None) -> np.ndarray:
    """RGB uint8 preview: depth coloured (turbo, near = red; black where it has no depth or,
    given ``confidence``, none of it: a matcher's rejected guesses neither show nor stretch the
    colour range), confidence grey, normals RGB."""
    import cv2

    if key == "normal":  # in the maps' float32: a full-size photo's normals are millions of values
        valid = (arr != 0).any(axis=-1) & np.isfinite(arr).all(axis=-1)
        arr = np.where(valid[..., None], arr, 0)
        rgb = ((arr * np.float32([0.5, -0.5, -0.5]) + np.float32(0.5)) * np.float32(255)).clip(0, 255).astype(np.uint8)
        rgb[~valid] = 0
        return rgb
    if key == "depth":
        valid = arr > 0
        if confidence is not None:
            valid &= confidence > 0
        if not valid.any():
            return np.zeros(arr.shape + (3,), np.uint8)
        lo, hi = np.percentile(arr[valid], [1, 99])
        x = (1 - np.clip((arr - lo) / max(hi - lo, 1e-12), 0, 1)) * 255
        rgb = cv2.applyColorMap(x.astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
        return np.where(valid[..., None], rgb, 0).astype(np.uint8)
    return (np.clip(arr, 0, 1) * 255).astype(np.uint8)
