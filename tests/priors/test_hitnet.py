"""The ``hitnet`` backend: HITNet's ETH3D weights as ONNX, read by path from the shared models
folder (``hitnet_model``; skipped where the files are not on the machine)."""
import numpy as np
import pytest
import torch

from eve3d.core.scene import Eve3dError
from eve3d.core.settings import HitnetSettings
from eve3d.priors.hitnet import HitnetStereo
from tests.helpers import hitnet_model, plane_pair

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::torch.jit.TracerWarning")


def plane_depth(net: HitnetStereo, tilt: float, disparity: float, search: tuple[float, float]):
    """HITNet's depth of an exact pair of a slanted textured plane (320×240 with a 48-column
    margin, as the stage pads a pair), its confidence, and the exact depth."""
    left, right, exact, f, baseline = plane_pair(tilt, disparity)
    padded = np.pad(left, ((0, 0), (48, 0), (0, 0)))
    disp, confidence = (m[:, 48:] for m in net(padded, right, search))
    return np.where(disp > 0, f * baseline / np.maximum(disp, 1e-6), 0), confidence >= 0.5, exact, disp


def test_hitnet_measures_a_slanted_plane_to_a_fraction_of_a_pixel(capsys):
    """On an exact pair (disparities 15–36 px, the plane tilted 50°), at the 480×640 export:
    measured median error 0.26 % of depth (0.07 px), every pixel confident. Searching from
    15 px (the right image shifted by 15 px first) gives the same disparities. A range wider
    than the network handles at its size is told."""
    net = HitnetStereo(HitnetSettings(model=str(hitnet_model("480x640"))))
    assert net.size == (480, 640)
    depth, confident, exact, disp = plane_depth(net, 50, 25.6, (0, 64))
    use = confident & (exact > 0)
    error = (depth[use] - exact[use]) / exact[use]
    print(f"density {use.mean():.3f}, median |error| {np.median(np.abs(error)) * 100:.3f} %")
    assert use.mean() > 0.98
    assert np.median(np.abs(error)) < 0.004 and abs(np.median(error)) < 0.003
    assert np.mean(np.abs(error) > 0.05) < 0.005
    _, shifted_confident, _, shifted = plane_depth(net, 50, 25.6, (15.0, 64))
    both = use & shifted_confident
    assert both.mean() > 0.97 and np.median(np.abs(shifted[both] - disp[both])) < 0.1
    assert "warning" not in capsys.readouterr().err
    tiny = np.zeros((48, 64, 3), np.uint8)
    net(tiny, tiny, (0, 20))  # 20 px of 64 are 200 px at the model's 640
    assert "reach 200 px at the model's width of 640 px, beyond the 120 px it handles" in capsys.readouterr().err


def test_a_missing_or_foreign_model_is_named_with_where_the_files_come_from(tmp_path):
    with pytest.raises(Eve3dError, match="needs the model file: set stereo.hitnet.model.*stereodemo"):
        HitnetStereo(HitnetSettings())
    missing = tmp_path / "hitnet_eth3d_480x640.onnx"
    with pytest.raises(Eve3dError, match=f"{missing}: HITNet model not found.*v0.1-hitnet"):
        HitnetStereo(HitnetSettings(model=str(missing)))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(Eve3dError, match="junk.onnx: not a loadable ONNX model.*expected HITNet: one input 'input'"):
        HitnetStereo(HitnetSettings(model=str(junk)))
    rgb = tmp_path / "rgb.onnx"  # a network with HITNet's names but colour input: another contract
    torch.onnx.export(torch.nn.Conv2d(3, 1, 1), (torch.rand(1, 3, 24, 32),), str(rgb), input_names=["input"],
                      output_names=["reference_output_disparity"], dynamo=False)
    with pytest.raises(Eve3dError, match=r"rgb.onnx: not a HITNet export: expected .*\[1, 2, H, W\].*the file has "
                                         r"input \[1, 3, 24, 32\]"):
        HitnetStereo(HitnetSettings(model=str(rgb)))
