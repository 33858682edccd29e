"""Recognise a dataset's layout and read it into a ``Scene``."""
from __future__ import annotations

import functools
import importlib
import json
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.io.colmap import colmap_model, find_colmap_model, read_colmap
from eve3d.core.scene import Scene

METADATA = "eve3d_scene.json"
"""Optional file beside a dataset (written by ``eve3d synth``): kind, GT mesh, object radius."""


def has_poses(root: Path) -> bool:
    """Whether the dataset brings its own poses (so SfM is skipped)."""
    return (root / "cameras.npz").exists() or find_colmap_model(root) is not None


@dataclass(frozen=True)
class DatasetFormat:
    """A dataset layout: a reader module declares its own as ``FORMAT``."""

    name: str
    detect: Callable[[Path], bool]
    """Whether a dataset folder is laid out in this format."""
    read: Callable[[Path, bool], Scene]
    """(folder, check_images) → the scene, its ``extras["format"]`` this format's name."""


def _read_colmap(root: Path, check_images: bool) -> Scene:
    scene = read_colmap(colmap_model(root), root / "images", root=root, check_images=check_images)
    scene.extras["format"] = "colmap"
    return scene


COLMAP = DatasetFormat("colmap", lambda root: True, _read_colmap)
"""The layout of any other folder: a COLMAP model, or images that SfM will pose."""


@functools.cache
def formats() -> tuple[DatasetFormat, ...]:
    """The dataset layouts, tried in this order: the ``FORMAT`` that each module of this
    package declares (its ``detect`` says how the layout is told), by module name, then
    :data:`COLMAP`. Read when first needed: the readers import this module for
    :class:`DatasetFormat`."""
    names = (info.name for info in pkgutil.iter_modules([str(Path(__file__).parent)]))
    modules = (importlib.import_module(f"{__package__}.{name}") for name in names)
    return (*(module.FORMAT for module in modules if hasattr(module, "FORMAT")), COLMAP)


def _format(root: Path) -> DatasetFormat:
    return next(f for f in formats() if f.detect(root))


def dataset_format(root: Path) -> str:
    """The name of the format (:func:`formats`) that ``root`` is laid out in."""
    return _format(Path(root)).name


def load_scene(root: str | Path, check_images: bool = True) -> Scene:
    """Read the posed dataset in ``root`` (any of :func:`formats`)."""
    root = Path(root)
    if not root.is_dir():
        raise Eve3dError(f"{root}: dataset folder not found")
    scene = _format(root).read(root, check_images)
    meta_path = root / METADATA
    if meta_path.exists():
        meta = json.loads(meta_path.read_text())
        scene.kind = meta.get("kind", scene.kind)
        if "gt_mesh" in meta:
            scene.gt_mesh = root / meta["gt_mesh"]
        if "object_radius" in meta:
            scene.extras["object_radius"] = meta["object_radius"]
    return scene
