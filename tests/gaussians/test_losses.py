"""eve3d.gaussians.losses: the photometric, NCC and round-trip losses, fused C++ against PyTorch."""
import numpy as np
import pytest
import torch

from eve3d.core.scene import Camera
from eve3d.gaussians.geometry import CameraStack, depth_to_normal
from eve3d.gaussians.losses import forward_backward_error, geometric_loss, ncc_loss, ssim
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.joint import prior_plane
from tests.helpers import plane_seen_twice as _plane_views
from tests.helpers import plane_view_pair as _plane_pair
from tests.helpers import plane_views


def test_homography_ncc_is_about_one_on_the_true_plane_and_lower_on_a_wrong_one():
    from eve3d.gaussians.losses import ncc_loss

    ref, nbr, depth = _plane_pair(tilt=0.3)  # 6 px of disparity, a texture period of about 11 px
    mask = torch.zeros_like(depth, dtype=torch.bool)
    mask[4:-4, 4:-20] = True
    scores = {}
    for name, d in (("true", depth), ("20% far", depth * 1.2), ("50% far", depth * 1.5),
                    ("untilted", torch.full_like(depth, float(depth.mean())))):
        normal, distance = prior_plane(d, ref)
        ncc, ok = (x[0] for x in ncc_loss(ref.grey, [nbr.grey], ref.cam, CameraStack([nbr.cam]), normal, distance,
                                          mask.nonzero()[None]))
        assert ok.float().mean() > 0.8
        scores[name] = 1 - float(ncc[ok].mean())  # the mean NCC
    assert scores["true"] > 0.999
    assert scores["20% far"] < 0.9 and scores["50% far"] < 0.6 and scores["untilted"] < scores["true"] - 0.01, scores


def test_a_neighbour_pixel_without_a_measured_depth_confirms_nothing():
    from eve3d.gaussians.losses import depth_confirmation

    xs = (0.3, -0.2)
    (ref, *nbrs), depth = plane_views(0.3, (0.0, *xs))
    theirs = [plane_views(0.3, (x,))[1] for x in xs]
    cams = CameraStack([n.cam for n in nbrs])

    def confirm(d, conf, tol=0.01):
        return depth_confirmation(d, ref.grey, ref.cam, cams, theirs, conf, [n.grey for n in nbrs], tol)

    everywhere = [torch.ones_like(d, dtype=torch.bool) for d in theirs]
    agrees, ncc, flat = confirm(depth, everywhere)
    assert agrees.shape == (2, *depth.shape) and agrees.float().mean() > 0.6 and not flat.any()
    assert float(ncc[agrees].median()) > 0.95  # the photos agree where the depth is right
    assert not confirm(depth, [~c for c in everywhere])[0].any()  # nothing measured: nothing confirmed
    # measured only on the left half of each neighbour: a pixel that lands anywhere near the right half confirms nothing
    left = [c.clone() for c in everywhere]
    for c in left:
        c[:, 32:] = False
    agrees_left = confirm(depth, left)[0]
    R, t = (x.to(depth.dtype) for x in (cams.R @ ref.cam.R.T, cams.t - (cams.R @ ref.cam.R.T) @ ref.cam.t))
    uv, _ = cams.project(depth[..., None] * ref.cam.rays() @ R.transpose(1, 2)[:, None] + t[:, None, None])
    assert agrees_left.any() and not agrees_left[uv[..., 0] > 31.5].any()
    # 2 % too far: refuted at a 1 % tolerance, confirmed at 3 %, and the photos disagree
    far = depth * 1.02
    assert confirm(far, everywhere)[0].float().mean() < 0.05 and confirm(far, everywhere, 0.03)[0].float().mean() > 0.6
    assert float(confirm(depth * 1.5, everywhere)[1][agrees].mean()) < float(ncc[agrees].mean()) - 0.3


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

    def phi(d, *n):
        return forward_backward_error(d, list(n), ref, nbrs, fused=True)[0] * defined

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

    def loss(n, d):
        return ncc_loss(grey, greys, ref, nbrs, n, d, pixels[:, :8], fused=True)[0] * ok

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

    def blur(m):
        return correlate(m, window, mode="constant", cval=0.0)

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
