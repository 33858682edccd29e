"""Recognise a dataset's layout and read it into a ``Scene``."""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.io.colmap import find_colmap_model, read_colmap
from eve3d.core.io.dtu import read_dtu
from eve3d.core.io.tnt import read_tnt, tnt_name
from eve3d.core.scene import Scene

METADATA = "eve3d_scene.json"
"""Optional file beside a dataset (written by ``eve3d synth``): kind, GT mesh, object radius."""


def has_poses(root: Path) -> bool:
    """Whether the dataset brings its own poses (so SfM is skipped)."""
    return (root / "cameras.npz").exists() or find_colmap_model(root) is not None


def _model(root: Path) -> Path:
    model = find_colmap_model(root)
    if model is None:
        raise Eve3dError(f"{root}: no poses (no cameras.npz, no COLMAP model in sparse/0): run `eve3d sfm` first")
    return model


def _read_colmap(root: Path, check_images: bool) -> Scene:
    scene = read_colmap(_model(root), root / "images", root=root, check_images=check_images)
    scene.extras["format"] = "colmap"
    return scene


@dataclass(frozen=True)
class DatasetFormat:
    name: str
    detect: Callable[[Path], bool]
    """Whether a dataset folder is laid out in this format."""
    read: Callable[[Path, bool], Scene]
    """(folder, check_images) → the scene, its ``extras["format"]`` this format's name."""


FORMATS: tuple[DatasetFormat, ...] = (
    DatasetFormat("dtu", lambda root: (root / "cameras.npz").exists(), read_dtu),
    DatasetFormat("tnt", lambda root: bool(tnt_name(root)), lambda root, check: read_tnt(root, _model(root), check)),
    DatasetFormat("colmap", lambda root: True, _read_colmap),
)
"""The dataset layouts, tried in this order: ``dtu`` (``cameras.npz``), ``tnt`` (a
``{Scene}_trans.txt`` beside the images), else ``colmap`` (a COLMAP model, or images that SfM
will pose)."""


def _format(root: Path) -> DatasetFormat:
    return next(f for f in FORMATS if f.detect(root))


def dataset_format(root: Path) -> str:
    """The name of the :data:`FORMATS` row that ``root`` is laid out in."""
    return _format(Path(root)).name


def load_scene(root: str | Path, check_images: bool = True) -> Scene:
    """Read the posed dataset in ``root`` (any of :data:`FORMATS`)."""
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
