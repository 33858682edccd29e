"""Tanks and Temples: COLMAP ``images/`` + ``sparse/`` and the official ground-truth files
``{Scene}.ply``, ``{Scene}.json`` (crop), ``{Scene}_trans.txt`` (alignment) and
``{Scene}_COLMAP_SfM.log`` (the trajectory the alignment refers to)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.io.colmap import colmap_model, read_colmap
from eve3d.core.io.loader import DatasetFormat
from eve3d.core.scene import Scene


def read_log_trajectory(path: Path) -> list[np.ndarray]:
    """The T&T/Redwood ``.log`` format: per camera a metadata line and a 4×4 matrix."""
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise Eve3dError(f"{path}: not a text file; a trajectory (.log) holds per camera a metadata line and the 4 "
                         f"rows of a 4×4 matrix") from None
    rows = [(number, line.split()) for number, line in enumerate(lines, 1) if line.strip()]
    if len(rows) % 5:
        raise Eve3dError(f"{path}: expected blocks of 5 lines (metadata + 4×4 matrix), got {len(rows)} lines")
    poses = []
    for first in range(0, len(rows), 5):
        matrix = rows[first + 1:first + 5]
        for number, row in matrix:  # a ragged block would make a matrix of another shape
            if len(row) != 4:
                raise Eve3dError(f"{path}: line {number}: expected a row of 4 numbers (camera {first // 5}'s 4×4 "
                                 f"matrix), got {len(row)} values")
        try:
            poses.append(np.array([row for _, row in matrix], dtype=np.float64))
        except ValueError as e:
            raise Eve3dError(f"{path}: malformed trajectory ({e})") from None
    return poses


def tnt_name(root: Path) -> str | None:
    trans = sorted(root.glob("*_trans.txt"))
    return trans[0].name[: -len("_trans.txt")] if trans else None


GROUND_TRUTH_FILES = {"gt_points": ".ply", "crop": ".json", "trans": "_trans.txt", "trajectory": "_COLMAP_SfM.log"}
"""The official evaluation files of a T&T scene, beside its images: ``{Scene}{suffix}``
(``Scene.extras`` keys)."""


def ground_truth_files(root: Path, name: str) -> dict[str, Path]:
    """The official evaluation files of the T&T scene ``name`` in ``root``, by key."""
    return {key: root / f"{name}{suffix}" for key, suffix in GROUND_TRUTH_FILES.items()}


def read_tnt(root: Path, check_images: bool = True) -> Scene:
    name = tnt_name(root)
    files = ground_truth_files(root, name)
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise Eve3dError(f"{root}: Tanks and Temples ground-truth files missing: {', '.join(missing)}")
    scene = read_colmap(colmap_model(root), root / "images", root=root, check_images=check_images)
    try:
        trans = np.loadtxt(files["trans"]).reshape(4, 4)
    except ValueError as e:
        raise Eve3dError(f"{files['trans']}: expected a 4×4 matrix ({e})") from None
    scene.kind = "scene"
    scene.extras.update(files, format="tnt", name=name, alignment=trans,
                        gt_trajectory=read_log_trajectory(files["trajectory"]))
    return scene


FORMAT = DatasetFormat("tnt", lambda root: bool(tnt_name(root)), read_tnt)
