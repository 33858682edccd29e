"""eve3d.gaussians.render.cuda: gsplat's rasteriser against ours (skipped without CUDA and gsplat)."""
import math

import pytest
import torch

from eve3d.gaussians.render import render
from eve3d.gaussians.render.projection import CameraTensors
from tests.helpers import pinhole_camera, random_gaussians


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA and gsplat")
def test_cpu_and_gsplat_agree():
    pytest.importorskip("gsplat")
    cam = pinhole_camera(320, 240, dtype=torch.float32)
    g = [x.float() for x in random_gaussians(5000, spread=0.8, scale=(0.005, 0.03))]
    cam_gpu = CameraTensors(cam.R.cuda(), cam.t.cuda(), cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    ref = render(*g, cam, backend="cpu")
    gpu = render(*(x.cuda() for x in g), cam_gpu, backend="gsplat")
    rgb, depth = gpu.rgb.cpu(), gpu.depth.cpu()
    mse = ((rgb - ref.rgb) ** 2).mean().item()
    psnr = -10 * math.log10(max(mse, 1e-20))
    seen = ref.alpha > 0.5
    rel = ((depth - ref.depth).abs() / ref.depth)[seen].median().item()
    print(f"gsplat vs cpu: RGB PSNR {psnr:.1f} dB, median relative depth difference {rel:.2e}")
    assert psnr >= 40
    assert rel <= 1e-3
