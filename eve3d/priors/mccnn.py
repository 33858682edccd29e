"""The ``mccnn`` stereo backend: MC-CNN matching costs aggregated by semi-global matching.

MC-CNN fast (Žbontar & LeCun, JMLR 2016) is a small network that describes each pixel's
11×11 grey patch; two patches match as well as their descriptors' cosine. Its weights ship
in CNES's ``mccnn`` wheel (``mc_cnn/weights/``, trained on Middlebury; Apache-2.0). The
wheel is used as a weights source only: its code needs numba, rasterio and h5py, and the
network is five 3×3 convolutions, written here. The costs 1 − cos are aggregated along
8 paths by SGM (Hirschmüller 2008; P1, P2 in cost units), the disparity is the
winner-take-all refined by a parabola through its two neighbours, and confidence is a
left–right check (the right image's disparity from the same costs) gated by texture, as
``sgbm``'s is: aggregation fills a flat black background with matches that mean nothing.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.settings_stereo import MccnnSettings, StereoSettings
from eve3d.priors.matching import grey, left_right_consistent, local_std

PATCH = 11
"""MC-CNN fast's receptive field (five 3×3 convolutions without padding), px."""
WEIGHTS_PACKAGE, WEIGHTS_FILE = "mc_cnn", "weights/mc_cnn_fast_mb_weights.pt"
INSTALL = "pip install --no-deps mccnn==1.4.1"


def packaged_weights() -> Path:
    """The MC-CNN fast Middlebury weights inside the installed ``mccnn`` wheel (found
    without importing the package, whose dependencies are not needed)."""
    spec = importlib.util.find_spec(WEIGHTS_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise Eve3dError(f"the mccnn stereo backend needs the weights of the `mccnn` wheel: run `{INSTALL}` "
                         f"(or set stereo.mccnn.weights to a {Path(WEIGHTS_FILE).name} file)")
    return Path(list(spec.submodule_search_locations)[0]) / WEIGHTS_FILE


def load_network(path: Path):
    """MC-CNN fast as a torch module with the weights in ``path`` (a training checkpoint
    whose ``model`` entry is the state dict, as the wheel ships them, or the state dict)."""
    import torch

    if not path.is_file():
        raise Eve3dError(f"{path}: MC-CNN weights not found (stereo.mccnn.weights; `{INSTALL}` brings them)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 (torch raises several types for a bad file)
        raise Eve3dError(f"{path}: not a torch weights file ({type(e).__name__}: {e})") from None
    state = state.get("model", state) if isinstance(state, dict) else state
    layers = []
    for i in range(5):
        layers += [torch.nn.Conv2d(1 if i == 0 else 64, 64, 3)] + ([torch.nn.ReLU()] if i < 4 else [])
    net = torch.nn.Sequential(*layers)
    try:
        net.load_state_dict({k.removeprefix("conv_blocks."): v for k, v in state.items()})
    except (RuntimeError, AttributeError) as e:
        raise Eve3dError(f"{path}: not MC-CNN fast weights ({str(e).splitlines()[0]})") from None
    return net.eval()


class MccnnStereo:
    """``matcher(left, right, (min, max))`` for :func:`eve3d.stereo.stereo_priors`."""

    def __init__(self, settings: MccnnSettings | None = None, min_texture: float = 0.0, texture_window: int = 5):
        self.settings = settings or MccnnSettings()
        self.texture_window = texture_window
        self.weights = Path(self.settings.weights) if self.settings.weights else packaged_weights()
        self.net = load_network(self.weights)
        self.min_texture = min_texture

    def features(self, image: np.ndarray):
        """(64, H, W) unit descriptors of each pixel's patch; the image is grey, normalised
        to zero mean and unit deviation as in training, and reflected at its border."""
        import torch

        level = grey(image)
        level = (level - level.mean()) / max(float(level.std()), 1e-6)
        x = torch.nn.functional.pad(torch.from_numpy(level)[None, None], (PATCH // 2,) * 4, mode="reflect")
        with torch.no_grad():
            f = self.net(x)[0]
        return torch.nn.functional.normalize(f, dim=0)

    def costs(self, left: np.ndarray, right: np.ndarray, low: int, high: int):
        """(D, H, W) matching costs 1 − cos of the left image's pixels for the disparities
        low..high, and the same of the right image's (the left pixel x matches the right
        pixel x − d); 2, the worst, where the other pixel falls outside the image."""
        import torch

        fl, fr = self.features(left), self.features(right)
        _, h, w = fl.shape
        cost_l, cost_r = torch.full((2, high - low + 1, h, w), 2.0)
        for i, d in enumerate(range(low, high + 1)):
            if d < w:
                cos = (fl[:, :, d:] * fr[:, :, :w - d]).sum(0)
                cost_l[i, :, d:] = 1 - cos
                cost_r[i, :, :w - d] = 1 - cos
        return cost_l, cost_r

    def __call__(self, left: np.ndarray, right: np.ndarray, search: tuple[float, float]
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Left disparity (px, float32; 0 where none) in the range ``search``, and its
        confidence: the right image's disparity confirms it (``lr_threshold``) and the
        pixel's window has texture (``min_texture``)."""
        low, high = max(int(np.floor(search[0])), 0), int(np.ceil(search[1]))
        cost_l, cost_r = self.costs(left, right, low, high)
        # both ≥ low ≥ 0: no negative disparity to clear
        p1, p2 = self.settings.p1, self.settings.p2
        disp_l, disp_r = (winner(semi_global(c, p1, p2)) + np.float32(low) for c in (cost_l, cost_r))
        ok = left_right_consistent(disp_l, disp_r, self.settings.lr_threshold)
        ok &= local_std(left, self.texture_window) >= self.min_texture
        return disp_l, ok.astype(np.float32)


def matcher(settings: StereoSettings) -> MccnnStereo:
    """The ``mccnn`` row of :data:`eve3d.core.settings_stereo.PRIOR_BACKENDS`: ``sgbm``'s texture gate."""
    return MccnnStereo(settings.mccnn, settings.min_texture, settings.block_size)


def winner(total) -> np.ndarray:
    """(H, W) float32: the index of each pixel's least aggregated cost, refined by the
    parabola through it and its two neighbours (sub-pixel)."""
    import torch

    best = total.argmin(0)

    def at(k):
        return total.gather(0, (best + k).clamp(0, len(total) - 1)[None])[0]

    c0, cm, cp = at(0), at(-1), at(1)
    curve = cm - 2 * c0 + cp
    inner = (best > 0) & (best < len(total) - 1) & (curve > 0)
    d = torch.where(inner, best + (cm - cp) / (2 * curve.clamp_min(1e-9)), best.float())
    return d.float().numpy()


PATHS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))
"""SGM's 8 paths as (dy, dx) steps."""


def semi_global(cost, p1: float, p2: float):
    """(D, H, W) costs summed over SGM's 8 paths: along each, L(p, d) = C(p, d) +
    min(L(p−r, d), L(p−r, d±1) + P1, min_k L(p−r, k) + P2) − min_k L(p−r, k)."""
    import torch

    total = torch.zeros_like(cost)
    for dy, dx in PATHS:
        c, vertical = cost, dx == 0
        if vertical:  # a vertical path is a horizontal one on the transposed image
            c, dy, dx = cost.transpose(1, 2), dx, dy
        if dx < 0:  # walk right to left as left to right on the mirrored image
            c = c.flip(2)
        c = c.contiguous()
        out = torch.empty_like(c)
        out[:, :, 0] = c[:, :, 0]
        for x in range(1, c.shape[2]):
            prev = out[:, :, x - 1]
            if dy:  # a diagonal: the predecessor is one row up (dy > 0) or down
                shifted = torch.zeros_like(prev)  # rows without a predecessor start the path afresh
                if dy > 0:
                    shifted[:, 1:] = prev[:, :-1]
                else:
                    shifted[:, :-1] = prev[:, 1:]
                prev = shifted
            low = prev.min(0).values
            step = torch.minimum(prev, low + p2)
            step[1:] = torch.minimum(step[1:], prev[:-1] + p1)
            step[:-1] = torch.minimum(step[:-1], prev[1:] + p1)
            out[:, :, x] = c[:, :, x] + step - low
        if dx < 0:
            out = out.flip(2)
        if vertical:
            out = out.transpose(1, 2)
        total += out
    return total
