"""Depth without bias (issue 19): the signed error as a figure, and the stages that gave one."""
import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import save_maps
from eve3d.core.settings import SgbmSettings
from eve3d.evaluate.depth import depth_accuracy
from eve3d.priors.sgbm import sgbm_disparity
from tests.helpers import plane_pair


def test_depth_accuracy_signs_the_error(tmp_path):
    """Too near is negative (and its absolute value positive); the median ignores a minority
    of gross errors; unconfident pixels and pixels without exact depth are left out."""
    exact = np.full((20, 30), 2.0, np.float32)
    exact[:, :3] = 0  # no exact depth there (a miss)
    depth = exact * 0.99
    depth[:4] = 5.0  # 20 % of the rows grossly wrong, too far
    confidence = np.ones_like(exact)
    confidence[:, -3:] = 0
    save_maps(tmp_path / "exact" / "a.npz", preview=False, depth=exact, confidence=(exact > 0).astype(np.float32))
    save_maps(tmp_path / "maps" / "a.npz", preview=False, depth=depth, confidence=confidence)
    acc = depth_accuracy(tmp_path / "maps", tmp_path / "exact")
    assert acc["median_signed_error"] == pytest.approx(-0.01, rel=1e-4)
    assert acc["median_rel_error"] == pytest.approx(0.01, rel=1e-4)
    assert acc["density"] == pytest.approx(24 / 27)
    assert acc["wrong_10"] == pytest.approx(4 / 20)
    save_maps(tmp_path / "squeezed" / "a.npz", preview=False, depth=exact[::2], confidence=confidence[::2])
    with pytest.raises(Eve3dError, match="maps of different shapes"):
        depth_accuracy(tmp_path / "squeezed", tmp_path / "exact")
    # a map at half the size (priors matched at the pretrain's size) is scored at the exact depth's size
    half = depth[::2, ::2]
    save_maps(tmp_path / "half" / "a.npz", preview=False, depth=half, confidence=confidence[::2, ::2])
    small = depth_accuracy(tmp_path / "half", tmp_path / "exact")
    # nearest resampling moves the unconfident columns' edge by up to a pixel
    assert small["median_signed_error"] == pytest.approx(-0.01, rel=1e-4) and small["density"] == pytest.approx(24 / 27, abs=0.01)
    save_maps(tmp_path / "no_depth" / "a.npz", preview=False, confidence=confidence)
    with pytest.raises(Eve3dError, match="no 'depth' array"):
        depth_accuracy(tmp_path / "no_depth", tmp_path / "exact")
    save_maps(tmp_path / "none" / "a.npz", preview=False, depth=depth, confidence=0 * confidence)
    assert depth_accuracy(tmp_path / "none", tmp_path / "exact")["median_signed_error"] is None  # nothing to score


def test_depth_accuracy_on_weak_texture(tmp_path):
    """With the photos, the weakly textured pixels (a flat grey half) are scored on their own:
    their share of the surface, how many have a depth, and their error."""
    import cv2

    exact = np.full((20, 40), 2.0, np.float32)
    photo = np.full((20, 40), 128, np.uint8)
    photo[:, 20:] = np.random.default_rng(0).integers(0, 255, (20, 20))  # textured right half
    depth = exact * 1.01
    depth[:, 20:] = exact[:, 20:] * 0.98
    confidence = np.ones_like(exact)
    confidence[:, :10] = 0  # half of the flat half has no depth
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "a.png"), photo)
    save_maps(tmp_path / "exact" / "a.npz", preview=False, depth=exact, confidence=np.ones_like(exact))
    save_maps(tmp_path / "maps" / "a.npz", preview=False, depth=depth, confidence=confidence)
    acc = depth_accuracy(tmp_path / "maps", tmp_path / "exact", images=tmp_path / "images", window=5)
    # the 5 px window reaches 2 px into the textured half from the flat one
    assert acc["weak_share"] == pytest.approx(18 / 40)
    assert acc["weak_density"] == pytest.approx(8 / 18)
    assert acc["weak_rel_error"] == pytest.approx(0.01, rel=1e-4)
    assert "weak_share" not in depth_accuracy(tmp_path / "maps", tmp_path / "exact")
    with pytest.raises(Eve3dError, match="no photo of view a"):
        depth_accuracy(tmp_path / "maps", tmp_path / "exact", images=tmp_path)


def sgbm_depth(left, right, f, baseline, settings=None, margin: int = 48):
    padded = np.pad(left, ((0, 0), (margin, 0), (0, 0)))
    disp, confidence = (m[:, margin:] for m in sgbm_disparity(padded, right, 64, settings))
    return np.where(disp > 0, f * baseline / np.maximum(disp, 1e-6), 0), confidence >= 0.5


@pytest.mark.parametrize("tilt", [10, 50])
def test_sgbm_on_exact_right_views_of_a_plane_has_no_depth_bias(tilt):
    """The issue's bound: SGBM on exact right views of a plane 2 units away (slanted, so
    that its disparity runs through fractions of a pixel), median signed relative depth
    error within 0.1 %."""
    left, right, exact, f, baseline = plane_pair(tilt, 25.6)
    depth, confident = sgbm_depth(left, right, f, baseline)
    use = confident & (exact > 0) & (depth > 0)
    assert use.mean() > 0.7
    assert abs(np.median((depth[use] - exact[use]) / exact[use])) < 0.001


def test_single_pass_aggregation_carries_the_disparity_down_a_slope():
    """The cause of the priors' bias on the object's table: SGBM's single-pass modes
    aggregate only along paths from above and the left, so on a surface slanted top to
    bottom they carry one end's disparity into the other (here 0.5 % of depth); the two-
    pass 8-direction mode (the default) stays within 0.1 %."""
    left, right, exact, f, baseline = plane_pair(35, 25.6)
    errors = {}
    for mode in ("hh", "3way"):
        depth, confident = sgbm_depth(left, right, f, baseline, SgbmSettings(sgm_mode=mode))
        use = confident & (exact > 0) & (depth > 0)
        errors[mode] = abs(float(np.median((depth[use] - exact[use]) / exact[use])))
    assert errors["hh"] < 0.001
    assert errors["3way"] > 0.004


def test_sgbm_mode_out_of_range_is_named():
    with pytest.raises(Eve3dError, match="stereo.sgm_mode"):
        SgbmSettings(sgm_mode="fast")


@pytest.fixture(scope="module")
def plane_dataset(tmp_path_factory):
    """The ``plane`` kind, small: 12 views at 160×120 (exact poses, GT mesh)."""
    from eve3d.core.io import load_scene
    from eve3d.priors.oracle import priors_from_mesh
    from eve3d.synth import generate

    dataset = generate("plane", tmp_path_factory.mktemp("plane") / "plane", views=12, width=160, height=120)
    priors_from_mesh(load_scene(dataset), dataset.parent / "exact", preview=False)  # its exact depth, once
    return dataset


def train_plane(dataset, out, **overrides):
    """``pgsr`` at the ``cpu`` preset, briefly (300 steps, its schedule scaled down) and at
    half the images' size (the preset's size when the bounds below were measured); returns
    the accuracy of its rendered depth against the exact depth."""
    from eve3d.config import job_config, stage_settings
    from eve3d.core.io import load_scene
    from eve3d.core.methods import methods
    from eve3d.core.settings import JointSettings
    from eve3d.joint import train_joint

    brief = ["joint.iterations=300", "joint.dn_from=100", "joint.mv_from=100", "joint.checkpoint_every=0",
             "joint.densify.refine_stop=250", "joint.previews=0", "train.resolution=0.5"]
    config = job_config(None, brief + [f"train.{k}={v}" for k, v in overrides.items()])
    settings = stage_settings(JointSettings, "joint", config, overrides=methods()["pgsr"].settings, method="pgsr")
    scene = load_scene(dataset)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # bit-reproducible: summed over 2 threads, the balls' bias drew −0.20 … −0.35 %
    try:
        train_joint(scene, out / "pgsr", settings)
    finally:
        torch.set_num_threads(threads)
    return depth_accuracy(out / "pgsr" / "depth", dataset.parent / "exact")


@pytest.mark.slow
def test_pgsr_on_a_plane_has_no_depth_bias(plane_dataset, tmp_path):
    """The issue's bound: a textured plane 2 units away, trained briefly with ``pgsr`` at the
    ``cpu`` preset: the rendered depth's median signed error within 0.1 % (measured +0.02 to
    +0.06 % over seeds 0–3). Started from 3DGS's isotropic balls instead of discs
    (``init_thickness: 1``), the same run renders the plane 0.3 % too near or more, on average
    over seeds 0–3: the cause this guards against. One seed alone is not a measurement of it:
    the balls' error moves with the split draws and with float rounding (seeds 0–3: −0.32,
    −0.32, −0.30, −0.37 % before issue 21's vectorised compositing and C++ SSIM; −0.25, −0.52,
    −0.25, −0.48 % after; the mean −0.33 and −0.38 %). At 3/4 of the images' size (the
    ``cpu`` preset since issue 21) the balls drew −0.35, −0.37, −0.18, −0.29 %, the discs
    stayed within 0.1 %."""
    acc = train_plane(plane_dataset, tmp_path / "discs")
    assert acc["density"] > 0.9
    assert abs(acc["median_signed_error"]) < 0.001
    balls = [train_plane(plane_dataset, tmp_path / f"balls{seed}", init_thickness=1.0, seed=seed)["median_signed_error"]
             for seed in range(4)]
    assert np.mean(balls) < -0.003, balls


def test_initial_gaussians_on_a_surface_are_discs_in_its_plane():
    """Points on a slanted plane become discs whose thin axis is the plane's normal;
    points scattered in a volume (3DGS's random start) stay balls."""
    from eve3d.gaussians.model import GaussianModel
    from eve3d.gaussians.render.projection import quat_to_rotmat

    rng = np.random.default_rng(0)
    normal = np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866])
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    plane = rng.uniform(-1, 1, (400, 2)) @ np.stack([u, np.cross(normal, u)])
    volume = rng.uniform(-1, 1, (400, 3)) + 5
    model = GaussianModel.from_points(np.concatenate([plane, volume]), None, 1, thickness=0.1)
    axes = quat_to_rotmat(model.params["quats"]).numpy()
    scales = model.scales.numpy()
    assert np.abs(axes[:400, :, 2] @ normal).min() > 0.999
    np.testing.assert_allclose(scales[:400, 2] / scales[:400, 0], 0.1, rtol=1e-5)
    assert (scales[400:, 2] / scales[400:, 0] > 0.5).mean() > 0.95
    line = np.outer(np.linspace(-1, 1, 50), normal) + 9  # collinear points span no plane: balls
    on_line = GaussianModel.from_points(line, None, 1, thickness=0.1).scales.numpy()
    assert np.allclose(on_line[:, 2], on_line[:, 0])
    balls = GaussianModel.from_points(plane, None, 1)  # thickness 1: 3DGS's initialisation
    assert np.allclose(balls.scales.numpy()[:, 2], balls.scales.numpy()[:, 0])
