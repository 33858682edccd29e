"""The ``onnx`` stereo backend: any stereo network exported to ONNX, run by onnxruntime.

A small spec says how to feed it (config ``stereo.onnx``): input and output names, layout,
value scale and normalisation, and either a fixed input size (images resized, disparity
rescaled by the width ratio) or a divisor (images padded at the bottom/right to a multiple,
and to the network's smallest input if it has one, output cropped). FoundationStereo's
export, for example: inputs ``left``, ``right`` 1×3×H×W RGB 0..255, output ``disp``: the
defaults below. The CUDA provider is used when onnxruntime has it. Confidence comes from a
left–right check, the right image's disparity from the mirrored pair.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.settings_stereo import OnnxSpec, StereoSettings
from eve3d.priors.matching import left_right_consistent, mirrored, onnx_session


class OnnxStereo:
    """A loaded network and its spec; ``disparity(left, right)`` → (H, W) float32 pixels."""

    def __init__(self, spec: OnnxSpec):
        self.spec = spec
        path = Path(spec.model)
        if not path.is_file():
            raise Eve3dError(f"{path}: ONNX stereo model not found (stereo.onnx.model)")
        try:
            self.session = onnx_session(path)
        except Exception as e:  # noqa: BLE001 (onnxruntime raises its own exception types)
            raise Eve3dError(f"{path}: not a loadable ONNX model ({type(e).__name__}: {e})") from None
        inputs = {i.name: i.shape for i in self.session.get_inputs()}
        outputs = [o.name for o in self.session.get_outputs()]
        want = [spec.left, spec.right]
        if sorted(want) != sorted(inputs) or spec.output not in outputs:
            raise Eve3dError(f"{path}: the spec expects inputs {want} and output {spec.output!r}; the model has "
                             f"inputs {list(inputs)} {list(inputs.values())} and outputs {outputs}")
        if spec.layout not in ("NCHW", "NHWC"):
            raise Eve3dError(f"stereo.onnx.layout: {spec.layout!r} is not NCHW or NHWC")
        self.input_shape = inputs[spec.left]
        fixed = [d if isinstance(d, int) else None for d in self.input_shape]
        hw = (fixed[2], fixed[3]) if spec.layout == "NCHW" else (fixed[1], fixed[2])
        if len(self.input_shape) != 4 or (None not in hw and spec.size is not None and tuple(spec.size) != hw):
            raise Eve3dError(f"{path}: input {spec.left!r} has shape {self.input_shape}; the spec expects "
                             f"1×3×H×W ({spec.layout}) with H×W = {spec.size or 'any'}")
        if None not in hw and spec.size is None:
            raise Eve3dError(f"{path}: input {spec.left!r} has the fixed shape {self.input_shape}; set "
                             f"stereo.onnx.size: [{hw[0]}, {hw[1]}] so images are resized to it")

    def _tensor(self, image: np.ndarray) -> np.ndarray:
        spec = self.spec
        x = (image.astype(np.float32) / 255.0 * spec.scale - np.float32(spec.mean)) / np.float32(spec.std)
        x = x[None]
        return np.ascontiguousarray(x.transpose(0, 3, 1, 2) if spec.layout == "NCHW" else x, dtype=np.float32)

    def _output(self, out: np.ndarray) -> np.ndarray:
        out = np.asarray(out, dtype=np.float32)
        if out.ndim == 4:  # drop the batch axis
            out = out[0]
        if out.ndim == 3:  # (C, H, W), (H, W, C) by the layout, or (1, H, W)
            channel_first = self.spec.layout == "NCHW" or out.shape[0] == 1
            out = out[self.spec.channel] if channel_first else out[..., self.spec.channel]
        if out.ndim != 2:
            raise Eve3dError(f"{self.spec.model}: output {self.spec.output!r} has shape {out.shape}; expected a map")
        return out * np.float32(self.spec.sign)

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        import cv2

        spec = self.spec
        h, w = left.shape[:2]
        if spec.size is not None:
            th, tw = spec.size

            def resize(im):
                return cv2.resize(im, (tw, th), interpolation=cv2.INTER_AREA if tw < w else cv2.INTER_LINEAR)

            out = self._run(resize(left), resize(right))
            return cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR) * np.float32(w / tw)
        ph, pw = (max(n, spec.min_size) + -max(n, spec.min_size) % spec.divisor - n for n in (h, w))

        def pad(im):
            return np.pad(im, ((0, ph), (0, pw), (0, 0)), mode="edge")

        return self._run(pad(left), pad(right))[:h, :w]

    def _run(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        feeds = {self.spec.left: self._tensor(left), self.spec.right: self._tensor(right)}
        try:
            out = self.session.run([self.spec.output], feeds)[0]
        except Exception as e:  # noqa: BLE001
            raise Eve3dError(f"{self.spec.model}: inference failed on inputs of shape "
                             f"{feeds[self.spec.left].shape} (model expects {self.input_shape}): {e}") from None
        return self._output(out)

    def __call__(self, left: np.ndarray, right: np.ndarray, search: tuple[float, float] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Left disparity (0 where not positive) and the left–right check, for
        :func:`eve3d.stereo.stereo_priors`."""
        disp_l = self.disparity(left, right)
        disp_r = mirrored(self.disparity, left, right)
        disp_l = np.where(disp_l > 0, disp_l, 0).astype(np.float32)
        return disp_l, left_right_consistent(disp_l, np.maximum(disp_r, 0), self.spec.lr_threshold)


def matcher(settings: StereoSettings) -> OnnxStereo:
    """The ``onnx`` row of :data:`eve3d.core.settings_stereo.PRIOR_BACKENDS`."""
    if not settings.onnx.model:
        raise Eve3dError("--backend onnx needs the model spec: stereo.onnx in --config, or --set stereo.onnx.model=FILE")
    return OnnxStereo(settings.onnx)
