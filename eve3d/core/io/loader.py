"""Recognise a dataset's layout and read it into a ``Scene``."""
from __future__ import annotations

import json
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


def dataset_format(root: Path) -> str:
    """``dtu`` (``cameras.npz``), ``tnt`` (a ``{Scene}_trans.txt`` beside the images) or
    ``colmap`` (a COLMAP model, or images that SfM will pose)."""
    root = Path(root)
    if (root / "cameras.npz").exists():
        return "dtu"
    return "tnt" if tnt_name(root) else "colmap"


def load_scene(root: str | Path, check_images: bool = True) -> Scene:
    """Read the posed dataset in ``root`` (DTU, Tanks and Temples, or COLMAP)."""
    root = Path(root)
    if not root.is_dir():
        raise Eve3dError(f"{root}: dataset folder not found")
    fmt = dataset_format(root)
    model = find_colmap_model(root)
    if fmt == "dtu":
        scene = read_dtu(root, check_images)
    elif model is None:
        raise Eve3dError(f"{root}: no poses (no cameras.npz, no COLMAP model in sparse/0): run `eve3d sfm` first")
    elif fmt == "tnt":
        scene = read_tnt(root, model, check_images)
    else:
        scene = read_colmap(model, root / "images", root=root, check_images=check_images)
        scene.extras["format"] = "colmap"
    meta_path = root / METADATA
    if meta_path.exists():
        meta = json.loads(meta_path.read_text())
        scene.kind = meta.get("kind", scene.kind)
        if "gt_mesh" in meta:
            scene.gt_mesh = root / meta["gt_mesh"]
        if "object_radius" in meta:
            scene.extras["object_radius"] = meta["object_radius"]
    return scene
