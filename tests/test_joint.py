"""eve3d.joint: the joint stage (pgsr, eve3d and their variants): priors, D̂, the LBA, the opacity loss, resuming."""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps, save_maps
from eve3d.core.methods import methods
from eve3d.core.settings import JointSettings
from eve3d.evaluate.depth import depth_accuracy
from eve3d.gaussians.geometry import CameraStack
from eve3d.gaussians.losses import forward_backward_error
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.train_state import Checkpoint
from eve3d.gaussians.training import Trainer
from eve3d.joint import multiview_terms, prior_plane, setup_joint, train_joint
from eve3d.priors.oracle import priors_from_mesh
from tests.helpers import joint_settings, run_cli
from tests.helpers import plane_view_pair as _plane_pair
from tests.helpers import plane_views as _plane_views


# -- the LBA's geometry ----------------------------------------------------------------------

def test_multiview_terms_of_k_neighbours_at_once_equal_one_at_a_time():
    xs = (0.3, -0.2, 0.15)
    (ref, *nbrs), depth = _plane_views(0.3, (0.0, *xs))
    nbr_depths = [_plane_views(0.3, (x,))[1] for x in xs]  # each neighbour's exact depth
    wrong = depth * (1 + 0.02 * torch.sin(torch.arange(depth.numel(), dtype=depth.dtype) / 7).reshape(depth.shape))
    normal, distance = prior_plane(wrong, ref)
    mask = torch.ones_like(depth, dtype=torch.bool)
    s = JointSettings(ncc_pixels=300)
    together = multiview_terms(ref, nbrs, wrong, normal, distance, nbr_depths, mask, s, torch.Generator().manual_seed(3))
    gen = torch.Generator().manual_seed(3)
    apart = [multiview_terms(ref, [v], wrong, normal, distance, [d], mask, s, gen) for v, d in zip(nbrs, nbr_depths)]
    geo, (ncc_sum, ncc_count), passed = together
    assert passed.shape == (3, *depth.shape) and 0.1 < passed.float().mean() < 0.99
    for k, (geo_k, (sum_k, count_k), passed_k) in enumerate(apart):
        assert torch.equal(passed[k], passed_k[0])
        assert torch.allclose(geo[k], geo_k[0], rtol=1e-9) and float(geo[k]) > 0
        assert ncc_count[k] == count_k[0] and torch.allclose(ncc_sum[k], sum_k[0], rtol=1e-9)


def test_lba_reprojection_returns_a_pixel_to_itself_with_exact_depth():
    ref, nbr, depth = _plane_pair()
    nbr_depth = torch.full_like(depth, 3.0)  # fronto-parallel: the neighbour sees z = 3 too
    phi, defined = (x[0] for x in forward_backward_error(depth, [nbr_depth], ref.cam, CameraStack([nbr.cam])))
    assert defined.float().mean() > 0.6 and float(phi[defined].max()) < 1e-3
    s = JointSettings(ncc_pixels=400)
    normal, distance = prior_plane(depth, ref)
    geo, ncc, _ = multiview_terms(ref, [nbr], depth, normal, distance, [nbr_depth], defined, s,
                                  torch.Generator().manual_seed(0))
    assert float(geo[0]) < 1e-3
    # 1 − NCC ≈ 0: the true plane's homography aligns the patches (up to the bilinear lookup)
    assert float(ncc[0][0] / ncc[1][0]) < 5e-3


# -- priors reaching training -----------------------------------------------------------------


@pytest.fixture(scope="module")
def noisy_priors(tiny_scene, tmp_path_factory) -> Path:
    """Oracle depth with a 3% multiplicative error on a band of rows and 2% noise, the band
    confident (a prior that is confident and wrong), a quarter of pixels unconfident."""
    exact = tmp_path_factory.mktemp("priors") / "oracle"
    priors_from_mesh(tiny_scene, exact, preview=False)
    noisy = exact.parent / "noisy"
    noisy.mkdir()
    rng = np.random.default_rng(0)
    for cam in tiny_scene.cameras:
        m = load_maps(exact / f"{cam.view_id}.npz")
        d = m["depth"] * (1 + 0.02 * rng.standard_normal(m["depth"].shape))
        d[10:20] *= 1.03
        conf = m["confidence"] * (rng.random(d.shape) > 0.25)
        save_maps(noisy / f"{cam.view_id}.npz", preview=False, depth=np.where(m["depth"] > 0, d, 0), confidence=conf,
                  normal=m["normal"])
    return noisy


def _eve3d(**kw) -> JointSettings:
    base = {**methods()["eve3d-paper"].settings, "init_prior_points": 3000}  # every Eve3D part on
    densify = joint_settings().densify
    return joint_settings(**{**base, **kw, "method": "eve3d"}, densify=replace(densify, refine_stop=0))


def _log_depths(trainer: Trainer) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in trainer.state.extras.items() if k.startswith("prior_log_depth/")}


def test_learnable_priors_move_only_as_the_method_says(tiny_scene, tmp_path, noisy_priors):
    # before T_joint, without the LBA: nothing moves D̂
    run = setup_joint(tiny_scene, tmp_path / "a", _eve3d(iterations=20, prior_from=0, joint_from=100, lba_weight=0.0),
                      noisy_priors)
    start = _log_depths(run.trainer)
    run.trainer.run(run.loss)
    assert all(torch.equal(start[k], v) for k, v in _log_depths(run.trainer).items())
    # before T_joint with the LBA among the priors: D̂ moves
    run = setup_joint(tiny_scene, tmp_path / "b", _eve3d(iterations=20, prior_from=0, joint_from=100), noisy_priors)
    run.trainer.run(run.loss)
    moved = _log_depths(run.trainer)
    assert sum(not torch.equal(start[k], v) for k, v in moved.items()) >= 6
    # after T_joint (L_prior towards D̂, L_pull, the LBA of the rendered depth): D̂ moves on
    run = setup_joint(tiny_scene, tmp_path / "c", _eve3d(iterations=20, prior_from=0, joint_from=0, lba_weight=0.0),
                      noisy_priors)
    run.trainer.run(run.loss)
    assert sum(not torch.equal(start[k], v) for k, v in _log_depths(run.trainer).items()) >= 6


def test_confidence_never_grows_and_the_check_refutes_what_is_wrong(tiny_scene, tmp_path, noisy_priors):
    from eve3d.gaussians.neighbours import select_neighbours

    exact, banded = noisy_priors.parent / "oracle", tmp_path / "banded"
    banded.mkdir()
    for cam in tiny_scene.cameras:  # 0.2 % noise, 5 % too far on a band of columns, all confident
        m = load_maps(exact / f"{cam.view_id}.npz")
        d = m["depth"] * (1 + 0.002 * np.random.default_rng(0).standard_normal(m["depth"].shape))
        d[:, 24:34] *= 1.05  # the cameras circle the object: in a neighbour the band falls on other columns
        save_maps(banded / f"{cam.view_id}.npz", preview=False, depth=d, confidence=m["confidence"], normal=m["normal"])
    run = setup_joint(tiny_scene, tmp_path / "run", _eve3d(iterations=20, prior_from=0, joint_from=10), banded)
    priors, views = run.priors, run.trainer.views
    for i, near in enumerate(select_neighbours(tiny_scene, 4)):
        priors.update_confidence(i, [views[j] for j in near])

    def kept(cols):
        mine, star = (sum(c[:, cols].sum() for c in maps.confidence) for maps in (priors, priors.star))
        return float(mine / star)

    assert kept(slice(24, 34)) < 0.2 * kept(slice(36, 64)) and kept(slice(36, 64)) > 0.1
    run.trainer.run(run.loss)
    for now, measured in zip(priors.confidence, priors.star.confidence):
        assert not (now & ~measured).any()  # never more than the stereo measured


def test_a_step_leaves_unvisited_views_priors_and_moments_untouched(tiny_scene, tmp_path, noisy_priors):
    from eve3d.gaussians.neighbours import select_neighbours

    run = setup_joint(tiny_scene, tmp_path, _eve3d(iterations=1, prior_from=0, joint_from=0, neighbours=2),
                      noisy_priors)
    start, visited, loss = _log_depths(run.trainer), [], run.loss
    run.trainer.run(lambda step, view, out: visited.append(view.index) or loss(step, view, out))
    used = {visited[0], *select_neighbours(tiny_scene, 2)[visited[0]]}
    assert len(used) == 3
    for k, v in _log_depths(run.trainer).items():
        i, state = int(k.split("/")[1]), run.trainer.state.extra_optimizers[k].state
        if i in used:
            assert not torch.equal(start[k], v) and state, i
        else:
            assert torch.equal(start[k], v) and not state, i


def test_prior_fixed_has_no_learnable_priors_and_pulls_towards_d_star(tiny_scene, tmp_path, noisy_priors):
    s = joint_settings(**methods()["prior-fixed"].settings, method="prior-fixed", iterations=30, prior_from=0,
                        joint_from=10)
    run = setup_joint(tiny_scene, tmp_path, s, noisy_priors)
    star = [d.clone() for d in run.priors.star.depth]
    seen = []
    loss = run.loss
    run.trainer.run(lambda step, view, out: seen.append(t := loss(step, view, out)) or t)
    assert not _log_depths(run.trainer) and all(map(torch.equal, run.priors.star.depth, star))
    assert all("prior" in t and "pull" not in t and "lba" not in t for t in seen)
    assert torch.equal(run.priors.depth(0), star[0])


def test_killed_run_resumes_to_the_same_gaussians_and_priors(tiny_scene, tmp_path, noisy_priors, monkeypatch,
                                                            one_thread):
    s = _eve3d(iterations=40, prior_from=0, joint_from=20, checkpoint_every=15)

    def final(out):
        run = setup_joint(tiny_scene, out, s, noisy_priors)
        run.trainer.run(run.loss)
        return run

    straight = final(tmp_path / "straight")
    save = Checkpoint.save

    def save_then_die(self, state):
        save(self, state)
        if state.step == 30:
            raise KeyboardInterrupt

    monkeypatch.setattr(Checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        final(tmp_path / "killed")
    monkeypatch.setattr(Checkpoint, "save", save)
    resumed = final(tmp_path / "killed")
    assert resumed.trainer.state.step == 40
    for name, value in straight.trainer.model.params.items():
        assert torch.allclose(resumed.trainer.model.params[name], value, atol=1e-5), name
    for k, v in _log_depths(straight.trainer).items():
        assert torch.allclose(_log_depths(resumed.trainer)[k], v, atol=1e-6), k
    assert all(map(torch.equal, resumed.priors.confidence, straight.priors.confidence))


def test_checkpoint_from_other_priors_is_not_resumed(tiny_scene, tmp_path, noisy_priors, capsys):
    s = _eve3d(iterations=10, prior_from=0, joint_from=5)
    run = setup_joint(tiny_scene, tmp_path / "run", s, noisy_priors)
    run.trainer.checkpoint.save(run.trainer.state)
    other = tmp_path / "other"
    other.mkdir()
    for f in noisy_priors.glob("*.npz"):
        m = load_maps(f)
        save_maps(other / f.name, preview=False, **{**m, "depth": m["depth"] * 1.01})
    same = setup_joint(tiny_scene, tmp_path / "run", s, noisy_priors).trainer
    assert same.checkpoint.resume(same.state)
    changed = setup_joint(tiny_scene, tmp_path / "run", s, other).trainer
    assert not changed.checkpoint.resume(changed.state)
    assert "other settings" in capsys.readouterr().err


def test_eve3d_starts_from_points_on_the_prior_surface(tiny_scene, tmp_path, noisy_priors):
    from eve3d.core.raycast import MeshRaycaster  # noqa: F401 (the GT mesh is read by open3d)
    import open3d as o3d

    run = setup_joint(tiny_scene, tmp_path, _eve3d(init_prior_points=2000), noisy_priors)
    means = run.trainer.model.params["means"].detach().numpy()
    assert len(means) == 2000
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(str(tiny_scene.gt_mesh)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    dist = scene.compute_distance(o3d.core.Tensor(means.astype(np.float32))).numpy()
    # the priors are 2% noisy (3% on a band): points lie within a few % of the depth (≈ 3 units)
    assert np.median(dist) < 0.05 and np.mean(dist < 0.15) > 0.95


def test_eve3d_starts_from_the_prior_points_and_the_sfm_points(tiny_scene, tmp_path, noisy_priors):
    run = setup_joint(tiny_scene, tmp_path, _eve3d(init="both", init_prior_points=2000), noisy_priors)
    means = run.trainer.model.params["means"].detach().numpy()
    assert len(tiny_scene.points) >= 4 and len(means) == 2000 + len(tiny_scene.points)
    np.testing.assert_allclose(means[2000:], tiny_scene.points, atol=1e-6)
    without = replace(tiny_scene, points=None, point_colors=None)  # no SfM: the prior points alone
    assert len(setup_joint(without, tmp_path / "b", _eve3d(init="both", init_prior_points=2000),
                           noisy_priors).trainer.model.params["means"]) == 2000


def test_exported_priors_at_dataset_resolution_with_previews(tiny_scene, tmp_path, noisy_priors):
    train_joint(tiny_scene, tmp_path, _eve3d(iterations=10, prior_from=0, joint_from=5, resolution=0.5), noisy_priors)
    m = load_maps(tmp_path / "priors/000.npz")
    cam = tiny_scene.cameras[0]
    assert m["depth"].shape == (cam.height, cam.width) and set(m) == {"depth", "confidence", "normal"}
    assert (tmp_path / "priors/000.compare.png").exists() and (tmp_path / "priors/000.depth.png").exists()


@pytest.mark.parametrize("damage, message", [
    ("missing", "003.npz: missing prior for view 003"),
    ("size", r"003.npz: maps are 64×24, view 003 is 64×48 \(or a scale of it\)"),
])
def test_bad_prior_map_is_named_before_training(tiny_scene, tmp_path, noisy_priors, damage, message):
    import shutil

    bad = tmp_path / "priors"
    shutil.copytree(noisy_priors, bad)
    path = bad / "003.npz"
    if damage == "missing":
        path.unlink()
    else:
        m = load_maps(path)
        # half the rows: not the view at any scale (a map at half the size is resampled)
        m = {k: v[::2] for k, v in m.items()}
        save_maps(path, preview=False, **m)
    with pytest.raises(Eve3dError, match=message):
        setup_joint(tiny_scene, tmp_path / "run", _eve3d(), bad)


def test_a_view_without_prior_depth_trains_without_prior_terms(tiny_scene, tmp_path, noisy_priors, capsys):
    """A view whose stereo matched nothing (a blank ceiling in a 300-view room) is named in
    a warning and trains: no L_prior, its D̂ starts at the median of the other views'
    median prior depths (L_pull moves it towards the rendered depth) and it is nobody's LBA
    neighbour. Priors blank in every view stop with the folder named."""
    import shutil

    bad = tmp_path / "priors"
    shutil.copytree(noisy_priors, bad)
    for cam in tiny_scene.cameras[:3]:
        m = load_maps(bad / f"{cam.view_id}.npz")
        save_maps(bad / f"{cam.view_id}.npz", preview=False, **{**m, "depth": m["depth"] * 0})
    run = setup_joint(tiny_scene, tmp_path / "run", _eve3d(iterations=12, prior_from=0, joint_from=4), bad)
    blank = [cam.view_id for cam in tiny_scene.cameras[:3]]
    warning = capsys.readouterr().err
    assert f"3 of {len(tiny_scene.cameras)} views have no confident prior depth" in warning, warning
    assert warning.rstrip().endswith(", ".join(blank)), warning
    typical = torch.stack([d[d > 0].median() for d in run.priors.star.depth[3:]]).median()
    start = _log_depths(run.trainer)
    assert run.priors.blank == {0, 1, 2}
    assert torch.allclose(start["prior_log_depth/0"], torch.log(typical).expand_as(start["prior_log_depth/0"]))
    terms = []
    run.trainer.run(lambda step, view, out: terms.append((view.index, set(t := run.loss(step, view, out)))) or t)
    blank_terms = set().union(*(t for i, t in terms if i < 3))
    assert "prior" not in blank_terms and terms and all(
        torch.isfinite(v).all() for v in _log_depths(run.trainer).values())
    for cam in tiny_scene.cameras[3:]:
        m = load_maps(bad / f"{cam.view_id}.npz")
        save_maps(bad / f"{cam.view_id}.npz", preview=False, **{**m, "depth": m["depth"] * 0})
    with pytest.raises(Eve3dError, match=f"{bad}: no confident prior depth in any view"):
        setup_joint(tiny_scene, tmp_path / "none", _eve3d(), bad)


def test_prior_method_without_priors_stops_with_what_is_missing(tiny_dataset, tmp_path):
    r = run_cli("joint", "--method", "eve3d", "--scene", tiny_dataset, "--out", tmp_path / "a")
    assert r.returncode == 2 and "method eve3d uses the stereo priors: give their folder (--priors" in r.stderr
    r = run_cli("joint", "--method", "prior-fixed", "--scene", tiny_dataset, "--out", tmp_path / "b",
                "--priors", tmp_path / "stereo")
    assert r.returncode == 2 and "no priors folder (run the stereo stage" in r.stderr
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())


def test_opacity_loss_lowers_the_opacity_of_every_visible_gaussian(tiny_scene, tmp_path):
    """``opacity_weight``: weight × mean opacity of the Gaussians a view sees, a term of its
    own, whose gradient lowers each of their opacities; off by default."""
    run = setup_joint(tiny_scene, tmp_path / "on", joint_settings(opacity_weight=0.01))
    model = run.trainer.model
    view = run.trainer.views[run.trainer.views.train_ids[0]]
    out = run.trainer.render(view, 0)
    terms = run.loss(0, view, out)
    opacities = model.opacities[out.visible].detach()
    assert out.visible.any() and float(terms["opacity"].detach()) == pytest.approx(0.01 * float(opacities.mean()), rel=1e-5)
    terms["opacity"].backward()
    grad = model.params["logit_opacities"].grad
    assert (grad[out.visible] > 0).all() and (grad[~out.visible] == 0).all()
    off = setup_joint(tiny_scene, tmp_path / "off", joint_settings())
    assert "opacity" not in off.loss(0, view, off.trainer.render(view, 0))
    # opacity_while_densifying: the term runs to the last refinement step, not after
    short = setup_joint(tiny_scene, tmp_path / "short", joint_settings(opacity_weight=0.01, opacity_while_densifying=True))
    stop = short.trainer.settings.densify.refine_stop
    out = short.trainer.render(view, stop)
    assert "opacity" in short.loss(stop - 1, view, out) and "opacity" not in short.loss(stop, view, out)
    assert "opacity" in run.loss(stop, view, out)  # without it, to the end


def test_opacity_loss_spares_the_gaussians_on_the_confident_prior(tiny_scene, tmp_path, noisy_priors):
    """``opacity_spare``: a Gaussian whose centre lies on the confident prior at its pixel
    keeps its opacity; the same Gaussian moved 20 % nearer the camera (in free space) is
    lowered, with the push per visible Gaussian of the plain opacity loss."""
    from eve3d.joint import on_prior_surface

    exact = noisy_priors.parent / "oracle"
    run = setup_joint(tiny_scene, tmp_path, _eve3d(prior_from=0, lba_weight=0.0, init="priors", opacity_weight=0.01,
                                                   opacity_spare=0.02), exact)
    model, view = run.trainer.model, run.trainer.views[run.trainer.views.train_ids[0]]
    visible = run.trainer.render(view, 0).visible
    before = on_prior_surface(model, view, run.priors, 0.02)
    assert before[visible].float().mean() > 0.5  # they start on the priors' surface
    with torch.no_grad():  # every other Gaussian slides 20 % of its depth towards this camera
        means, centre = model.params["means"], -view.cam.R.T @ view.cam.t
        means[1::2] = centre + 0.8 * (means[1::2] - centre)
    spared = on_prior_surface(model, view, run.priors, 0.02)
    assert torch.equal(spared[0::2], before[0::2]) and not spared[1::2][before[1::2]].any()
    out = run.trainer.render(view, 0)
    terms = run.loss(0, view, out)
    lowered = out.visible & ~spared
    expected = 0.01 * float(model.opacities.detach()[lowered].sum() / out.visible.sum())
    assert float(terms["opacity"].detach()) == pytest.approx(expected, rel=1e-5)
    terms["opacity"].backward()
    grad = model.params["logit_opacities"].grad
    assert (grad[lowered] > 0).all() and (grad[~lowered] == 0).all()


# -- pgsr: resuming, depth without bias --------------------------------------------------------

def test_killed_run_resumes_to_the_same_parameters(tiny_scene, tmp_path, monkeypatch, one_thread):
    settings = dict(exposure=True, exposure_lr=0.01)  # the per-image exposures are resumed too
    train_joint(tiny_scene, tmp_path / "straight", joint_settings(**settings))
    straight = GaussianModel.load_ply(tmp_path / "straight/point_cloud.ply")
    assert not (tmp_path / "straight/checkpoint.pt").exists()  # removed once the outputs exist

    save = Checkpoint.save

    def save_then_die(self, state):
        save(self, state)
        if state.step == 50:
            raise KeyboardInterrupt  # killed right after the second checkpoint

    monkeypatch.setattr(Checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        train_joint(tiny_scene, tmp_path / "killed", joint_settings(**settings))
    monkeypatch.setattr(Checkpoint, "save", save)
    assert (tmp_path / "killed/checkpoint.pt").exists() and not (tmp_path / "killed/point_cloud.ply").exists()
    train_joint(tiny_scene, tmp_path / "killed", joint_settings(**settings))
    resumed = GaussianModel.load_ply(tmp_path / "killed/point_cloud.ply")
    assert len(resumed) == len(straight)
    for name, value in straight.params.items():
        assert torch.allclose(resumed.params[name], value, atol=1e-5), name
    assert (tmp_path / "killed/depth/000.npz").exists() and (tmp_path / "killed/previews/000.rgb.png").exists()


@pytest.fixture(scope="module")
def plane_dataset(tmp_path_factory):
    """The ``plane`` kind, small: 12 views at 160×120 (exact poses, GT mesh)."""
    from eve3d.synth import generate

    from eve3d.core.io import load_scene
    from eve3d.priors.oracle import priors_from_mesh

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
    ``cpu`` preset: the rendered depth's median signed error within 0.1 %. Started from 3DGS's
    isotropic balls instead of discs (``init_thickness: 1``), the same run fails that bound on
    every seed, always too near: the cause this guards against. How far too near moves with the
    split draws and with float rounding, which changes with the CPU the C++ rasteriser was
    compiled for (``-march=native``): the mean over seeds 0–3 was −0.33, −0.38 and −0.30 % on
    earlier machines and −0.22 % on an AMD EPYC (seeds 0–7 there: −0.34, −0.21, −0.14, −0.18,
    −0.43, −0.50, −0.29, −0.38 %; the same code built for generic x86-64 drew −0.29, −0.31,
    −0.45, −0.18 % on seeds 0–3; the discs +0.05 to +0.09 %), so a bound on the mean of four
    seeds is a draw, and the test asserts the separation instead."""
    acc = train_plane(plane_dataset, tmp_path / "discs")
    assert acc["density"] > 0.9
    assert abs(acc["median_signed_error"]) < 0.001
    balls = [train_plane(plane_dataset, tmp_path / f"balls{seed}", init_thickness=1.0, seed=seed)["median_signed_error"]
             for seed in range(4)]
    assert max(balls) < -0.001, balls


def test_coarse_steps_take_every_term_and_prior_at_the_coarse_size(tiny_scene, tmp_path, noisy_priors):
    """Coarse to fine with every Eve3D term on from the start (L_prior towards D̂, L_pull, the
    LBA, PGSR's multi-view terms): the first 30 of 40 steps render and fit each view, its
    neighbours and its priors at half the training size; M^c is re-checked at the training
    size on every visit; the coarse steps train every pixel of D̂, not one of each 2×2
    block (which would leave at most a quarter of a map moved); the priors written are at the
    training size."""
    from eve3d.joint import PriorState

    fine = torch.arange(48 * 64, dtype=torch.float32).reshape(48, 64)
    half = type("V", (), {"image": torch.zeros(24, 32, 3)})()
    assert torch.equal(PriorState.sized(fine, half), fine[1::2, 1::2])  # one pixel of each block, never a blend
    picked = {tuple(PriorState.sized(fine, half, step)[0, 0:1].long().tolist()) for step in range(8)}
    assert len(picked) == 4  # the block's four pixels in turn
    cam = tiny_scene.cameras[0]
    h, w = cam.height, cam.width
    s = _eve3d(iterations=40, prior_from=0, joint_from=0, dn_from=0, mv_from=0, coarse_until=0.75,
               coarse_side=max(w, h) // 2, checkpoint_every=0)
    run = setup_joint(tiny_scene, tmp_path, s, noisy_priors)
    trainer = run.trainer
    shapes, checked = [], []
    update = run.priors.update_confidence

    def checking(i, nbrs):
        checked.append({tuple(n.image.shape[:2]) for n in nbrs})
        update(i, nbrs)

    run.priors.update_confidence = checking

    def loss(step, view, out):
        shapes.append(tuple(out.rgb.shape[:2]))
        return run.loss(step, view, out)

    start = _log_depths(trainer)
    trainer.run(loss, until=30)
    moved = [(start[k] != v).float().mean().item() for k, v in _log_depths(trainer).items()]
    print(f"share of D̂ moved by the coarse steps, per view: {[round(m, 2) for m in moved]}")
    assert max(moved) > 0.4, moved  # measured 0.43-0.78 (a quarter at most from one pixel a block)
    trainer.run(loss)
    assert shapes == [(h // 2, w // 2)] * 30 + [(h, w)] * 10
    assert len(checked) == 40 and all(sizes == {(h, w)} for sizes in checked)
    assert all(v.shape == (h, w) for v in _log_depths(trainer).values())


def test_a_prior_beyond_the_measured_scene_is_not_trusted(tiny_sky_scene, tmp_path):
    # a matcher that finds the sky textured gives it a finite, confident depth everywhere
    exact, sky = tmp_path / "oracle", tmp_path / "sky"
    priors_from_mesh(tiny_sky_scene, exact, preview=False)
    sky.mkdir()
    for cam in tiny_sky_scene.cameras:
        m = load_maps(exact / f"{cam.view_id}.npz")
        save_maps(sky / f"{cam.view_id}.npz", preview=False, depth=np.where(m["depth"] > 0, m["depth"], 10.0),
                  confidence=np.ones_like(m["depth"]), normal=m["normal"])
    run = setup_joint(tiny_sky_scene, tmp_path / "run", _eve3d(iterations=1), sky)
    views = run.trainer.views
    beyond = sum(int(v.beyond.sum()) for v in views)
    assert beyond > 0.1 * sum(v.beyond.numel() for v in views)  # the sky fills a good part of the photos
    assert not any((c & v.beyond).any() for c, v in zip(run.priors.star.confidence, views))
    surface = [torch.from_numpy(load_maps(exact / f"{v.camera.view_id}.npz")["depth"] > 0) for v in views]
    kept = sum(int((c & s).sum()) for c, s in zip(run.priors.star.confidence, surface))
    assert kept > 0.95 * sum(int(s.sum()) for s in surface)  # the object's priors stay


def test_the_prior_weighs_more_where_the_photo_has_no_texture():
    """prior_flat_weight: λ_prior rises from prior_weight on texture to prior_flat_weight on a
    blank wall (5×5 grey-level std 0), linearly below FLAT_LEVELS; off, it is the scalar."""
    from eve3d.gaussians.views import View
    from eve3d.joint import FLAT_LEVELS, prior_weights

    grey = torch.full((40, 40, 1), 0.5)
    grey[:, 20:, 0] += 0.2 * (torch.rand(40, 20, generator=torch.Generator().manual_seed(0)) - 0.5)  # textured
    grey[:, :10, 0] += FLAT_LEVELS / 2 * torch.tensor([1.0, -1.0]).repeat(5)[None]  # half the level: std FLAT_LEVELS/2
    view = View(0, None, None, grey.expand(-1, -1, 3))  # a grey photo: its grey levels are these
    assert prior_weights(view, JointSettings(prior_weight=0.05)) == 0.05
    w = prior_weights(view, JointSettings(prior_weight=0.05, prior_flat_weight=0.5))
    assert w.shape == (40, 40)
    assert torch.allclose(w[:, 13:17], torch.tensor(0.5))  # blank
    assert torch.allclose(w[:, 24:], torch.tensor(0.05))  # textured
    # ±half a level in alternate columns: a 5×5 std of 0.98 × FLAT_LEVELS/2, about half the rise
    assert torch.allclose(w[5:35, 2:8], torch.tensor(0.05 + 0.45 * (1 - 0.98 / 2)), atol=2e-3)
