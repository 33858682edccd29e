"""eve3d.core.io.loader: a dataset's layout recognised, and a folder without poses named."""
import json

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import write_image
from eve3d.core.io import load_scene
from eve3d.core.io.colmap import write_colmap
from eve3d.core.io.loader import METADATA, dataset_format, has_poses
from eve3d.core.scene import Camera, Scene


def test_the_layout_is_told_by_its_files_and_the_metadata_is_read(tmp_path):
    (tmp_path / "images").mkdir()
    assert dataset_format(tmp_path) == "colmap" and not has_poses(tmp_path)  # photos SfM will pose
    with pytest.raises(Eve3dError, match="no poses .* run `eve3d sfm` first"):
        load_scene(tmp_path)
    with pytest.raises(Eve3dError, match="missing: dataset folder not found"):
        load_scene(tmp_path / "missing")
    cam = Camera("a.png", 8, 6, np.array([[8.0, 0, 4], [0, 8, 3], [0, 0, 1]]), np.eye(3), np.zeros(3))
    write_image(tmp_path / "images/a.png", np.zeros((6, 8, 3), np.uint8))
    write_colmap(Scene(tmp_path, [cam]), tmp_path / "sparse" / "0")
    (tmp_path / METADATA).write_text(json.dumps({"kind": "object", "gt_mesh": "gt/mesh.ply", "object_radius": 1.5}))
    scene = load_scene(tmp_path)
    assert has_poses(tmp_path) and scene.extras["format"] == "colmap" and [c.name for c in scene.cameras] == ["a.png"]
    assert scene.kind == "object" and scene.gt_mesh == tmp_path / "gt/mesh.ply" and scene.extras["object_radius"] == 1.5
    (tmp_path / "Barn_trans.txt").write_text("")
    assert dataset_format(tmp_path) == "tnt"
    (tmp_path / "cameras.npz").write_bytes(b"")
    assert dataset_format(tmp_path) == "dtu"  # cameras.npz first, whatever else lies beside it


def test_the_formats_are_what_the_readers_declare_and_colmap_comes_last():
    """A reader adds its layout by declaring ``FORMAT`` in its module: nothing else lists it."""
    import importlib
    import pkgutil

    import eve3d.core.io as package
    from eve3d.core.io.loader import COLMAP, formats

    modules = [importlib.import_module(f"eve3d.core.io.{m.name}") for m in pkgutil.iter_modules(package.__path__)]
    declared = [m.FORMAT for m in modules if hasattr(m, "FORMAT")]
    assert [f.name for f in formats()] == ["dtu", "tnt", "colmap"] and formats() == (*declared, COLMAP)
    assert len({f.name for f in formats()}) == len(formats())
