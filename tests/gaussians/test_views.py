"""eve3d.gaussians.views: where the training views and a model read from disk go."""
import torch

from eve3d.core.settings import RenderSettings
from eve3d.gaussians.views import model_device


def test_a_model_read_from_disk_goes_where_its_backend_renders():
    """stereo-render reads the pretrained model from its PLY: gsplat renders it only on the GPU."""
    assert model_device(RenderSettings(backend="cpu")).type == "cpu"
    assert model_device(RenderSettings(backend="torch")).type == "cpu"
    assert model_device(RenderSettings(backend="gsplat")).type == "cuda"
    assert model_device(RenderSettings(backend="auto")).type == ("cuda" if torch.cuda.is_available() else "cpu")
