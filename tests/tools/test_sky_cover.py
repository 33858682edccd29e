"""eve3d.tools.sky_cover: the share of the sky pixels a mesh covers."""
import numpy as np
import pytest
import trimesh

from eve3d.core.settings import TrainSettings
from eve3d.tools.sky_cover import main, sky_cover


def test_the_true_surface_leaves_the_sky_open_and_a_dome_around_the_cameras_covers_it(tiny_sky_scene, tmp_path):
    margin = TrainSettings().sky_margin
    share, sheets = sky_cover(tiny_sky_scene, tiny_sky_scene.gt_mesh, margin)
    assert share < 0.02 and sheets <= 1, (share, sheets)
    # a sphere around every camera: each ray beyond the scene meets it, in every view
    dome = trimesh.creation.icosphere(subdivisions=3, radius=3 * tiny_sky_scene.radius
                                      + max(np.linalg.norm(c.center) for c in tiny_sky_scene.cameras))
    dome.export(tmp_path / "dome.ply")
    share, sheets = sky_cover(tiny_sky_scene, tmp_path / "dome.ply", margin)
    assert share > 0.99 and sheets == len(tiny_sky_scene.cameras), (share, sheets)


def test_a_missing_scene_or_mesh_is_named_without_a_traceback(tiny_sky_scene, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main([str(tmp_path / "nothing"), str(tiny_sky_scene.gt_mesh)])
    assert stop.value.code == 2 and f"{tmp_path / 'nothing'}: dataset folder not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main([str(tiny_sky_scene.root), str(tmp_path / "mesh.ply")])
    assert stop.value.code == 2 and f"{tmp_path / 'mesh.ply'}: mesh not found" in capsys.readouterr().err
