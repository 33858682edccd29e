"""The ``hitnet`` stereo backend: HITNet (Tankovich et al., CVPR 2021) exported to ONNX at a
fixed input size, run by onnxruntime from a path alone (``stereo.hitnet.model``).

The contract is HITNet's ONNX export (PINTO's model zoo, 142_HITNET; the ``stereodemo``
project's release ``v0.1-hitnet`` carries the ETH3D files): one input ``[1, 2, H, W]``, the
left and right grey images in [0, 1] stacked left first; one output ``[1, H, W, 1]``, the
left disparity in pixels at the model's size. Each pair is resized to H × W (upsampled too:
on the demo object's pairs 480×640 gave 0.36 % median error against 240×320's 0.67 %) and
the disparity rescaled by the width ratio. The network answers everywhere, a black
background and the sky included, so its confidence is a left–right check through the
mirrored pair; the stage's checks (the pretrained model's alpha, the neighbours' photos) do
the rest.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.photos import warn
from eve3d.core.settings_stereo import HitnetSettings, StereoSettings
from eve3d.priors.matching import grey, left_right_consistent, mirrored, onnx_session

INPUT, OUTPUT = "input", "reference_output_disparity"
WHERE = ("HITNet's ETH3D exports (hitnet_eth3d_HxW.onnx) are the release assets v0.1-hitnet of the stereodemo "
         "project on GitHub (from PINTO's model zoo, 142_HITNET; weights Apache-2.0, Google Research)")
CONTRACT = f"one input {INPUT!r} float32 [1, 2, H, W] (left and right grey in [0, 1]), one output {OUTPUT!r} [1, H, W, 1]"


class HitnetStereo:
    """``matcher(left, right, (min, max))`` for :func:`eve3d.stereo.stereo_priors`."""

    def __init__(self, settings: HitnetSettings):
        self.settings = settings
        if not settings.model:
            raise Eve3dError(f"--backend hitnet needs the model file: set stereo.hitnet.model (--set "
                             f"stereo.hitnet.model=PATH/hitnet_eth3d_480x640.onnx). {WHERE}")
        self.path = Path(settings.model).expanduser()
        if not self.path.is_file():
            raise Eve3dError(f"{self.path}: HITNet model not found (stereo.hitnet.model). {WHERE}")
        try:
            self.session = onnx_session(self.path)
        except Exception as e:  # noqa: BLE001 (onnxruntime raises its own exception types)
            raise Eve3dError(f"{self.path}: not a loadable ONNX model ({type(e).__name__}: {e}); expected HITNet: "
                             f"{CONTRACT}. {WHERE}") from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        shape = inputs[0].shape if len(inputs) == 1 else None
        if (shape is None or inputs[0].name != INPUT or len(shape) != 4 or shape[:2] != [1, 2]
                or not all(isinstance(n, int) for n in shape[2:]) or OUTPUT not in [o.name for o in outputs]):
            found = ", ".join(f"{i.name} {i.shape}" for i in inputs) + " → " + ", ".join(f"{o.name} {o.shape}"
                                                                                       for o in outputs)
            raise Eve3dError(f"{self.path}: not a HITNet export: expected {CONTRACT}; the file has {found}. {WHERE}")
        self.size = (int(shape[2]), int(shape[3]))
        """The model's fixed input (height, width)."""
        self.warned = False

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """The left image's disparity (px at the images' size) of a pair of any size."""
        import cv2

        h, w = left.shape[:2]
        th, tw = self.size

        def resize(im):  # the grey levels in [0, 1], at the model's size
            return cv2.resize(grey(im) / 255, (tw, th), interpolation=cv2.INTER_AREA if tw < w else cv2.INTER_LINEAR)

        pair = np.stack([resize(left), resize(right)])[None]
        out = np.asarray(self.session.run([OUTPUT], {INPUT: np.ascontiguousarray(pair)})[0], np.float32)
        return cv2.resize(out.reshape(th, tw), (w, h), interpolation=cv2.INTER_LINEAR) * np.float32(w / tw)

    def __call__(self, left: np.ndarray, right: np.ndarray, search: tuple[float, float]
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Left disparity (px; 0 where not positive) and its left–right check. The right image
        is shifted right by the search range's start, so the network sees only the range's
        width (``max_disparity`` at its size bounds what it handles)."""
        shift = max(int(np.floor(search[0])), 0)
        width = (search[1] - shift) * self.size[1] / left.shape[1]
        if width > self.settings.max_disparity and not self.warned:
            self.warned = True
            warn(f"{self.path.name}: a pair's disparities reach {width:.0f} px at the model's width of {self.size[1]} px, "
                 f"beyond the {self.settings.max_disparity:g} px it handles (stereo.hitnet.max_disparity): the nearest "
                 f"surfaces may get no depth; an export of a smaller size, or a smaller stereo.target_disparity, narrows it")
        right = np.pad(right, ((0, 0), (shift, 0)) + ((0, 0),) * (right.ndim - 2))[:, :right.shape[1]]
        disp_l = self.disparity(left, right)
        disp_r = mirrored(self.disparity, left, right)
        ok = left_right_consistent(np.maximum(disp_l, 0), np.maximum(disp_r, 0), self.settings.lr_threshold)
        disp = np.where(disp_l > 0, disp_l + shift, 0).astype(np.float32)
        return disp, ok.astype(np.float32)


def matcher(settings: StereoSettings) -> HitnetStereo:
    """The ``hitnet`` row of :data:`eve3d.core.settings_stereo.PRIOR_BACKENDS`."""
    return HitnetStereo(settings.hitnet)
