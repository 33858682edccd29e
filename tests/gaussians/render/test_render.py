"""eve3d.gaussians.render: the rasteriser against a brute-force reference, finite differences and analytic planes."""
import math

import numpy as np
import pytest
import torch
from PIL import Image

from eve3d.gaussians.render import render
from eve3d.gaussians.render.projection import ALPHA_MIN, project, quat_to_rotmat
from tests.helpers import pinhole_camera, random_gaussians


def brute_force(means, quats, scales, opacities, colors, cam, background):
    """Per-pixel loop: sort the Gaussians by depth and composite with gsplat's rules."""
    with torch.no_grad():
        R = quat_to_rotmat(quats)
        mc = means @ cam.R.T + cam.t
        proj = project(mc, R, scales, opacities, cam)
        out = np.zeros((cam.height, cam.width, 9))
        stops = 0
        for v in range(cam.height):
            for u in range(cam.width):
                T, acc = 1.0, np.zeros(8)
                for i in np.argsort(proj.depths.numpy(), kind="stable"):
                    if not (proj.radii[i] > 0).any():
                        continue
                    a, b, c = proj.conics[i].tolist()
                    dx, dy = u + 0.5 - proj.means2d[i, 0].item(), v + 0.5 - proj.means2d[i, 1].item()
                    alpha = min(0.999, opacities[i].item() * math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)))
                    if alpha < ALPHA_MIN:
                        continue
                    if T * (1 - alpha) <= 1e-4:
                        stops += 1
                        break
                    n = (cam.R @ R[i][:, int(torch.argmin(scales[i]))]).numpy()
                    if n @ mc[i].numpy() > 0:
                        n = -n
                    feat = np.concatenate([colors[i].numpy(), n, [-(n @ mc[i].numpy()), mc[i, 2].item()]])
                    acc += alpha * T * feat
                    T *= 1 - alpha
                out[v, u, :8] = acc
                out[v, u, :3] += T * background
                out[v, u, 8] = 1 - T
        return out, stops


BACKENDS = ["cpu", "torch"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_forward_matches_brute_force_reference(backend):
    cam = pinhole_camera()
    g = random_gaussians(150, spread=0.3)
    bg = np.array([0.2, 0.5, 0.9])
    out = render(*g, cam, background=torch.tensor(bg), backend=backend)
    ref, stops = brute_force(*g, cam, bg)
    assert out.n_pairs > 500
    np.testing.assert_allclose(out.rgb.numpy(), ref[..., :3], atol=1e-5)
    np.testing.assert_allclose(out.normal.numpy(), ref[..., 3:6], atol=1e-5)
    np.testing.assert_allclose(out.distance.numpy(), ref[..., 6], atol=1e-5)
    np.testing.assert_allclose(out.alpha.numpy(), ref[..., 8], atol=1e-5)
    covered = ref[..., 8] > 1e-8
    np.testing.assert_allclose(out.depth_expected.numpy()[covered], ref[..., 7][covered] / ref[..., 8][covered],
                               atol=1e-5)
    assert stops > 20  # the early stop at T ≤ 1e-4 was exercised


@pytest.mark.parametrize("backend", BACKENDS)
def test_float32_agrees_with_float64(backend):
    cam64, cam32 = pinhole_camera(), pinhole_camera(dtype=torch.float32)
    g64 = random_gaussians(40)
    out64 = render(*g64, cam64, backend=backend)
    out32 = render(*(x.float() for x in g64), cam32, backend=backend)
    np.testing.assert_allclose(out32.rgb.numpy(), out64.rgb.numpy(), atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_gradients_match_finite_differences(backend):
    cam = pinhole_camera(16, 12)
    g = [x.clone().requires_grad_(True) for x in random_gaussians(8, seed=3, spread=0.3, scale=(0.04, 0.1))]
    weights = torch.rand(12, 16, 7, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss(means, quats, scales, opacities, colors):
        out = render(means, quats, scales, opacities, colors, cam, backend=backend,
                     background=torch.tensor([0.3, 0.1, 0.7], dtype=torch.float64))
        maps = torch.cat([out.rgb, out.normal, out.distance[..., None]], dim=-1)
        return (maps * weights).sum() + (out.alpha * weights[..., 0]).sum()

    assert torch.autograd.gradcheck(loss, g, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_backends_agree_on_a_surface_scene():
    """The C++ tiles and the PyTorch pairs: same pairs, same images, same gradients."""
    from eve3d.tools.bench.rasterizer import surface_gaussians

    params, cam = surface_gaussians(3000, 160, 120)
    results = {}
    for backend in BACKENDS:
        g = [torch.from_numpy(p).requires_grad_(True) for p in params]
        out = render(*g, cam, backend=backend, absgrad=True)
        (out.rgb.square().mean() + out.depth.mean() + out.normal.abs().mean()).backward()
        results[backend] = out, [x.grad for x in g]
    (a, a_grads), (b, b_grads) = results["cpu"], results["torch"]
    assert a.n_pairs == b.n_pairs > 100_000
    for name in ("rgb", "alpha", "normal", "distance", "depth"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(a.absgrad, b.absgrad, rtol=1e-4, atol=1e-7)
    for ga, gb in zip(a_grads, b_grads):
        torch.testing.assert_close(ga, gb, rtol=1e-3, atol=1e-4 * gb.abs().max().item())



def test_small_gaussians_in_either_half_of_a_tile_render_as_the_torch_backend():
    """The C++ compositing takes half a tile's row where a Gaussian's footprint lies within
    one half (rasterize.cpp, ``Entry::lanes``): small Gaussians in the left half, the right
    half, across the middle and across a tile's edge give the torch backend's images and
    gradients."""
    cam = pinhole_camera(48, 20)
    u = torch.tensor([3.5, 11.5, 8.0, 7.6, 15.8, 16.2, 24.0, 31.9, 40.5, 44.0], dtype=torch.float64)
    v = torch.tensor([4.0, 9.0, 10.5, 15.0, 8.0, 12.0, 3.0, 16.5, 10.0, 6.0], dtype=torch.float64)
    z = torch.full_like(u, 2.5)
    means = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1)
    g = torch.Generator().manual_seed(5)
    quats = torch.randn(len(u), 4, generator=g, dtype=torch.float64)
    scales = 0.01 + 0.03 * torch.rand(len(u), 3, generator=g, dtype=torch.float64)
    opacities = 0.5 + 0.45 * torch.rand(len(u), generator=g, dtype=torch.float64)
    colors = torch.rand(len(u), 3, generator=g, dtype=torch.float64)
    weights = torch.rand(20, 48, 5, generator=g, dtype=torch.float64)
    results = {}
    for backend in BACKENDS:
        params = [x.clone().requires_grad_(True) for x in (means, quats, scales, opacities, colors)]
        out = render(*params, cam, backend=backend)
        maps = torch.cat([out.rgb, out.alpha[..., None], out.depth[..., None]], -1)
        (maps * weights).sum().backward()
        results[backend] = out, [x.grad for x in params]
    (a, a_grads), (b, b_grads) = results["cpu"], results["torch"]
    assert a.n_pairs == b.n_pairs > 100
    assert int((a.alpha > 0.1).sum()) > 40  # every Gaussian covers a few pixels
    for name in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), rtol=1e-10, atol=1e-12)
    for ga, gb in zip(a_grads, b_grads):
        assert gb.abs().max() > 0
        torch.testing.assert_close(ga, gb, rtol=1e-8, atol=1e-10 * gb.abs().max().item())

def test_torch_backend_in_bands_equals_single_pass():
    cam = pinhole_camera(40, 30, dtype=torch.float32)
    g = [x.float().requires_grad_(True) for x in random_gaussians(200, seed=5)]
    results = []
    for max_pairs in (10**9, 2000):
        out = render(*g, cam, backend="torch", max_pairs=max_pairs, absgrad=True)
        (out.rgb.square().sum() + out.depth.sum()).backward()
        results.append((out.rgb.detach().clone(), out.depth.detach().clone(), out.absgrad.clone(),
                        [x.grad.clone() for x in g]))
        for x in g:
            x.grad = None
    (a_rgb, a_depth, a_abs, a_grads), (b_rgb, b_depth, b_abs, b_grads) = results
    torch.testing.assert_close(a_rgb, b_rgb)
    torch.testing.assert_close(a_depth, b_depth)
    torch.testing.assert_close(a_abs, b_abs)
    for ga, gb in zip(a_grads, b_grads):
        torch.testing.assert_close(ga, gb, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_absgrad_sums_per_pixel_magnitudes(backend):
    """For a loss on one pixel, the accumulated |grad| equals |grad|; over many it is larger."""
    cam = pinhole_camera(dtype=torch.float32)
    g = [x.float().requires_grad_(True) for x in random_gaussians(40)]
    out = render(*g, cam, backend=backend, absgrad=True)
    out.rgb[9, 12].sum().backward()
    torch.testing.assert_close(out.absgrad, out.means2d_grad.abs())
    out = render(*g, cam, backend=backend, absgrad=True)
    (out.rgb[..., 0] * torch.linspace(-1, 1, 24)).sum().backward()
    vis = out.visible
    assert (out.absgrad[vis] >= out.means2d_grad.abs()[vis] - 1e-7).all()
    assert (out.absgrad[vis] > out.means2d_grad.abs()[vis] + 1e-6).any()


def flat_gaussian(normal_cam, center, cam, size=0.4):
    """One opaque, flat Gaussian through ``center`` with the given camera-space normal."""
    n = torch.nn.functional.normalize(torch.tensor(normal_cam, dtype=torch.float64), dim=0)
    # Rotation whose third column is n (smallest scale on that axis).
    a = torch.tensor([1.0, 0, 0], dtype=torch.float64)
    u = torch.nn.functional.normalize(torch.linalg.cross(n, a), dim=0)
    v = torch.linalg.cross(n, u)
    Rw = cam.R.T @ torch.stack([u, v, n], dim=1)  # world-space axes
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(Rw.numpy()).as_quat()
    means = (cam.R.T @ (torch.tensor(center, dtype=torch.float64) - cam.t))[None]
    return (means, torch.tensor([[w, x, y, z]], dtype=torch.float64),
            torch.tensor([[size, size, 1e-7]], dtype=torch.float64), torch.tensor([0.9], dtype=torch.float64),
            torch.ones(1, 3, dtype=torch.float64))


@pytest.mark.parametrize("backend", ["cpu", "torch"])
def test_a_geometry_only_render_gives_the_same_geometry_and_gradients(backend):
    """PGSR's neighbour render skips the colours: its depth, normals, alpha and their
    gradients are those of the full render."""
    from eve3d.core.settings import RenderSettings
    from eve3d.gaussians.model import GaussianModel
    from eve3d.gaussians.render import render_model

    means, quats, scales, opacities, colors = random_gaussians(150, seed=4)
    model = GaussianModel.from_points(means.numpy(), colors.numpy(), sh_degree=1)
    model.params.update(quats=quats, log_scales=scales.log())
    model.params = {k: v.double() for k, v in model.params.items()}  # float64: no rounding in the comparison
    cam = pinhole_camera(tilt=0.1)
    settings = RenderSettings(backend=backend, background=(0.2, 0.3, 0.4))
    results = []
    for geometry_only in (False, True):
        params = {k: v.detach().clone().requires_grad_() for k, v in model.params.items()}
        out = render_model(GaussianModel(params, 1), cam, settings, geometry_only=geometry_only)
        (out.depth.sum() + out.normal.abs().sum() + out.alpha.sum() + out.distance.sum()).backward()
        results.append((out, {k: params[k].grad for k in ("means", "quats", "log_scales", "logit_opacities")}))
    (full, full_grads), (geometry, geometry_grads) = results
    assert geometry.rgb.shape == (cam.height, cam.width, 0) and full.rgb.shape == (cam.height, cam.width, 3)
    for name in ("depth", "normal", "alpha", "distance"):
        assert torch.equal(getattr(full, name), getattr(geometry, name)), name
    for name, grad in full_grads.items():
        assert grad.abs().max() > 0 and torch.allclose(grad, geometry_grads[name], rtol=1e-10, atol=1e-12), name


def test_flat_gaussian_facing_the_camera_renders_its_plane():
    cam = pinhole_camera(32, 24)
    out = render(*flat_gaussian([0, 0, -1], [0.05, -0.02, 2.0], cam), cam, backend="cpu")
    seen = out.alpha > 0.01
    assert seen.sum() > 100
    torch.testing.assert_close(out.depth[seen], torch.full_like(out.depth[seen], 2.0), rtol=1e-9, atol=1e-9)
    normal = torch.nn.functional.normalize(out.normal[seen], dim=-1)
    torch.testing.assert_close(normal, torch.tensor([0, 0, -1.0], dtype=torch.float64).expand_as(normal))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("sigma_px", [0.2, 0.5, 3.0])
def test_antialiased_mode_compensates_the_dilation(backend, sigma_px):
    """An isotropic Gaussian of screen variance v centred on a pixel: peak alpha o in classic
    mode, o·v/(v + 0.3) in antialiased mode (gsplat's rule)."""
    cam = pinhole_camera(16, 12)
    z = 2.0
    centre = torch.tensor([[(7.5 - cam.cx) * z / cam.fx, (5.5 - cam.cy) * z / cam.fy, z]], dtype=torch.float64)
    scale = sigma_px * z / cam.fx
    args = (centre, torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
            torch.tensor([[scale, scale * cam.fx / cam.fy, 1e-9]], dtype=torch.float64),  # a disc facing the camera
            torch.tensor([0.8], dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64), cam)
    classic = render(*args, backend=backend).alpha[5, 7]
    anti = render(*args, backend=backend, antialiased=True).alpha[5, 7]
    v = sigma_px**2
    assert float(classic) == pytest.approx(0.8, rel=1e-9)
    assert float(anti) == pytest.approx(0.8 * v / (v + 0.3), rel=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("thin", [1e-5, 1e-7, 1e-9])
def test_an_edge_on_disc_gives_finite_gradients_in_antialiased_mode(backend, thin):
    """A disc seen exactly edge-on whose thin axis the flattening loss has taken to ~1e-7 of
    the others: its compensation is 0 in float32, and its gradients must stay finite (a NaN
    there reached the parameters and stayed, unseen by the loss)."""
    cam = pinhole_camera(32, 24, dtype=torch.float32)
    means = torch.tensor([[0.0, 0.0, 2.0]], requires_grad=True)
    quats = torch.tensor([[math.cos(math.pi / 4), 0, math.sin(math.pi / 4), 0]], requires_grad=True)  # normal ⟂ view
    log_scales = torch.tensor([[math.log(0.1), math.log(0.1), math.log(thin)]], requires_grad=True)
    opacities, colors = torch.tensor([0.9], requires_grad=True), torch.rand(1, 3, requires_grad=True)
    out = render(means, quats, log_scales.exp(), opacities, colors, cam, backend=backend, antialiased=True)
    (out.rgb.sum() + out.depth.sum()).backward()
    for p in (means, quats, log_scales, opacities, colors):
        assert torch.isfinite(p.grad).all()


@pytest.mark.parametrize("tilt", [0.0, 0.4])
def test_tilted_flat_gaussian_renders_the_tilted_plane_depth(tilt):
    cam = pinhole_camera(32, 24, tilt=tilt)
    n = torch.nn.functional.normalize(torch.tensor([0.5, -0.3, -1.0], dtype=torch.float64), dim=0)
    center = torch.tensor([0.1, 0.05, 2.2], dtype=torch.float64)
    out = render(*flat_gaussian(n.tolist(), center.tolist(), cam), cam, backend="cpu")
    seen = out.alpha > 0.01
    rays = cam.rays()[seen]
    analytic = (n @ center) / (rays @ n)  # the plane n·X = n·c along X = D·r
    assert seen.sum() > 100 and analytic.std() > 0.05  # really tilted across the footprint
    torch.testing.assert_close(out.depth[seen], analytic, rtol=1e-4, atol=0)


def test_fitting_an_image_by_adam_exceeds_30_db(object_dataset):
    """2k Gaussians learn a 64×48 view of the synthetic object (noise textures, tiles, edges)."""
    torch.manual_seed(0)
    width, height = 64, 48
    cam = pinhole_camera(width, height, dtype=torch.float32)
    photo = Image.open(object_dataset / "images" / "000.png").convert("RGB").resize((width, height), Image.BOX)
    target = torch.from_numpy(np.asarray(photo, dtype=np.float32) / 255)
    n = 2000
    px = torch.rand(n, 2) * torch.tensor([width, height])
    z = 2.0 + 0.1 * torch.rand(n)
    means = torch.stack([(px[:, 0] - cam.cx) / cam.fx * z, (px[:, 1] - cam.cy) / cam.fy * z, z], dim=1)
    params = {
        "means": means.requires_grad_(True),
        "quats": torch.randn(n, 4).requires_grad_(True),
        "log_scales": torch.full((n, 3), math.log(1.2 * z.mean().item() / cam.fx)).requires_grad_(True),
        "logit_opacities": torch.zeros(n).requires_grad_(True),
        "colors": torch.rand(n, 3).requires_grad_(True),
    }
    lrs = {"means": 1e-3, "quats": 1e-2, "log_scales": 1e-2, "logit_opacities": 5e-2, "colors": 2e-2}
    opt = torch.optim.Adam([{"params": [p], "lr": lrs[k]} for k, p in params.items()])
    for _ in range(300):
        out = render(params["means"], params["quats"], params["log_scales"].exp(),
                     torch.sigmoid(params["logit_opacities"]), params["colors"], cam, backend="cpu")
        loss = (out.rgb - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    psnr = -10 * math.log10(((out.rgb.detach() - target) ** 2).mean().item())
    print(f"PSNR after 300 steps: {psnr:.2f} dB")
    assert psnr > 30
