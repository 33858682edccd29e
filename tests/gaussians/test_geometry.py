"""eve3d.gaussians.geometry (for now in eve3d.gaussians.losses): normals from depth, fused C++ against PyTorch."""
import pytest
import torch

# these move to eve3d.gaussians.geometry: the import is changed when that move is merged
from eve3d.gaussians.geometry import depth_to_normal
from eve3d.gaussians.render.projection import CameraTensors
from tests.helpers import plane_seen_twice as _plane_views


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
