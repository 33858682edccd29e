"""eve3d.gaussians.render.cpu: the fused C++ projection against finite differences and its PyTorch reference."""
import math

import pytest
import torch

from eve3d.gaussians.render import cpu
from eve3d.gaussians.render.projection import CameraTensors, project_gaussians

NEAR = 0.01


def camera(dtype=torch.float64) -> CameraTensors:
    """A rotated, translated 160×120 camera with an off-centre principal point."""
    c, s = math.cos(0.3), math.sin(0.3)
    yaw = torch.tensor([[c, 0, -s], [0, 1, 0], [s, 0, c]], dtype=torch.float64)
    c, s = math.cos(0.2), math.sin(0.2)
    pitch = torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=torch.float64)
    return CameraTensors((pitch @ yaw).to(dtype), torch.tensor([0.1, -0.2, 0.5], dtype=dtype),
                         180.0, 189.0, 81.3, 58.8, 160, 120)


def gaussians(cam: CameraTensors, u: torch.Tensor, z: torch.Tensor, scales: torch.Tensor,
              g: torch.Generator) -> tuple[torch.Tensor, ...]:
    """Gaussians at image fractions ``u`` (N, 2) and camera depths ``z`` (N,), with random
    rotations (quaternions of random norm) and opacities; world-space means."""
    n = len(z)
    x = (u[:, 0] * cam.width - cam.cx) / cam.fx * z
    y = (u[:, 1] * cam.height - cam.cy) / cam.fy * z
    means = (torch.stack([x, y, z], -1) - cam.t) @ cam.R  # R⁻¹ (x_c − t)
    quats = torch.randn(n, 4, generator=g, dtype=z.dtype) * (0.5 + torch.rand(n, 1, generator=g, dtype=z.dtype))
    return means, quats, scales, 0.05 + 0.9 * torch.rand(n, generator=g, dtype=z.dtype)


def gradcheck_scene() -> tuple[torch.Tensor, ...]:
    """A few dozen Gaussians: ordinary ones, some beyond the image edges (inside and well
    outside the tangent clamp), thin discs and needles, sub-pixel ones, one behind the near
    plane; then those within reach of a kink (clamp limits, the facing sign, the
    compensation floor, z = near) dropped, since finite differences are meaningless there."""
    g = torch.Generator().manual_seed(7)
    cam = camera()

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=torch.float64)

    u = torch.cat([0.1 + 0.8 * rand(24, 2),
                   torch.tensor([[-0.1, 0.5], [1.1, 0.3], [0.4, -0.1], [0.6, 1.1], [-0.4, 0.5], [0.5, 1.4]]),
                   0.2 + 0.6 * rand(10, 2)])
    z = torch.cat([1.5 + 2.5 * rand(30), 1.5 + 2.5 * rand(9), torch.tensor([0.005])])
    s = torch.exp(math.log(0.02) + (math.log(0.3) - math.log(0.02)) * rand(40, 3))
    s[30:33] *= torch.tensor([1.0, 0.8, 0.01])  # thin discs
    s[33:36] *= torch.tensor([1.0, 0.011, 0.01])  # needles
    s[36:39] = 0.004 * (1 + rand(3, 3))  # sub-pixel
    means, quats, scales, opacities = gaussians(cam, u, z, s, g)

    with torch.no_grad():
        proj, _, normals, distances = project_gaussians(means, quats, scales, opacities, cam, NEAR)
        mc = means @ cam.R.T + cam.t
        zs = mc[:, 2].clamp_min(NEAR)
        tangent_margin = torch.cat([
            (mc[:, 0] / zs - lim).abs() for lim in (-(cam.cx / cam.fx + 0.15 * cam.width / cam.fx),
                                                    (cam.width - cam.cx) / cam.fx + 0.15 * cam.width / cam.fx)] + [
            (mc[:, 1] / zs - lim).abs() for lim in (-(cam.cy / cam.fy + 0.15 * cam.height / cam.fy),
                                                    (cam.height - cam.cy) / cam.fy + 0.15 * cam.height / cam.fy)]
        ).reshape(4, -1).min(0).values
        sorted_scales = scales.sort(-1).values
        keep = ((tangent_margin > 1e-3) & (distances / mc.norm(dim=-1) > 0.02)
                & (proj.compensation > 1e-4) & ((mc[:, 2] - NEAR).abs() > 1e-3)
                & (sorted_scales[:, 1] > 1.01 * sorted_scales[:, 0]))
    assert keep.sum() >= 32 and keep[24:30].sum() >= 5 and keep[30:39].sum() >= 7 and keep[39]
    return tuple(x[keep].clone() for x in (means, quats, scales, opacities))


def fused_outputs(means, quats, scales, opacities, cam, antialiased):
    """Every differentiable output of the fused projection."""
    proj, opac, normals, distances = cpu.project(means, quats, scales, opacities, cam, NEAR, 1e10, antialiased)
    return proj.means2d, proj.conics, proj.depths, proj.compensation, normals, distances, opac


@pytest.mark.parametrize("antialiased", [False, True])
def test_fused_projection_passes_gradcheck(antialiased):
    cam = camera()
    inputs = [x.requires_grad_(True) for x in gradcheck_scene()]
    assert torch.autograd.gradcheck(lambda *x: fused_outputs(*x, cam, antialiased), inputs, eps=1e-6,
                                    atol=1e-6, rtol=1e-4)


def random_scene(n: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """``n`` Gaussians in and around the view: behind the camera, beyond the image, far
    away, scales 0.01–0.3 (log-uniform), opacities from 0 (some below 1/255: culled)."""
    g = torch.Generator().manual_seed(seed)
    z = 6 * torch.rand(n, generator=g, dtype=torch.float64) - 0.45
    u = torch.rand(n, 2, generator=g, dtype=torch.float64) * 2 - 0.5
    scales = torch.exp(torch.empty(n, 3, dtype=torch.float64).uniform_(math.log(0.01), math.log(0.3), generator=g))
    means, quats, scales, _ = gaussians(camera(), u, z, scales, g)
    return means, quats, scales, torch.rand(n, generator=g, dtype=torch.float64)


@pytest.mark.parametrize("antialiased", [False, True])
def test_fused_projection_matches_pytorch_in_float32(antialiased):
    """Outputs and gradients (random weights on every output) agree to 1e-5 (relative, plus
    1e-5 of the largest magnitude), and the radii (culling included) are the same except
    where a ceil lands on the other side of an integer by rounding."""
    params = random_scene(20_000)
    results = []
    for project in (project_gaussians, cpu.project):
        inputs = [x.float().requires_grad_(True) for x in params]
        proj, opac, normals, distances = project(*inputs, camera(torch.float32), NEAR, 1e10, antialiased)
        outputs = [proj.means2d, proj.conics, proj.depths, proj.compensation, normals, distances, opac]
        g = torch.Generator().manual_seed(1)
        sum((x * torch.randn(x.shape, generator=g)).sum() for x in outputs).backward()
        results.append((proj.radii, [x.detach() for x in outputs] + [x.grad for x in inputs]))
    (ref_radii, ref), (radii, fused) = results
    assert 5_000 < (ref_radii > 0).any(-1).sum() < 15_000  # culling exercised both ways
    differ = (radii != ref_radii).any(-1)
    assert differ.sum() <= 5 and (radii - ref_radii).abs().max() <= 1
    for x, r in zip(fused, ref):
        torch.testing.assert_close(x, r, rtol=1e-5, atol=1e-5 * r.abs().max().item())


def test_means2d_keeps_its_gradient_for_densification():
    from eve3d.gaussians.render import render

    cam = camera()
    means, quats, scales, opacities = [x.requires_grad_(True) for x in gradcheck_scene()]
    colors = torch.rand(len(means), 3, dtype=torch.float64)
    out = render(means, quats, scales, opacities, colors, cam, backend="cpu")
    out.rgb.sum().backward()
    assert out.means2d_grad is not None and out.means2d_grad[out.visible].abs().sum() > 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_front_to_back_in_cpp_matches_pytorch(dtype):
    """The C++ visible set, depth order (stable, ties included) and pixel boxes are the
    PyTorch reference's, exactly."""
    from eve3d.gaussians.render.projection import front_to_back

    g = torch.Generator().manual_seed(3)
    cam = camera(dtype)
    n = 3000
    u = -0.2 + 1.4 * torch.rand(n, 2, generator=g, dtype=dtype)
    z = torch.cat([0.5 + 5 * torch.rand(n - 500, generator=g, dtype=dtype), torch.full((500,), 2.0, dtype=dtype)])
    s = torch.exp(math.log(0.003) + (math.log(0.3) - math.log(0.003)) * torch.rand(n, 3, generator=g, dtype=dtype))
    means, quats, scales, opacities = gaussians(cam, u, z, s, g)
    proj, _, _, _ = cpu.project(means, quats, scales, opacities, cam, NEAR)
    visible, boxes = front_to_back(proj, cam.width, cam.height)
    visible_cpp, boxes_cpp = cpu.extension().front_to_back(proj.radii, proj.depths, proj.means2d, cam.width,
                                                           cam.height)
    assert 100 < len(visible) < n
    assert torch.equal(visible, visible_cpp)
    assert torch.equal(boxes, boxes_cpp)
