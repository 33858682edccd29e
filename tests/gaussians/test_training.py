"""Gaussian training: densification rules, the multi-view geometry of the PGSR losses,
checkpoint/resume, the NaN stop, and that training actually fits a tiny scene."""
import math

import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera
from eve3d.core.settings import DensifySettings, JointSettings, TrainSettings
from eve3d.core.settings_fields import from_mapping
from eve3d.gaussians.densify import Densifier, reset_opacity
from eve3d.gaussians.geometry import CameraStack, depth_to_normal
from eve3d.gaussians.losses import forward_backward_error, geometric_loss, ncc_loss, rgb_loss, ssim
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.gaussians.train_state import Checkpoint
from eve3d.gaussians.training import NonFiniteLoss, Trainer
from eve3d.gaussians.view_report import view_metrics
from eve3d.joint import train_joint
from tests.helpers import joint_settings


def constructed_model():
    """Six Gaussians whose fate under the default rules (scene scale 1) is known:
    0 small, high gradient → cloned; 1 large, high absolute gradient → split;
    2 large, high gradient but low absolute gradient → kept; 3 transparent → pruned;
    4 small, low gradient → kept; 5 small, high gradient but transparent → cloned, both pruned."""
    means = torch.arange(18, dtype=torch.float32).reshape(6, 3)
    scales = torch.tensor([0.005, 0.05, 0.05, 0.005, 0.005, 0.005])[:, None].repeat(1, 3)
    opac = torch.tensor([0.5, 0.5, 0.5, 0.001, 0.5, 0.002])
    params = {"means": means, "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(6, 1), "log_scales": scales.log(),
              "logit_opacities": torch.log(opac / (1 - opac)), "sh0": torch.rand(6, 1, 3), "shN": torch.zeros(6, 3, 3)}
    params = {k: torch.nn.Parameter(v) for k, v in params.items()}
    optimizers = {k: torch.optim.Adam([p], lr=0.01) for k, p in params.items()}
    for p in params.values():  # one step, so that every parameter has Adam moments
        p.grad = torch.ones_like(p)
    for o in optimizers.values():
        o.step()
    return params, optimizers


def test_densify_and_prune_follow_the_rules():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(grow_grad2d=0.0002, grow_absgrad2d=0.0008, grow_scale3d=0.01, prune_opa=0.005))
    state = d.init_state(6, n_views=4)
    state["count"][:] = 2
    state["grad2d"][:] = 2 * torch.tensor([0.001, 0.0001, 0.001, 0.0001, 0.0001, 0.001])
    state["absgrad2d"][:] = 2 * torch.tensor([0.001, 0.002, 0.0005, 0.0001, 0.0001, 0.001])
    before = {k: v.detach().clone() for k, v in params.items()}
    changed = d.refine(params, optimizers, state, step=600, scene_scale=1.0, generator=torch.Generator().manual_seed(0))
    assert changed == {"clone": 2, "split": 1, "prune": 3}  # pruned: 3, 5 and 5's clone
    # 6 + 2 clones + 1 (split: one becomes two) − 3 pruned
    assert len(params["means"]) == 6
    means = params["means"].detach()
    # survivors in order: 0, 2, 4, clone of 0, the two halves of 1
    assert torch.equal(means[:3], before["means"][[0, 2, 4]])
    assert torch.equal(means[3], before["means"][0])
    halves = params["log_scales"].detach()[4:]
    assert torch.allclose(halves, before["log_scales"][1] - math.log(1.6))
    assert ((means[4:] - before["means"][1]).norm(dim=-1) < 0.05 * 5).all()
    assert not torch.equal(means[4], means[5])
    for name, p in params.items():
        st = optimizers[name].state[p]
        assert st["exp_avg"].shape == p.shape  # moments follow the rows
        assert torch.count_nonzero(st["exp_avg"][:3]) == st["exp_avg"][:3].numel()  # survivors keep theirs
        assert torch.count_nonzero(st["exp_avg"][3:]) == 0  # new rows start at zero
    assert len(state["grad2d"]) == 6 and float(state["count"].sum()) == 0


def test_prune_by_views_and_size_and_reset_opacity():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(prune_min_views=2, reset_every=1000, prune_scale3d=0.03))
    state = d.init_state(6, n_views=4)
    state["seen"][:, 0] = True
    state["seen"][[0, 1], 1] = True  # only 0 and 1 were seen by two views
    state["birth"][0] = 100  # too young to be judged
    mask = d.prune_mask(params, state, step=105, scene_scale=1.0)
    assert mask.tolist() == [False, False, True, True, True, True]
    mask = d.prune_mask(params, state, step=1500, scene_scale=1.0)  # after a reset: size rule on
    assert mask.tolist() == [False, True, True, True, True, True]
    low = params["logit_opacities"].detach()[3].clone()
    reset_opacity(params, optimizers, 0.01)
    assert torch.sigmoid(params["logit_opacities"].detach()).max() <= 0.01 + 1e-6
    assert params["logit_opacities"].detach()[3] == low  # already below: untouched


def _plane_views():
    """A textured plane z = 3 seen by two cameras; exact depth, normal, distance, images."""
    K = np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]])
    ry = np.radians(8)
    R2 = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    cams = [Camera("a.png", 64, 48, K, np.eye(3), np.zeros(3)),
            Camera("b.png", 64, 48, K, R2, np.array([-0.4, 0.05, 0.0]))]
    out = []
    for cam in cams:
        rays = cam.pixel_rays()
        c = cam.center
        s = (3.0 - c[2]) / rays[..., 2]
        p = c + rays * s[..., None]
        tex = 0.5 + 0.25 * np.sin(3 * p[..., 0]) * np.cos(2 * p[..., 1]) + 0.2 * np.sin(5 * p[..., 0] + 1.3 * p[..., 1])
        depth = (p @ cam.R.T + cam.t)[..., 2]
        out.append((CameraTensors.from_camera(cam, torch.float64), torch.tensor(depth),
                    torch.tensor(np.repeat(tex[..., None], 3, -1))))
    normal_a = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand(48, 64, 3)
    return out, normal_a, torch.full((48, 64), 3.0, dtype=torch.float64)


def test_multiview_losses_vanish_on_the_true_plane_and_not_off_it():
    (a, b), normal, distance = _plane_views()
    cam_a, depth_a, img_a = a
    cam_b, depth_b, img_b = b
    assert torch.allclose(depth_to_normal(depth_a, cam_a)[1:-1, 1:-1], normal[1:-1, 1:-1], atol=1e-9)
    phi, defined = (x[0] for x in forward_backward_error(depth_a, [depth_b], cam_a, CameraStack([cam_b])))
    assert defined.float().mean() > 0.5 and phi[defined].max() < 0.01  # bilinear depth lookup: z is not affine in (u, v)
    loss, valid = geometric_loss(phi, defined)
    assert float(loss) < 0.01 and torch.equal(valid, defined)
    # 8 px of disparity here: a 5% depth error leaves the loop open by about 0.4 px, 20% by 1.6 px
    phi_off = forward_backward_error(depth_a * 1.05, [depth_b], cam_a, CameraStack([cam_b]))[0][0]
    assert 0.3 < phi_off[defined].median() < 0.5
    phi_off = forward_backward_error(depth_a * 1.2, [depth_b], cam_a, CameraStack([cam_b]))[0][0]
    assert phi_off[defined].median() > 1.0
    pixels = torch.stack(torch.meshgrid(torch.arange(10, 38, 3), torch.arange(10, 54, 3), indexing="ij"), -1).reshape(-1, 2)
    grey_a, grey_b, cams_b = img_a.mean(-1, keepdim=True), [img_b.mean(-1, keepdim=True)], CameraStack([cam_b])
    ncc, ok = (x[0] for x in ncc_loss(grey_a, grey_b, cam_a, cams_b, normal, distance, pixels[None]))
    # exact up to the bilinear lookup in the neighbour (low-contrast patches feel it most)
    assert ok.float().mean() > 0.5 and ncc[ok].median() < 1e-3 and ncc[ok].max() < 0.02
    ncc_off, ok_off = (x[0] for x in ncc_loss(grey_a, grey_b, cam_a, cams_b, normal, distance * 1.3, pixels[None]))
    assert ncc_off[ok & ok_off].mean() > 0.1


def _round_trip_setup(dtype, width=40, height=30):
    """A reference and three rotated, shifted neighbours with noisy depths near 3 (every
    pixel a round trip that mostly closes, some leaving the neighbour's frame)."""
    K = np.array([[44.0, 0, 20.3], [0, 46, 14.8], [0, 0, 1]])
    cams = []
    for i in range(4):
        a = 0.06 * i
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        cam = Camera(f"{i}.png", width, height, K, R, np.array([-0.15 * i, 0.02 * i, 0]))
        cams.append(CameraTensors.from_camera(cam, dtype))
    g = torch.Generator().manual_seed(0)
    depth = 3 + 0.2 * torch.rand(height, width, generator=g, dtype=dtype)
    nbr_depths = [3 + 0.2 * torch.rand(height, width, generator=g, dtype=dtype) for _ in range(3)]
    return cams[0], CameraStack(cams[1:]), depth, nbr_depths


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-10), (torch.float32, 2e-4)])
def test_fused_round_trip_matches_the_pytorch_reference(dtype, tol):
    ref, nbrs, depth, nbr_depths = _round_trip_setup(dtype)
    depth[0, :5] = 0  # no depth: undefined
    results = []
    for fused in (False, True):
        d, n = depth.clone().requires_grad_(), [x.clone().requires_grad_() for x in nbr_depths]
        phi, defined = forward_backward_error(d, n, ref, nbrs, fused=fused)
        weights = torch.linspace(0.1, 1, phi.numel(), dtype=dtype).reshape(phi.shape)
        (phi * weights * defined).sum().backward()
        results.append((phi, defined, d.grad, torch.stack([x.grad for x in n])))
    (phi, defined, g_ref, g_nbr), (phi_f, defined_f, g_ref_f, g_nbr_f) = results
    assert torch.equal(defined, defined_f) and 0.5 < defined.float().mean() < 0.99
    assert torch.allclose(phi_f[defined], phi[defined], rtol=tol, atol=tol)
    assert g_ref.abs().max() > 0.1 and g_nbr.abs().max() > 0.1
    assert torch.allclose(g_ref_f, g_ref, rtol=tol, atol=tol * 10) and torch.allclose(g_nbr_f, g_nbr, rtol=tol,
                                                                                         atol=tol * 10)


def test_fused_round_trip_gradients_pass_gradcheck():
    ref, nbrs, depth, nbr_depths = _round_trip_setup(torch.float64, 12, 9)
    defined = forward_backward_error(depth, nbr_depths, ref, nbrs, fused=True)[1]
    assert defined.float().mean() > 0.7
    phi = lambda d, *n: forward_backward_error(d, list(n), ref, nbrs, fused=True)[0] * defined  # noqa: E731
    inputs = (depth.requires_grad_(), *[x.requires_grad_() for x in nbr_depths])
    assert torch.autograd.gradcheck(phi, inputs, eps=1e-7, atol=1e-5)


def _ncc_inputs(dtype):
    """Grey images with a shared sinusoidal texture (shifted per neighbour, plus noise),
    planes near the fronto-parallel z = 3, and 50 random pixels per neighbour."""
    g = torch.Generator().manual_seed(1)
    yy, xx = torch.meshgrid(torch.arange(30, dtype=dtype), torch.arange(40, dtype=dtype), indexing="ij")
    grey = (0.5 + 0.3 * torch.sin(xx * 0.7) * torch.cos(yy * 0.5))[..., None]
    greys = [(0.5 + 0.3 * torch.sin(xx * 0.7 + 0.3 * k) * torch.cos(yy * 0.5 - 0.2 * k)
              + 0.05 * torch.rand(30, 40, generator=g, dtype=dtype))[..., None] for k in range(3)]
    tilt = torch.tensor([0.05, -0.03, -1.0], dtype=dtype)
    normal = torch.nn.functional.normalize(tilt + 0.1 * torch.randn(30, 40, 3, generator=g, dtype=dtype), dim=-1)
    distance = 3 + 0.3 * torch.rand(30, 40, generator=g, dtype=dtype)
    pixels = torch.stack([torch.randint(0, 30, (3, 50), generator=g), torch.randint(0, 40, (3, 50), generator=g)], -1)
    return grey, greys, normal, distance, pixels


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-10), (torch.float32, 1e-4)])
def test_fused_ncc_matches_the_pytorch_reference(dtype, tol):
    ref, nbrs, _, _ = _round_trip_setup(dtype)
    grey, greys, normal, distance, pixels = _ncc_inputs(dtype)
    results = []
    for fused in (False, True):
        n, d = normal.clone().requires_grad_(), distance.clone().requires_grad_()
        loss, ok = ncc_loss(grey, greys, ref, nbrs, n, d, pixels, fused=fused)
        weights = torch.linspace(0.1, 1, loss.numel(), dtype=dtype).reshape(loss.shape)
        (loss * weights * ok).sum().backward()
        results.append((loss, ok, n.grad, d.grad))
    (loss, ok, g_n, g_d), (loss_f, ok_f, g_n_f, g_d_f) = results
    assert torch.equal(ok, ok_f) and 0.4 < ok.float().mean() < 0.9
    assert torch.allclose(loss_f[ok], loss[ok], atol=tol) and 0.3 < loss[ok].mean() < 1.2
    assert g_n.abs().max() > 1 and g_d.abs().max() > 1
    assert torch.allclose(g_n_f, g_n, atol=tol * 10) and torch.allclose(g_d_f, g_d, atol=tol * 10)


def test_fused_ncc_gradients_pass_gradcheck():
    ref, nbrs, _, _ = _round_trip_setup(torch.float64)
    grey, greys, normal, distance, pixels = _ncc_inputs(torch.float64)
    ok = ncc_loss(grey, greys, ref, nbrs, normal, distance, pixels[:, :8], fused=True)[1]
    assert ok.float().mean() > 0.4
    loss = lambda n, d: ncc_loss(grey, greys, ref, nbrs, n, d, pixels[:, :8], fused=True)[0] * ok  # noqa: E731
    assert torch.autograd.gradcheck(loss, (normal.requires_grad_(), distance.requires_grad_()), eps=1e-7, atol=1e-5)


def test_ssim_matches_a_reference_with_zero_padding():
    """3DGS's SSIM (11×11 Gaussian window, σ 1.5, zero padding) against scipy's correlate."""
    from scipy.ndimage import correlate

    rng = np.random.default_rng(0)
    a = rng.random((30, 41, 3))
    b = np.clip(a + 0.1 * rng.normal(size=a.shape), 0, 1)
    x = np.arange(11) - 5.0
    g = np.exp(-x**2 / (2 * 1.5**2))
    window = np.outer(g, g) / g.sum() ** 2
    blur = lambda m: correlate(m, window, mode="constant", cval=0.0)  # noqa: E731
    maps = []
    for ch in range(3):
        u, v = a[..., ch], b[..., ch]
        mu_u, mu_v = blur(u), blur(v)
        var_u, var_v, cov = blur(u * u) - mu_u**2, blur(v * v) - mu_v**2, blur(u * v) - mu_u * mu_v
        c1, c2 = 0.01**2, 0.03**2
        maps.append((2 * mu_u * mu_v + c1) * (2 * cov + c2) / ((mu_u**2 + mu_v**2 + c1) * (var_u + var_v + c2)))
    for fused in (False, True):
        assert abs(float(ssim(torch.tensor(a), torch.tensor(b), fused=fused)) - np.mean(maps)) < 1e-12, fused


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-14), (torch.float32, 1e-6)])
def test_fused_ssim_matches_the_pytorch_reference(dtype, tol):
    """Values and gradients of the C++ SSIM against the grouped-convolution reference, on an
    image whose sides are not multiples of anything and one smaller than the window."""
    g = torch.Generator().manual_seed(3)
    for shape in ((37, 53, 3), (6, 9, 1)):
        a = torch.rand(shape, generator=g, dtype=dtype).requires_grad_()
        b = torch.rand(shape, generator=g, dtype=dtype)
        ref, fused = ssim(a, b, fused=False), ssim(a, b, fused=True)
        assert abs(float((ref - fused).detach())) < tol
        grad_ref, grad_fused = (torch.autograd.grad(v, a)[0] for v in (ref, fused))
        assert grad_ref.abs().max() > 1e-5
        torch.testing.assert_close(grad_fused, grad_ref, rtol=1e-4, atol=tol * 1e-2)


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_fused_depth_to_normal_matches_the_pytorch_reference(dtype, tol):
    """Normals and depth gradients of the C++ depth_to_normal against the reference, on a
    rough depth with a hole, for spans 1 to 3."""
    c = _plane_views()[0][0][0]
    cam = CameraTensors(c.R.to(dtype), c.t.to(dtype), c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    g = torch.Generator().manual_seed(5)
    depth = (2 + torch.rand(48, 64, generator=g, dtype=dtype))
    depth[10:14, 20:23] = 0
    weights = torch.randn(48, 64, 3, generator=g, dtype=dtype)
    for span in (1, 2, 3):
        d = depth.clone().requires_grad_()
        ref, fused = (depth_to_normal(d, cam, span, fused=f) for f in (False, True))
        assert fused.dtype == dtype and fused.is_contiguous()
        torch.testing.assert_close(fused, ref, rtol=0, atol=tol)
        grad_ref, grad_fused = (torch.autograd.grad((n * weights).sum(), d)[0] for n in (ref, fused))
        assert grad_ref.abs().max() > 1
        torch.testing.assert_close(grad_fused, grad_ref, rtol=tol, atol=tol * grad_ref.abs().max().item())


def test_fused_depth_to_normal_gradients_pass_gradcheck():
    cam = _plane_views()[0][0][0]
    g = torch.Generator().manual_seed(6)
    depth = (2 + torch.rand(48, 64, generator=g, dtype=torch.float64))[20:29, 30:41].contiguous()
    small = CameraTensors(cam.R, cam.t, cam.fx, cam.fy, cam.cx - 30, cam.cy - 20, 11, 9)
    for span in (1, 2):
        assert torch.autograd.gradcheck(lambda d: depth_to_normal(d, small, span, fused=True),
                                        (depth.requires_grad_(),))


def test_fused_ssim_gradients_pass_gradcheck():
    g = torch.Generator().manual_seed(4)
    a = torch.rand(9, 12, 2, generator=g, dtype=torch.float64).requires_grad_()
    b = torch.rand(9, 12, 2, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda x: 3 * ssim(x, b, fused=True), (a,), eps=1e-6, atol=1e-8)


def test_ncc_gradient_reaches_the_plane():
    (a, b), normal, distance = _plane_views()
    d = (distance * 1.1).requires_grad_()
    pixels = torch.tensor([[24, 32], [20, 20], [30, 40]])
    ncc, ok = (x[0] for x in ncc_loss(a[2].mean(-1, keepdim=True), [b[2].mean(-1, keepdim=True)], a[0],
                                      CameraStack([b[0]]), normal, d, pixels[None]))
    ncc[ok].sum().backward()
    assert d.grad[24, 32] != 0 and torch.count_nonzero(d.grad) == 3


def test_unknown_or_mistyped_setting_is_named():
    with pytest.raises(Exception, match="joint.densify: unknown key.*grow_grad"):
        from_mapping(JointSettings, {"densify": {"grow_grad": 1}}, "joint")
    with pytest.raises(Exception, match="joint.iterations: expected an integer ≥ 0, got 'many'"):
        from_mapping(JointSettings, {"iterations": "many"}, "joint")


def test_200_iterations_raise_psnr_by_5_db(tiny_scene, tmp_path):
    s = TrainSettings(iterations=200, sh_degree=0, checkpoint_every=0,
                      densify=DensifySettings(refine_start=50, refine_every=50, reset_every=0))
    trainer = Trainer(tiny_scene, s, tmp_path, "fit")
    trainer.state.set_model(GaussianModel.from_points(tiny_scene.points, tiny_scene.point_colors / 255, 0))
    before = view_metrics(trainer.model, trainer.views, trainer.views.train_ids, s)["psnr"]
    trainer.run(lambda step, view, out: {"rgb": rgb_loss(out.rgb, view.image)})
    after = view_metrics(trainer.model, trainer.views, trainer.views.train_ids, s)["psnr"]
    print(f"PSNR {before:.2f} → {after:.2f} dB")
    assert after - before >= 5.0


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


def test_changed_settings_do_not_resume_a_stale_checkpoint(tiny_scene, tmp_path, capsys):
    trainer = Trainer(tiny_scene, joint_settings(), tmp_path, "a")
    trainer.state.set_model(GaussianModel.from_points(tiny_scene.points, None, 1))
    trainer.checkpoint.save(trainer.state)
    other = Trainer(tiny_scene, joint_settings(iterations=61), tmp_path, "b")
    other.state.set_model(GaussianModel.from_points(tiny_scene.points, None, 1))
    assert not other.checkpoint.resume(other.state)
    assert "other settings" in capsys.readouterr().err


def test_nan_stops_with_iteration_and_term_and_keeps_checkpoint(tiny_scene, tmp_path):
    with pytest.raises(Eve3dError, match="joint.dn_weight: expected a number ≥ 0, got nan"):
        joint_settings(dn_weight=float("nan"))  # a NaN setting is refused up front
    s = joint_settings(dn_from=30, checkpoint_every=10)
    s.dn_weight = float("nan")  # so the loss term turns NaN at step 30
    (tmp_path / "point_cloud.ply").write_bytes(b"an earlier run's model")
    with pytest.raises(NonFiniteLoss, match=r"^joint \(pgsr\): loss term depth_normal is not finite at iteration 30;"
                                            r".*checkpoint.pt \(step 30\)$"):
        train_joint(tiny_scene, tmp_path, s)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 30
    assert all(torch.isfinite(v).all() for v in ckpt["params"].values())
    # no model of this run is written: the earlier one is intact, and nothing else was
    assert (tmp_path / "point_cloud.ply").read_bytes() == b"an earlier run's model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt", "point_cloud.ply"]


def test_growth_budget_keeps_the_strongest_candidates():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(max_gaussians=7, prune_opa=0.0))  # room for one more Gaussian
    state = d.init_state(6, n_views=4)
    state["count"][:] = 1
    # candidates, by gradient over threshold: clone 5 (15×), clone 0 (5×), split 1 (2.5×)
    state["grad2d"][:] = torch.tensor([0.001, 0.0001, 0.001, 0.0001, 0.0001, 0.003])
    state["absgrad2d"][:] = torch.tensor([0.001, 0.002, 0.0005, 0.0001, 0.0001, 0.001])
    means5 = params["means"].detach()[5].clone()
    changed = d.refine(params, optimizers, state, step=600, scene_scale=1.0)
    assert changed == {"clone": 1, "split": 0, "prune": 0} and len(params["means"]) == 7
    assert torch.equal(params["means"].detach()[6], means5)


def test_scene_without_points_starts_from_random_points_in_the_camera_sphere(tiny_scene):
    from dataclasses import replace

    from eve3d.gaussians.training import initial_points

    bare = replace(tiny_scene, points=None, point_colors=None, point_views=None)
    pts, colors = initial_points(bare, 500, np.random.default_rng(0))
    assert pts.shape == (500, 3) and colors.shape == (500, 3)
    dist = np.linalg.norm(pts - bare.center, axis=1)
    assert dist.max() <= bare.radius and np.median(dist) > 0.5 * bare.radius  # uniform in the ball
    same, _ = initial_points(tiny_scene, 500, np.random.default_rng(0))
    assert same is tiny_scene.points
