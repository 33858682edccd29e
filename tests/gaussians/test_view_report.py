"""eve3d.gaussians.view_report: a model's PSNR and SSIM over views, and its previews."""
import math

import numpy as np
import torch

from eve3d.core.fileio import read_image
from eve3d.core.scene import Camera
from eve3d.core.settings import RenderSettings
from eve3d.gaussians.model import GaussianModel
from eve3d.gaussians.render.projection import CameraTensors
from eve3d.gaussians.view_report import view_metrics, write_previews
from eve3d.gaussians.views import View


def test_metrics_are_the_means_over_the_views_and_the_pairs_are_written(tmp_path):
    """Four Gaussians behind the camera: every view renders the background. A photo of the
    background scores PSNR 120 dB (the 1e-12 floor) and SSIM 1; a grey one the PSNR of its
    difference; the metrics are their means; each view's render | photo is written."""
    background = (0.2, 0.3, 0.4)
    settings = RenderSettings(background=background, backend="cpu")
    model = GaussianModel.from_points(np.array([[0.0, 0, -5], [0.1, 0, -5], [0, 0.1, -5], [0.1, 0.1, -5]]), None, 0)
    cam = Camera("v.png", 16, 12, np.array([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]]), np.eye(3), np.zeros(3))
    images = [torch.tensor(background).expand(12, 16, 3).clone(), torch.full((12, 16, 3), 0.5)]
    views = [View(i, Camera(f"{i}.png", 16, 12, cam.K, cam.R, cam.t), CameraTensors.from_camera(cam), image)
             for i, image in enumerate(images)]
    grey = 10 * math.log10(3 / (0.3**2 + 0.2**2 + 0.1**2))  # 13.31 dB
    assert view_metrics(model, views, [0], settings)["psnr"] == 120.0
    assert view_metrics(model, views, [0], settings)["ssim"] == 1.0
    m = view_metrics(model, views, [0, 1], settings, tmp_path / "held_out")
    assert m["views"] == 2 and abs(m["psnr"] - (120 + grey) / 2) < 1e-4 and 0 < m["ssim"] < 1
    pair = read_image(tmp_path / "held_out/1.png")
    assert pair.shape == (12, 32, 3)
    assert np.all(pair[:, :16] == np.round(np.array(background) * 255)) and np.all(pair[:, 16:] == 128)
    assert view_metrics(model, views, [], settings) == {}
    write_previews(model, views, settings, 1, tmp_path / "previews")
    assert sorted(p.name for p in (tmp_path / "previews").iterdir()) == ["0.depth.png", "0.normal.png", "0.rgb.png"]
