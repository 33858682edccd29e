"""eve3d.gaussians.render.pairs: the ``torch`` backend's compositing of pixel–Gaussian pairs."""
import math

import numpy as np
import pytest
import torch

from eve3d.gaussians.render import pairs
from eve3d.gaussians.render.projection import ALPHA_MIN, Projected


def _projected(centres, depths):
    """Gaussians on a 5×5 image with conic (1, 0, 1) and boxes covering it all."""
    n = len(centres)
    return Projected(torch.tensor(centres, dtype=torch.float64), torch.tensor([[1.0, 0, 1]] * n, dtype=torch.float64),
                     torch.tensor(depths, dtype=torch.float64), torch.full((n, 2), 2, dtype=torch.int32),
                     torch.ones(n, dtype=torch.float64))


def _brute_force(proj, opacities, features):
    """Per pixel: the Gaussians by depth whose box (centre ± radius) holds the pixel's centre,
    α = min(0.999, o·exp(−σ)), those under 1/255 skipped, stopped before the one that takes
    T to 1e-4 or less. Returns the image, alpha and the number of pairs composited."""
    image, alpha, count = np.zeros((5, 5, features.shape[1])), np.zeros((5, 5)), 0
    for v in range(5):
        for u in range(5):
            T = 1.0
            for i in np.argsort(proj.depths.numpy(), kind="stable"):
                (mx, my), (a, b, c) = proj.means2d[i].tolist(), proj.conics[i].tolist()
                dx, dy = u + 0.5 - mx, v + 0.5 - my
                if abs(dx) > proj.radii[i, 0] or abs(dy) > proj.radii[i, 1]:
                    continue
                al = min(0.999, float(opacities[i]) * math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)))
                if al < ALPHA_MIN:
                    continue
                if T * (1 - al) <= 1e-4:
                    break
                image[v, u] += al * T * features[i].numpy()
                T *= 1 - al
                count += 1
            alpha[v, u] = 1 - T
    return image, alpha, count


def test_pairs_composite_front_to_back_as_the_brute_force_does():
    """Two Gaussians centred on the centre pixel (the nearer listed second), a third beside
    it between them in depth: there α = o for the two, so the colour is o₁f₁ + (1 − o₁)α₃f₃
    + (1 − o₁)(1 − α₃)o₂f₂; everywhere the per-pixel reference; in bands of rows (a pair
    budget of 30) the same."""
    proj = _projected([[2.5, 2.5], [2.5, 2.5], [1.2, 3.7]], [3.0, 2.0, 2.5])
    opacities = torch.tensor([0.5, 0.6, 0.3], dtype=torch.float64)
    features = torch.tensor([[0.0, 1, 0], [1.0, 0, 0], [0, 0, 1.0]], dtype=torch.float64)
    image, alpha, count = pairs.rasterize(proj, opacities, features, 5, 5)
    beside = 0.3 * math.exp(-0.5 * (1.3**2 + 1.2**2))  # (dx, dy) = (1.3, −1.2) from its centre
    torch.testing.assert_close(image[2, 2], torch.tensor([0.6, 0.4 * (1 - beside) * 0.5, 0.4 * beside],
                                                         dtype=torch.float64))
    ref_image, ref_alpha, ref_count = _brute_force(proj, opacities, features)
    np.testing.assert_allclose(image.numpy(), ref_image, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(alpha.numpy(), ref_alpha, rtol=1e-12, atol=1e-15)
    assert count == ref_count == 2 * 25 + 9  # the third's box: 3 × 3 pixels inside the image
    assert pairs._row_bands(pairs.front_to_back(proj, 5, 5)[1], 5, 30) == [(0, 2), (2, 4), (4, 5)]
    banded, banded_alpha, _ = pairs.rasterize(proj, opacities, features, 5, 5, max_pairs=30)
    torch.testing.assert_close(banded, image, rtol=1e-12, atol=1e-15)  # summed in another order
    torch.testing.assert_close(banded_alpha, alpha, rtol=1e-12, atol=1e-15)


def test_compositing_stops_before_the_transmittance_falls_to_1e_4():
    """Three opaque Gaussians (o = 0.995) on one pixel: the first leaves T = 0.005; the second
    would leave 2.5e-5, so it and everything behind it are dropped (gsplat's early stop)."""
    proj = _projected([[2.5, 2.5]] * 3, [1.0, 2.0, 3.0])
    opacities = torch.full((3,), 0.995, dtype=torch.float64)
    features = torch.eye(3, dtype=torch.float64)
    image, alpha, _ = pairs.rasterize(proj, opacities, features, 5, 5)
    torch.testing.assert_close(image[2, 2], torch.tensor([0.995, 0, 0], dtype=torch.float64))
    assert float(alpha[2, 2]) == pytest.approx(0.995, rel=1e-12)
    np.testing.assert_allclose(image.numpy(), _brute_force(proj, opacities, features)[0], rtol=1e-12, atol=1e-15)


def test_the_sum_over_earlier_pairs_restarts_at_each_pixel():
    x = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    pix = torch.tensor([0, 0, 0, 3, 7, 7])
    assert pairs._exclusive_segment_cumsum(x, pix).tolist() == [0, 1, 3, 0, 0, 5]
