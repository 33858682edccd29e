"""eve3d.core.io.tnt: a Tanks and Temples folder read with its ground-truth files."""
import shutil

import numpy as np

from eve3d.core.io import load_scene
from eve3d.core.io.colmap import write_colmap


def test_tnt_reader_finds_ground_truth_files(object_scene, tmp_path):
    root = tmp_path / "Barn"
    shutil.copytree(object_scene.root / "images", root / "images")
    write_colmap(object_scene, root / "sparse" / "0")
    (root / "Barn.ply").write_text("ply\n")
    (root / "Barn.json").write_text("{}")
    np.savetxt(root / "Barn_trans.txt", np.eye(4))
    log = "".join(f"{i} {i} 0\n" + "\n".join(" ".join(map(str, row)) for row in np.eye(4)) + "\n"
                  for i in range(len(object_scene.cameras)))
    (root / "Barn_COLMAP_SfM.log").write_text(log)
    scene = load_scene(root)
    assert scene.extras["format"] == "tnt" and scene.extras["name"] == "Barn"
    assert len(scene.extras["gt_trajectory"]) == len(scene.cameras)
    assert np.array_equal(scene.extras["alignment"], np.eye(4))
