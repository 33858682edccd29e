"""eve3d.tools.sky_cover: the share of the sky pixels a mesh covers."""
import numpy as np
import trimesh

from eve3d.core.settings import TrainSettings
from eve3d.tools.sky_cover import sky_cover


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
