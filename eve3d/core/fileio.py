"""Atomic artefact writes and image reading with clear errors.

Every stage writes through these helpers so that a killed or failed run never leaves a
file or folder that looks complete.
"""
from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


class DiskFull(Eve3dError):
    """No space left (or over quota) while an artefact was written; the message names the
    artefact, not the temporary file, and says the earlier one is kept."""

    def __init__(self, path: Path, reason: str):
        kept = "the earlier one is kept as it was" if path.exists() else "nothing was written"
        super().__init__(f"{path}: cannot write it, the disk is full ({reason}); {kept}")
        self.reason = reason


_FULL = (errno.ENOSPC, errno.EDQUOT)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as e:
        if e.errno not in _FULL:
            raise
        raise DiskFull(path, e.strerror or "no space left on the device") from None
    finally:
        tmp.unlink(missing_ok=True)


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; it replaces ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except DiskFull as e:  # a file inside: name the folder, the artefact the user knows
        raise DiskFull(path, e.reason) from None
    except OSError as e:
        if e.errno not in _FULL:
            raise
        raise DiskFull(path, e.strerror or "no space left on the device") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def list_images(folder: Path) -> list[Path]:
    """Image files in ``folder``, sorted by name; an error if the folder is missing or empty."""
    if not folder.is_dir():
        raise Eve3dError(f"{folder}: image folder not found")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise Eve3dError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return images


def check_image(path: Path, size: tuple[int, int] | None = None) -> tuple[int, int]:
    """Verify that ``path`` is a readable, complete image (optionally of ``size`` = (w, h))
    without decoding it fully; return its (width, height)."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise Eve3dError(f"{path}: image not found")
    try:
        with Image.open(path) as im:
            im.verify()
            wh = im.size
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise Eve3dError(f"{path}: corrupt or unreadable image ({e})") from None
    if size is not None and tuple(wh) != tuple(size):
        raise Eve3dError(f"{path}: image is {wh[0]}×{wh[1]} but its camera says {size[0]}×{size[1]}")
    return wh


def read_image(path: Path) -> np.ndarray:
    """RGB uint8 image (H,W,3), its pixels as stored: an EXIF orientation tag is ignored, as
    COLMAP ignores it (``eve3d.core.photos``: SfM imports tagged photos upright)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise Eve3dError(f"{path}: corrupt or unreadable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_mask(path: Path) -> np.ndarray:
    """Boolean mask (H,W): any non-zero channel counts as foreground."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise Eve3dError(f"{path}: corrupt or unreadable mask")
    return (img.reshape(img.shape[0], img.shape[1], -1)[..., :3] > 127).any(axis=-1)


def write_image(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image atomically (format from the suffix)."""
    import cv2

    with atomic_path(path) as tmp:
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
        if not cv2.imwrite(str(tmp), bgr):
            raise Eve3dError(f"{path}: could not write image")


def read_mesh(path: Path):
    """An open3d legacy triangle mesh, or a clear error."""
    import open3d as o3d

    if not Path(path).is_file():
        raise Eve3dError(f"{path}: mesh not found")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0 and len(mesh.vertices):  # distances to a surface need its triangles
        raise Eve3dError(f"{path}: a point cloud ({len(mesh.vertices)} points, no triangles), not a triangle mesh")
    if len(mesh.triangles) == 0:
        raise Eve3dError(f"{path}: not a triangle mesh that open3d reads (.ply, .obj, .off, .stl, .glb), or an "
                         f"empty one")
    return mesh
