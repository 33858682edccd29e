"""Photos as users bring them, and as every stage reads them.

One orientation rule (DESIGN §6): every stage reads a file's pixels *as stored*, the way
COLMAP does, so a pose and its pixels always agree. Phone photos often store their pixels
sideways with an EXIF orientation tag; the SfM stage imports such photos upright (the
rotation applied, the tag gone) before COLMAP sees them, so a posed dataset made by SfM
never depends on the tag.

The import also bounds the longest side (``sfm.max_image_size``) and writes an image
pyramid beside the posed images (``images_2``, ``images_4``, ``images_8``: the Mip-NeRF 360
layout), from which :func:`read_view` reads a view at any smaller size without decoding
the full photo.
"""
from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import IMAGE_SUFFIXES, read_image, write_image
from eve3d.core.maps import same_aspect
from eve3d.core.scene import Camera, Scene

PYRAMID_LEVELS = (2, 4, 8)
"""Downscale factors of the cached image pyramid (folders ``images_{k}``)."""
PYRAMID_MIN_SIDE = 64
"""No pyramid level whose shorter side would fall below this many pixels."""


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


def scan_photos(folder: Path) -> list[Path]:
    """The usable photos of ``folder``, sorted by name. Files that are not images, and
    images that cannot be read (empty, truncated), are skipped with a warning that names
    them; an error when none is left or two photos share a name stem (their view id)."""
    from PIL import Image, UnidentifiedImageError

    if not folder.is_dir():
        raise Eve3dError(f"{folder}: image folder not found")
    photos, stems = [], {}
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or path.is_dir():
            continue
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            warn(f"{path}: not an image ({', '.join(IMAGE_SUFFIXES)}), skipped")
            continue
        try:
            with Image.open(path) as im:
                im.verify()
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
            warn(f"{path}: unreadable image ({'empty file' if path.stat().st_size == 0 else e}), skipped")
            continue
        if path.stem in stems:
            raise Eve3dError(f"{path}: same name as {stems[path.stem].name}; a view is named by its file's stem, "
                             f"rename one of them")
        stems[path.stem] = path
        photos.append(path)
    if not photos:
        raise Eve3dError(f"{folder}: no readable images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return photos


def read_upright(path: Path) -> np.ndarray:
    """RGB uint8 (H, W, 3) of a photo as a viewer shows it: its EXIF orientation applied."""
    from PIL import Image, ImageOps

    try:
        with Image.open(path) as im:
            return np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
    except (OSError, SyntaxError, ValueError) as e:
        raise Eve3dError(f"{path}: corrupt or unreadable image ({e})") from None


def fit_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """(w, h) scaled down so that the longer side is at most ``max_side`` (never up)."""
    factor = min(1.0, max_side / max(width, height))
    return max(1, round(width * factor)), max(1, round(height * factor))


def import_photos(photos: list[Path], out_dir: Path, max_side: int) -> list[str]:
    """Write each photo upright and with its longest side at most ``max_side`` to
    ``out_dir/{w}x{h}/{stem}.png``, a folder per size (COLMAP's ``PER_FOLDER`` camera mode
    then gives each size a camera of its own); returns the names written, relative to
    ``out_dir``. A warning says when the photos have several sizes."""
    import cv2
    from tqdm import tqdm

    names, sizes = [], {}
    for path in tqdm(photos, desc="importing photos", unit="img"):
        rgb = read_upright(path)
        h, w = rgb.shape[:2]
        sizes.setdefault((w, h), []).append(path.name)
        size = fit_size(w, h, max_side)
        if size != (w, h):
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        names.append(f"{size[0]}x{size[1]}/{path.stem}.png")
        write_image(out_dir / names[-1], rgb)
    if len(sizes) > 1:
        listed = "; ".join(f"{w}×{h}: {len(n)} ({', '.join(n[:3])}{', …' if len(n) > 3 else ''})"
                           for (w, h), n in sizes.items())
        warn(f"{photos[0].parent}: photos of {len(sizes)} sizes ({listed}, upright); each size gets a camera of its own")
    return names


def pyramid_dir(image_dir: Path, factor: int) -> Path:
    return image_dir.with_name(f"{image_dir.name}_{factor}")


def write_pyramid(image_dir: Path) -> None:
    """The pyramid levels of every image in ``image_dir`` (area filter from the full size)."""
    import cv2

    for path in sorted(image_dir.iterdir()):
        rgb = read_image(path)
        h, w = rgb.shape[:2]
        for k in PYRAMID_LEVELS:
            if min(w, h) / k < PYRAMID_MIN_SIDE:
                break
            small = cv2.resize(rgb, (round(w / k), round(h / k)), interpolation=cv2.INTER_AREA)
            write_image(pyramid_dir(image_dir, k) / f"{path.stem}.png", small)


def read_view(cam: Camera) -> np.ndarray:
    """The photo of ``cam`` at ``cam``'s size (RGB uint8): a camera scaled down from its
    dataset's (``Camera.scaled``) is read from the smallest cached pyramid level that is at
    least its size, when there is one, and resized with an area filter."""
    import cv2
    from PIL import Image

    if cam.image_path is None:
        raise Eve3dError(f"view {cam.view_id} has no image")
    source = cam.image_path
    for k in reversed(PYRAMID_LEVELS):
        # ours ({stem}.png), or a released pyramid's copy of the same file (Mip-NeRF 360's images_4/DSC….JPG)
        level = next((p for p in (pyramid_dir(source.parent, k) / name for name in (f"{source.stem}.png", source.name))
                      if p.is_file()), None)
        if level is not None:
            with Image.open(level) as im:  # the header only
                w, h = im.size
            if w >= cam.width - 1 and h >= cam.height - 1:  # a released level may round its size down
                source = level
                break
    rgb = read_image(source)
    h, w = rgb.shape[:2]
    if not same_aspect(rgb.shape, cam.width, cam.height):  # e.g. rotated
        raise Eve3dError(f"{source}: image is {w}×{h}, its camera says {cam.width}×{cam.height} (or a scale of it)")
    if (h, w) != (cam.height, cam.width):
        rgb = cv2.resize(rgb, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    return rgb


def equalizing_curve(images: Iterable[np.ndarray], clip: float) -> np.ndarray:
    """(256,) uint8 tone curve: contrast-limited histogram equalisation of the grey levels of
    ``images`` (uint8) together. The histogram is clipped at ``clip`` × its mean bin count and
    the excess spread over every level, so the curve's slope stays near ``clip`` or below;
    level 0 stays 0 (a black background stays black)."""
    hist = sum(np.bincount(im.ravel(), minlength=256) for im in images).astype(np.float64)
    cap = clip * hist.mean()
    for _ in range(8):  # spreading the excess can lift bins over the cap again; a few rounds settle it
        excess = np.maximum(hist - cap, 0).sum()
        hist = np.minimum(hist, cap) + excess / 256
    cdf = np.cumsum(hist)
    cdf = (cdf - cdf[0]) / max(cdf[-1] - cdf[0], 1e-12)
    return np.round(255 * cdf).astype(np.uint8)


def scene_tone_curve(scene: Scene, clip: float) -> np.ndarray:
    """The pretrain's tone curve: ``equalizing_curve`` over every photo of ``scene``, one curve
    for the whole scene so that a surface keeps its grey levels from view to view; the
    identity when ``clip`` is 0."""
    from tqdm import tqdm

    if clip <= 0:
        return np.arange(256, dtype=np.uint8)
    return equalizing_curve((read_image(c.image_path) for c in tqdm(scene.cameras, desc="tone curve", unit="img",
                                                                    leave=False)), clip)
