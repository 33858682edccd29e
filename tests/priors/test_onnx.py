"""eve3d.priors.onnx: the ONNX stereo backend, with small networks the test builds and exports itself."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from eve3d.core.errors import Eve3dError
from eve3d.core.maps import load_maps
from eve3d.core.settings_stereo import OnnxSpec
from eve3d.priors.onnx import OnnxStereo
from eve3d.stereo import stereo_priors
from tests.helpers import shifted_pair, stereo_scene, virtual_pairs

# torch's TorchScript-based exporter (no onnxscript needed) warns that it is the legacy one.
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::torch.jit.TracerWarning",
                                        "ignore:Constant folding:UserWarning")


class CostVolume(torch.nn.Module):
    """A tiny cost-volume stereo network: L1 costs over disparities 0..D−1, box-filtered,
    soft-argmin; ``sign`` −1 mimics networks that output x_right − x_left."""

    def __init__(self, max_disparity: int = 12, sign: float = 1.0):
        super().__init__()
        self.max_disparity, self.sign = max_disparity, sign

    def forward(self, left, right):
        width = left.shape[-1]
        costs = [-(left - F.pad(right, (d, 0))[..., :width]).abs().mean(1, keepdim=True)
                 for d in range(self.max_disparity)]
        cost = F.avg_pool2d(torch.cat(costs, 1), 5, stride=1, padding=2)
        prob = torch.softmax(cost * 2.0, dim=1)
        disparities = torch.arange(self.max_disparity, dtype=left.dtype).reshape(1, -1, 1, 1)
        return self.sign * (prob * disparities).sum(1, keepdim=True)


class Echo(torch.nn.Module):
    """Returns the green channel of the left input (NHWC): exposes exactly what was fed."""

    def forward(self, left, right):
        return left[..., 1] + 0 * right[..., 1]


class PaddedSize(torch.nn.Module):
    """Returns 1000 × the input height + its width everywhere: the size the network was fed."""

    def forward(self, left, right):
        return 0 * (left[:, :1] + right[:, :1]) + left.shape[2] * 1000 + left.shape[3]


def export(model, path, shape, dynamic: bool, names=("left", "right"), output="disp"):
    args = (torch.rand(*shape), torch.rand(*shape))
    axes = {n: {0: "batch", 2: "height", 3: "width"} for n in names} if dynamic else None
    torch.onnx.export(model, args, str(path), input_names=list(names), output_names=[output], dynamic_axes=axes,
                      dynamo=False)
    return path


def test_divisor_model_pads_crops_and_applies_the_sign(tmp_path):
    left, right = shifted_pair(4, h=45, w=61)  # not a multiple of 8: padded to 48×64, then cropped
    for sign in (1.0, -1.0):
        model = export(CostVolume(sign=sign), tmp_path / f"cv{sign}.onnx", (1, 3, 16, 24), dynamic=True)
        net = OnnxStereo(OnnxSpec(model=str(model), divisor=8, sign=sign))
        disp = net.disparity(left, right)
        assert disp.shape == (45, 61)
        np.testing.assert_allclose(np.median(disp[8:-8, 16:-8]), 4.0, atol=0.02)
        d, confident = net(left, right)
        assert confident[8:-8, 16:-8].mean() > 0.9


def test_divisor_model_is_padded_to_its_minimum_size(tmp_path):
    model = export(PaddedSize(), tmp_path / "size.onnx", (1, 3, 16, 24), dynamic=True)
    image = np.zeros((45, 61, 3), np.uint8)
    for spec, fed in [(dict(divisor=8), (48, 64)), (dict(divisor=8, min_size=56), (56, 64)),
                      (dict(divisor=16, min_size=50), (64, 64))]:  # at least min_size, still a multiple
        out = OnnxStereo(OnnxSpec(model=str(model), **spec)).disparity(image, image)
        assert out.shape == (45, 61) and np.all(out == fed[0] * 1000 + fed[1]), spec


def test_fixed_size_model_resizes_and_rescales_disparity(tmp_path):
    model = export(CostVolume(), tmp_path / "fixed.onnx", (1, 3, 32, 48), dynamic=False)
    left, right = shifted_pair(8, h=64, w=96)  # the network sees 32×48, where the disparity is 4
    with pytest.raises(Eve3dError, match=r"fixed shape \[1, 3, 32, 48\].*size: \[32, 48\]"):
        OnnxStereo(OnnxSpec(model=str(model)))
    disp = OnnxStereo(OnnxSpec(model=str(model), size=(32, 48))).disparity(left, right)
    assert disp.shape == (64, 96)
    np.testing.assert_allclose(np.median(disp[16:-16, 24:-16]), 8.0, atol=0.1)


def test_scale_normalisation_and_layout_come_back_exact(tmp_path):
    model = export(Echo(), tmp_path / "echo.onnx", (1, 8, 8, 3), dynamic=False)
    image = np.random.default_rng(0).integers(0, 256, (8, 8, 3)).astype(np.uint8)
    spec = OnnxSpec(model=str(model), layout="NHWC", size=(8, 8), scale=1.0, mean=(0.1, 0.4, 0.2),
                    std=(0.5, 0.25, 0.5))
    out = OnnxStereo(spec).disparity(image, image)
    np.testing.assert_allclose(out, (image[..., 1] / 255.0 - 0.4) / 0.25, rtol=1e-6, atol=1e-6)


def test_bad_models_are_named(tmp_path):
    with pytest.raises(Eve3dError, match="nothing.onnx: ONNX stereo model not found"):
        OnnxStereo(OnnxSpec(model=str(tmp_path / "nothing.onnx")))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(Eve3dError, match="junk.onnx: not a loadable ONNX model"):
        OnnxStereo(OnnxSpec(model=str(junk)))
    other = export(CostVolume(), tmp_path / "names.onnx", (1, 3, 16, 24), dynamic=True, names=("img0", "img1"))
    with pytest.raises(Eve3dError, match=r"expects inputs \['left', 'right'\].*has inputs \['img0', 'img1'\] "
                                         r"\[\['batch', 3, 'height', 'width'\]"):
        OnnxStereo(OnnxSpec(model=str(other)))


def test_onnx_priors_through_the_stereo_stage(tmp_path):
    scene, write_pairs = stereo_scene(tmp_path, 6, baseline=0.3)
    write_pairs()
    model = export(CostVolume(), tmp_path / "cv.onnx", (1, 3, 16, 24), dynamic=True)
    stereo_priors(scene, tmp_path / "stereo", tmp_path / "priors", OnnxStereo(OnnxSpec(model=str(model), divisor=8)),
                  "onnx", pairs=virtual_pairs())
    maps = load_maps(tmp_path / "priors/v.npz")
    sure = maps["confidence"] > 0.5
    assert sure.mean() > 0.5
    np.testing.assert_allclose(np.median(maps["depth"][sure]), 100 * 0.3 / 6, rtol=2e-3)
