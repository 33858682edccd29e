"""eve3d.gaussians.model: the Gaussians' initialisation (balls or discs), spherical harmonics, PLY I/O."""
import math

import numpy as np
import pytest
import torch

from eve3d.core.errors import Eve3dError
from eve3d.gaussians.model import SH_C0, GaussianModel, eval_sh, sh_coefficients


def random_model(n=50, degree=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    params = {
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.randn(n, 4, generator=g),
        "log_scales": torch.randn(n, 3, generator=g) - 3,
        "logit_opacities": torch.randn(n, generator=g),
        "sh0": torch.randn(n, 1, 3, generator=g),
        "shN": torch.randn(n, sh_coefficients(degree) - 1, 3, generator=g),
    }
    return GaussianModel(params, degree)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_ply_round_trip_is_exact(tmp_path, degree):
    model = random_model(degree=degree)
    model.save_ply(tmp_path / "point_cloud.ply")
    back = GaussianModel.load_ply(tmp_path / "point_cloud.ply")
    assert back.sh_degree == degree
    for name in GaussianModel.NAMES:
        assert torch.equal(back.params[name], model.params[name]), name


def test_ply_is_readable_by_standard_tools(tmp_path):
    import trimesh

    model = random_model(degree=1)
    model.save_ply(tmp_path / "g.ply")
    cloud = trimesh.load(tmp_path / "g.ply")
    np.testing.assert_array_equal(np.asarray(cloud.vertices, dtype=np.float32), model.params["means"].numpy())


def test_truncated_ply_is_refused_with_its_name(tmp_path):
    random_model().save_ply(tmp_path / "g.ply")
    data = (tmp_path / "g.ply").read_bytes()
    (tmp_path / "bad.ply").write_bytes(data[:-100])
    with pytest.raises(Eve3dError, match="bad.ply: truncated"):
        GaussianModel.load_ply(tmp_path / "bad.ply")


def test_sh_basis_is_orthonormal_on_the_sphere():
    """Each coefficient alone gives one real SH basis function; ∫ Y_i Y_j = δ_ij, by a product
    quadrature exact for these degree-≤6 products: Gauss–Legendre in cos θ (4 nodes, exact to
    degree 7) times 8 equally spaced φ (exact to trigonometric degree 7)."""
    z, w = np.polynomial.legendre.leggauss(4)
    phi = np.arange(8) * 2 * math.pi / 8
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    dirs = torch.from_numpy(np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1).reshape(-1, 3))
    weights = torch.from_numpy(np.repeat(w, 8) * 2 * math.pi / 8)
    basis = []
    for i in range(16):
        sh = torch.zeros(len(dirs), 16, 3, dtype=torch.float64)
        sh[:, 0] = 10.0  # keeps the output above the clamp at 0
        sh[:, i] += 1.0
        basis.append(eval_sh(3, sh, dirs)[:, 0] - 0.5 - SH_C0 * 10.0)
    Y = torch.stack(basis, dim=1)
    gram = Y.T @ (weights[:, None] * Y)
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-12, rtol=0)


def test_from_points_scales_by_nearest_neighbours():
    h = 0.05
    grid = np.stack(np.meshgrid(*[np.arange(6) * h] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    model = GaussianModel.from_points(grid, np.full((len(grid), 3), 0.25), sh_degree=2)
    assert len(model) == 216 and model.params["shN"].shape == (216, 8, 3)
    torch.testing.assert_close(model.scales, torch.full((216, 3), h))
    torch.testing.assert_close(model.opacities, torch.full((216,), 0.1))
    colors = model.colors(torch.tensor([1.0, 2.0, 3.0]))
    torch.testing.assert_close(colors, torch.full((216, 3), 0.25))


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
