"""eve3d.stereo: right cameras and views, the confidence checks every backend passes through, depth from disparity."""
import json

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings_stereo import BaselineSettings, MatchCheck
from tests.helpers import dim, sgbm_priors, shifted_pair, stereo_scene
from eve3d.core.photos import equalizing_curve
from eve3d.priors.matching import local_std
from eve3d.priors.sgbm import sgbm_disparity
from eve3d.stereo import PAIRS_FILE, checked_confidence, render_right_views, right_camera


def test_right_camera_gives_disparity_fx_b_over_z():
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    angle = np.radians(30)
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    left = Camera("a.png", 320, 240, K, R, np.array([0.1, -0.2, 0.3]))
    right = right_camera(left, 0.25)
    assert np.allclose(right.R, left.R) and np.allclose(right.K, left.K)
    assert np.allclose(right.center - left.center, 0.25 * left.R[0])  # along the camera's own x axis
    points = np.random.default_rng(0).normal(size=(50, 3)) + left.center + 4 * left.R[2]
    (uv_l, z), (uv_r, _) = left.project(points), right.project(points)
    assert np.allclose(uv_l[:, 0] - uv_r[:, 0], 300 * 0.25 / z) and np.allclose(uv_l[:, 1], uv_r[:, 1])


def test_sgbm_priors_match_the_photo_through_the_pretrains_tone_curve(tmp_path):
    """A dim photo whose right view comes from a model fitted to the equalised photos: with
    the pretrain's curve in pairs.json the photo is matched through it (right depth, confident
    over most of the view); without it, the photo's faint texture meets the right view's
    stretched one and far fewer pixels are confident (0.23 against 0.58)."""
    import cv2

    scene, write_pairs = stereo_scene(tmp_path, 10)
    left, right = shifted_pair(10)
    curve = equalizing_curve((dim(left),), 5)
    cv2.imwrite(str(tmp_path / "v.png"), dim(left)[..., ::-1])
    cv2.imwrite(str(tmp_path / "stereo/right/v.png"), curve[dim(right)][..., ::-1])
    write_pairs()
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "plain", preview=False)
    pairs = json.loads((tmp_path / "stereo" / PAIRS_FILE).read_text())
    (tmp_path / "stereo" / PAIRS_FILE).write_text(json.dumps({**pairs, "tone_curve": curve.tolist()}))
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "toned", preview=False)
    plain, toned = load_maps(tmp_path / "plain/v.npz"), load_maps(tmp_path / "toned/v.npz")
    sure = toned["confidence"] > 0.5
    print(f"confident: without the curve {(plain['confidence'] > 0.5).mean():.3f}, with it {sure.mean():.3f}")
    assert sure.mean() > 0.5 and (plain["confidence"] > 0.5).mean() < sure.mean() - 0.25
    np.testing.assert_allclose(np.median(toned["depth"][sure]), 100 * 0.5 / 10, rtol=1e-3)
    (tmp_path / "stereo" / PAIRS_FILE).write_text(json.dumps({**pairs, "tone_curve": [0, 1]}))
    with pytest.raises(Eve3dError, match="tone_curve must list 256"):
        sgbm_priors(scene, tmp_path / "stereo", tmp_path / "bad", preview=False)


def test_sgbm_priors_write_depth_fx_b_over_d(tmp_path):
    scene, write_pairs = stereo_scene(tmp_path, 10)
    with pytest.raises(Eve3dError, match="pairs.json: missing"):
        sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    write_pairs()
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.5
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 100 * 0.5 / 10, rtol=1e-3)
    assert (tmp_path / "priors/v.depth.png").exists() and (tmp_path / "priors/v.confidence.png").exists()


def test_a_shifted_disparity_loses_its_confidence():
    """The photometric check does not rest on the matcher: the true disparity keeps its
    confidence, the same map shifted by a few pixels (consistent, but wrong) loses it, and
    so does a disparity pinned at the end of the range searched."""
    left, right = shifted_pair(12, grain=2)
    sure = np.ones(left.shape[:2], np.float32)

    def kept(disp):
        return checked_confidence(left, right, disp, sure, (0, 40))[:, 20:].mean()

    true = np.full(left.shape[:2], 12.0, np.float32)
    assert kept(true) > 0.95
    for shift in (3, -3, 5):
        assert kept(true + shift) < 0.1, shift
    assert kept(np.full_like(true, 39.5)) == 0


def test_a_silhouette_gives_the_empty_background_no_confident_depth():
    """A textured square on an empty black background: SGBM's window straddling its edge gives
    the background beside it the square's disparity (foreground fattening), and the
    left–right and NCC checks pass it. The jump check drops it, so does the pretrained
    model's alpha (here exactly the square), so does the flat test (the black is a plain
    background), and so does the black background's lack of any light (``min_light``, off by
    default); what stays confident is right."""
    left, right = shifted_pair(12, grain=2)
    square = np.zeros(left.shape[:2], bool)
    square[24:72, 40:100] = True
    moved = np.roll(square, -12, axis=1)  # the square in the right view (x_right = x_left − 12)
    left, right = left * square[..., None], right * moved[..., None]
    disp, conf = sgbm_disparity(left, right, 40)

    def confident(alpha=None, **check):
        return checked_confidence(left, right, disp, conf, (0, 40), check=MatchCheck(**check), alpha=alpha) > 0

    assert (confident(edge_window=0, min_alpha=0, flat_level=0) & ~square).sum() > 100  # the halo
    for c in (confident(min_alpha=0, flat_level=0), confident(square.astype(np.float32), edge_window=0, flat_level=0),
              confident(min_alpha=0), confident(edge_window=0, min_alpha=0, flat_level=0, min_light=1),
              confident(square.astype(np.float32))):
        assert not (c & ~square).any() and c[square].mean() > 0.5 and np.all(disp[c] == 12)


def test_a_plain_sky_gets_no_depth_where_a_plain_wall_between_edges_keeps_it():
    """A network answers everywhere: here the disparity of two textured squares carried
    into everything around them, as HITNet carries a table's into a sky beyond its edge.
    The plain wall between the squares is enclosed by their texture and keeps its depth (a
    matcher interpolates it between its edges); the plain sky around them, open to the
    image's border, loses it (there it extrapolates). Without the flat test every pixel is
    confident."""
    rng = np.random.default_rng(0)
    h, w = 80, 140
    left = np.tile(np.linspace(200, 215, h)[:, None, None], (1, w, 3))  # a sky: plain, a faint gradient
    for cols in (slice(10, 40), slice(90, 120)):
        left[20:60, cols] = rng.uniform(0, 255, (40, 30, 1))
    left[20:60, 40:90] = 150  # a plain wall between them
    left = left.astype(np.uint8)
    disp, everywhere = np.full((h, w), 12.0, np.float32), np.ones((h, w), np.float32)

    def confident(**check):
        check = MatchCheck(ncc_threshold=0, min_alpha=0, **check)
        return checked_confidence(left, left, disp, everywhere, (0, 40), check=check) > 0

    assert confident(flat_level=0).all()
    kept = confident()
    assert kept[24:56, 50:80].all()  # the wall, a few pixels in from its edges
    assert kept[24:56, 14:36].all() and kept[24:56, 94:116].all()  # the squares
    sky = np.ones((h, w), bool)
    sky[20:60, 10:120] = False
    assert not kept[sky].any()


def test_priors_without_the_pretrained_models_alpha_are_refused_by_name(tmp_path):
    import shutil

    scene, write_pairs = stereo_scene(tmp_path, 10)
    write_pairs()
    shutil.rmtree(tmp_path / "stereo/alpha")
    with pytest.raises(Eve3dError, match=r"stereo/alpha/v.png: missing .*stereo-render.*min_alpha: 0"):
        sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    assert not (tmp_path / "priors").exists()
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors", check=MatchCheck(min_alpha=0))
    assert (tmp_path / "priors/v.npz").exists()


def plane_model(tmp_path, depth: float, cam: Camera):
    """Gaussians on a textured fronto-parallel plane at ``depth`` in front of ``cam``."""
    from eve3d.gaussians.model import GaussianModel

    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.linspace(-1.2, 1.2, 160), np.linspace(-0.9, 0.9, 120))
    points = np.stack([u.ravel() * depth, v.ravel() * depth, np.full(u.size, depth)], 1)
    colors = np.repeat(rng.uniform(0, 1, (u.size, 1)), 3, axis=1)
    model = GaussianModel.from_points(points, colors, sh_degree=0, opacity=0.99)
    model.save_ply(tmp_path / "model.ply")
    return tmp_path / "model.ply"


def test_disparity_baseline_gives_the_target_disparity_at_the_median_depth(tmp_path):
    """On a synthetic pair (a textured plane 4 units away) the per-view baseline makes the
    disparity at the median depth the target fraction of the width; SGBM finds it on the
    rendered pair, including near the left edge (the right view's margin), and the depth
    it gives back is the plane's. The bound B ≤ max_baseline × Z holds."""
    import torch

    from eve3d.core.fileio import write_image
    from eve3d.gaussians.model import GaussianModel
    from eve3d.gaussians.render import render

    K = np.array([[80.0, 0, 48], [0, 80, 36], [0, 0, 1]])
    cam = Camera("v.png", 96, 72, K, np.eye(3), np.zeros(3), image_path=tmp_path / "v.png")
    model = GaussianModel.load_ply(plane_model(tmp_path, 4.0, cam))
    with torch.no_grad():
        photo = render(model.params["means"], model.params["quats"], model.scales, model.opacities,
                       model.colors(torch.zeros(3)), cam, antialiased=True).rgb
    write_image(cam.image_path, (photo.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
    scene = Scene(tmp_path, [cam])
    info = render_right_views(scene, tmp_path / "model.ply", tmp_path / "stereo", BaselineSettings(target_disparity=10 / 96))
    pair = info["views"]["v"]
    assert pair["baseline"] * 80 / 4.0 == pytest.approx(10, rel=0.02)  # an integer: SGBM pixel-locks
    assert pair["max_disparity"] < pair["margin"]
    sgbm_priors(scene, tmp_path / "stereo", tmp_path / "priors")
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.6 and sure[:, :20].mean() > 0.5  # the left edge keeps its matches
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 4.0, rtol=0.01)
    bounded = BaselineSettings(target_disparity=0.5, max_baseline=0.15)
    assert bounded.of_view(cam, 1.0, 4.0) == pytest.approx(0.6)
    assert BaselineSettings(baseline="radius", baseline_factor=0.07).of_view(cam, 3.0, 4.0) == pytest.approx(0.21)
    with pytest.raises(Eve3dError, match="stereo.target_disparity"):
        BaselineSettings(target_disparity=0)


def test_neighbour_photos_agree_with_the_exact_depth_and_not_with_a_wrong_one(object_scene):
    """The multi-view check compares real photos: warped by the exact depth, a view's
    neighbours agree with it; by a depth 8 % too far (what a wrongly placed pretrained model
    would give the right view, and SGBM would then find), they do not."""
    from eve3d.core.fileio import read_image
    from eve3d.core.raycast import MeshRaycaster
    from eve3d.gaussians.neighbours import select_neighbours
    from eve3d.stereo import neighbour_ncc

    cams = object_scene.cameras
    i, near = 0, select_neighbours(object_scene, 4)[0]
    hits = MeshRaycaster.from_file(object_scene.gt_mesh).cast(cams[i])
    depth = np.where(hits.valid, hits.depth, 0).astype(np.float32)
    photo = read_image(cams[i].image_path)
    others = [(cams[j], read_image(cams[j].image_path)) for j in near]
    textured = hits.valid & (local_std(photo, 7) > 4)

    def agree(d):
        return ((neighbour_ncc(cams[i], photo, d, others) >= 0.5).sum(0) >= 2)[textured].mean()

    assert agree(depth) > 0.85  # measured 0.92
    assert agree(1.08 * depth) < 0.45  # measured 0.35


@pytest.mark.parametrize("max_disparity, density, wrong", [(128.0, 0.6, 0.005), (48.0, 0.5, 0.03)])
def test_real_pairs_carry_the_exact_depth_back_to_the_view(object_scene, max_disparity, density, wrong):
    """A view and its real neighbours, rectified with the known poses and matched by SGBM:
    the depth carried back to the view is the ray-cast depth to a fraction of a percent, with
    no model in between, and the empty background gets none; matched at a smaller scale too,
    where the pair's range passes ``stereo.real_max_disparity`` (48 px: a quarter to half size)."""
    from eve3d.core.fileio import read_image
    from eve3d.core.raycast import MeshRaycaster
    from eve3d.core.settings_stereo import RealPairSettings
    from eve3d.gaussians.neighbours import select_neighbours
    from eve3d.priors.real_pairs import pair_candidates
    from eve3d.priors.sgbm import SgbmStereo
    from eve3d.stereo import real_prior

    cams = object_scene.cameras
    chosen = pair_candidates(object_scene, select_neighbours(object_scene, 6), 3)
    i = 0
    assert len(chosen[i]) >= 2
    hits = MeshRaycaster.from_file(object_scene.gt_mesh).cast(cams[i])
    exact = np.where(hits.valid, hits.depth, 0)
    near, far = np.percentile(exact[hits.valid], [1, 99])
    pair = {"baseline": 1.0, "min_disparity": 0.75 * cams[i].fx / far, "max_disparity": 1.25 * cams[i].fx / near}
    depth, confidence = real_prior(cams[i], read_image(cams[i].image_path),
                                   [(cams[j], read_image(cams[j].image_path)) for j in chosen[i]], pair,
                                   SgbmStereo(), MatchCheck(), RealPairSettings(real_max_disparity=max_disparity), None)
    used = (confidence > 0) & hits.valid
    error = depth[used] / exact[used] - 1
    assert used.sum() > density * hits.valid.sum()  # measured 0.68 at 128 px, 0.62 at 48 px
    assert abs(np.median(error)) < 0.001  # measured 0.016 %, −0.019 %
    assert np.mean(np.abs(error) > 0.05) < wrong  # measured 0.13 %, 1.7 %
    assert (confidence > 0)[~hits.valid].mean() < 0.002  # measured 0.06 %


def test_a_pair_whose_baseline_runs_aslant_keeps_the_whole_view_in_its_rectified_frame():
    """Rectification turns the frame so that the baseline runs along its rows: with the
    neighbour down and to the right in the image (20°), a frame of the view's own size held 87 %
    of its pixels (a room's views lost their top rows, the ceiling). The frame now holds the whole
    view, and a plane 3 units ahead comes back at depth 3 on every pixel."""
    from eve3d.core.scene import Camera
    from eve3d.priors.real_pairs import RectifiedPair

    K = np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]])
    view = Camera("a.png", 64, 48, K, np.eye(3), np.zeros(3))
    centre = 0.2 * np.array([np.cos(np.radians(20)), np.sin(np.radians(20)), 0.0])
    other = Camera("b.png", 64, 48, K, np.eye(3), -centre)
    image = np.full((48, 64), 128, np.uint8)
    rect = RectifiedPair.build(view, image, other, image, (1.0, 10.0), 128.0)
    assert rect.left.shape[0] > 48 and rect.left.shape[1] > 64  # turned by 20°: a larger frame
    disparity = np.full(rect.left.shape, 60 * 0.2 / 3, np.float32)
    depth, confidence = rect.carried_back(disparity, np.ones_like(disparity))
    assert (depth > 0).all() and (confidence > 0).all()
    np.testing.assert_allclose(depth, 3.0, rtol=1e-5)


def test_a_view_without_a_real_pair_takes_its_virtual_prior(tmp_path):
    """``stereo.pairs: real`` on a view no neighbour rectifies with (here: it has none; in a
    capture walking forward, every neighbour stands along its line of sight): its prior is
    the virtual pair's, fx·B/d, not an empty map."""
    from eve3d.core.settings_stereo import RealPairSettings
    from eve3d.priors.sgbm import SgbmStereo
    from eve3d.stereo import stereo_priors

    scene, write_pairs = stereo_scene(tmp_path, 10)
    write_pairs()
    stereo_priors(scene, tmp_path / "stereo", tmp_path / "priors", SgbmStereo(), "SGBM", preview=False,
                  pairs=RealPairSettings(pairs="real"))
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.5
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 100 * 0.5 / 10, rtol=1e-3)


def test_real_pairs_agree_by_majority():
    """Two pairs that disagree on a pixel leave it without a prior; of three, the two that
    agree give their mean; one pair alone keeps its depth."""
    from eve3d.priors.real_pairs import agreed_depth

    depths = np.array([[2.0, 2.0, 2.0, 2.0], [2.1, 2.01, 2.3, 0.0], [0.0, 0.0, 2.02, 0.0]])[:, None, :]
    confidences = (depths > 0).astype(np.float32)
    depth, confidence = agreed_depth(depths, confidences, 1, 0.01)
    np.testing.assert_allclose(depth[0], [0, 2.005, 2.01, 2.0])
    assert (confidence[0] > 0).tolist() == [False, True, True, True]
    depth, confidence = agreed_depth(depths, confidences, 2, 0.01)
    assert (confidence[0] > 0).tolist() == [False, True, True, False]


def test_real_pair_settings_are_checked():
    from eve3d.core.settings_stereo import RealPairSettings

    with pytest.raises(Eve3dError, match="stereo.real_views"):
        RealPairSettings(real_views=4, real_neighbours=3)
    with pytest.raises(Eve3dError, match="stereo.pairs"):
        RealPairSettings(pairs="rendered")
