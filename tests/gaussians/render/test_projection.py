"""eve3d.gaussians.render.projection: quaternions, the EWA projection and its culling, depth order and boxes."""
import math

import numpy as np
import pytest
import torch

from eve3d.gaussians.render.projection import (EPS2D, CameraTensors, front_to_back, project_gaussians,
                                               quat_to_rotmat)


def test_quaternions_give_rotations_whatever_their_norm():
    angle = 0.7
    R = quat_to_rotmat(torch.tensor([[math.cos(angle / 2), 0, 0, math.sin(angle / 2)]], dtype=torch.float64) * 3)[0]
    expected = [[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]]
    torch.testing.assert_close(R, torch.tensor(expected, dtype=torch.float64))
    Rs = quat_to_rotmat(torch.randn(50, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64))
    torch.testing.assert_close(Rs @ Rs.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(50, 3, 3))
    assert torch.allclose(torch.linalg.det(Rs), torch.ones(50, dtype=torch.float64))


def test_isotropic_gaussians_project_to_the_pinhole_and_their_dilated_covariance():
    """Σ2D = σ² J Jᵀ + 0.3 I with J the pinhole's Jacobian at the centre; the conic is its
    inverse; behind the near plane, too transparent or off the image: culled. The planes'
    normals (the shortest axis) face the camera with n·μ = −d."""
    cam = CameraTensors(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), 40.0, 44.0, 16.0, 12.0,
                        32, 24)
    means = torch.tensor([[0.3, -0.2, 2.0], [0.0, 0.0, 4.0], [0.1, 0.1, -1.0], [0.0, 0.0, 3.0], [50.0, 0.0, 2.0]],
                         dtype=torch.float64)
    sigma = 0.05
    scales = torch.tensor([[sigma, sigma, sigma]] * 4 + [[sigma, sigma, 0.001]], dtype=torch.float64)
    opacities = torch.tensor([0.9, 0.9, 0.9, 0.002, 0.9], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 5, dtype=torch.float64)
    proj, opac, normals, distances = project_gaussians(means, quats, scales, opacities, cam)
    assert (proj.radii > 0).all(-1).tolist() == [True, True, False, False, False]
    for i in (0, 1):
        x, y, z = means[i].tolist()
        torch.testing.assert_close(proj.means2d[i], torch.tensor([40 * x / z + 16, 44 * y / z + 12], dtype=torch.float64))
        J = np.array([[40 / z, 0, -40 * x / z**2], [0, 44 / z, -44 * y / z**2]])
        cov = sigma**2 * J @ J.T + EPS2D * np.eye(2)
        inv = np.linalg.inv(cov)
        torch.testing.assert_close(proj.conics[i], torch.tensor([inv[0, 0], inv[0, 1], inv[1, 1]], dtype=torch.float64))
        compensation = math.sqrt(np.linalg.det(cov - EPS2D * np.eye(2)) / np.linalg.det(cov))
        assert float(proj.compensation[i]) == pytest.approx(compensation, rel=1e-12)
        assert proj.depths[i] == z
    assert torch.equal(opac, opacities)  # not antialiased: the opacities as given
    assert ((normals * means).sum(-1) <= 0).all() and torch.allclose((normals * means).sum(-1), -distances)
    assert normals[4].tolist() == [0, 0, -1] and distances[4] == 2  # the disc's thin axis, towards the camera
    anti = project_gaussians(means, quats, scales, opacities, cam, antialiased=True)[1]
    torch.testing.assert_close(anti, opacities * proj.compensation)


def test_the_visible_gaussians_come_nearest_first_with_their_pixel_boxes():
    cam = CameraTensors(torch.eye(3), torch.zeros(3), 40.0, 40.0, 16.0, 12.0, 32, 24)
    means = torch.tensor([[0.0, 0.0, 3.0], [0.0, 0.0, -1.0], [0.2, 0.1, 1.0], [0.0, 0.0, 2.0]])
    scales = torch.full((4, 3), 0.02)
    proj = project_gaussians(means, torch.tensor([[1.0, 0, 0, 0]] * 4), scales, torch.full((4,), 0.8), cam)[0]
    visible, boxes = front_to_back(proj, 32, 24)
    assert visible.tolist() == [2, 3, 0]  # by depth: 1, 2, 3; the one behind the camera culled
    for i, box in zip(visible.tolist(), boxes.tolist()):
        (mx, my), (rx, ry) = proj.means2d[i].tolist(), proj.radii[i].tolist()
        lo = [max(0, math.ceil(mx - rx - 0.5)), max(0, math.ceil(my - ry - 0.5))]
        hi = [min(31, math.floor(mx + rx - 0.5)), min(23, math.floor(my + ry - 0.5))]
        assert box == lo + hi and rx > 0
