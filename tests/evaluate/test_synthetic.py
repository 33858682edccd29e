"""eve3d.evaluate.synthetic: the synthetic protocol scores a known displacement, ignores unseen GT, crops far pieces."""
import numpy as np
import pytest

from eve3d.core.scene import Scene
from eve3d.core.settings import EvalSettings
from eve3d.evaluate import PROTOCOLS, EvalInputs
from eve3d.evaluate.common import hot_r
from eve3d.synth import object_cameras


def sphere_and_ground(delta: float = 0.0):
    """A sphere floating above a ground plate, every surface moved along its normal by
    ``delta`` (the sphere scaled about its centre, the plate lifted)."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.4, resolution=80)
    sphere.scale((0.4 + delta) / 0.4, center=np.zeros(3))
    sphere.translate([0.1, -0.2, 0.7])
    plate = o3d.geometry.TriangleMesh()
    plate.vertices = o3d.utility.Vector3dVector(np.array([[-1.2, -1.2, delta], [1.2, -1.2, delta],
                                                         [1.2, 1.2, delta], [-1.2, 1.2, delta]]))
    plate.triangles = o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]]))
    return sphere + plate


def test_mesh_displaced_by_delta_scores_delta(tmp_path):
    """Accuracy and completeness of a copy of the GT moved along its normals by δ equal δ;
    precision and recall switch from 0 to 1 as τ passes δ."""
    import open3d as o3d

    delta = 0.01
    o3d.io.write_triangle_mesh(str(tmp_path / "gt.ply"), sphere_and_ground())
    o3d.io.write_triangle_mesh(str(tmp_path / "moved.ply"), sphere_and_ground(delta))
    scene = Scene(root=tmp_path, cameras=object_cameras(24, 160, 120, np.random.default_rng(0)))
    protocol = PROTOCOLS["synthetic"]

    def score(**settings):
        return protocol.run(EvalInputs(scene, tmp_path / "moved.ply", tmp_path / "m.json", gt=tmp_path / "gt.ply",
                                       settings=EvalSettings(samples=200_000, **settings)))

    m = score()
    assert m["accuracy"] == pytest.approx(delta, rel=0.05) and m["completeness"] == pytest.approx(delta, rel=0.05)
    # The bottom of the sphere faces the plate, out of every camera's sight.
    assert 0.9 < m["visible_gt_fraction"] < 0.99
    assert m["tau_rule"].startswith("0.0025 x visible-GT bounding-box diagonal")
    # the error maps: every point δ from the other surface, coloured δ/3τ of the way to black
    for name, count in (("precision", m["n_recon"]), ("recall", m["n_gt"])):
        cloud = o3d.io.read_point_cloud(str(tmp_path / f"{name}.ply"))
        assert len(cloud.points) == min(count, 200_000)
        expected = hot_r(np.array([delta / (3 * m["tau"])]))[0]
        assert np.mean(np.abs(np.asarray(cloud.colors) - expected).max(axis=1) < 0.05) > 0.95
    assert score(tau=1.5 * delta)["fscore"] > 0.99 and score(tau=0.5 * delta)["fscore"] < 0.01


def test_synthetic_protocol_ignores_unseen_gt_and_crops_far_recon(tmp_path):
    """GT surface no camera sees (a box buried in the plate, a plate far behind the
    cameras) changes neither score; a reconstruction fragment outside the visible GT's box
    is cropped and reported."""
    import open3d as o3d

    gt = sphere_and_ground()
    hidden = o3d.geometry.TriangleMesh.create_box(0.3, 0.3, 0.3).translate([0.5, 0.5, -0.4])
    far = o3d.geometry.TriangleMesh.create_box(0.5, 0.5, 0.5).translate([0, 0, 30])
    o3d.io.write_triangle_mesh(str(tmp_path / "gt.ply"), gt)
    o3d.io.write_triangle_mesh(str(tmp_path / "gt_hidden.ply"), gt + hidden)
    o3d.io.write_triangle_mesh(str(tmp_path / "recon_far.ply"), gt + far)
    scene = Scene(root=tmp_path, cameras=object_cameras(24, 160, 120, np.random.default_rng(0)))

    def run(recon, gt_name):
        inputs = EvalInputs(scene, tmp_path / recon, tmp_path / "m.json", gt=tmp_path / gt_name,
                            settings=EvalSettings(samples=100_000))
        return PROTOCOLS["synthetic"].run(inputs)

    with_hidden = run("gt.ply", "gt_hidden.ply")
    assert with_hidden["recall"] == 1.0 and with_hidden["precision"] == 1.0
    far_recon = run("recon_far.ply", "gt.ply")
    assert far_recon["precision"] == 1.0 and far_recon["crop"]["recon_area_fraction_left_out"] > 0.05
