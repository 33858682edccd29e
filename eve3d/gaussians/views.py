"""A scene's views as training sees them: each camera at the training resolution with its
photo as a tensor, split into training and held-out views.

Shared by the training stages and by everything that scores a trained model against the
photos the same way (the nvs protocol), so that both read, resize and split the images alike.
"""
from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
import torch
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.photos import read_view
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings import RenderSettings, TrainSettings
from eve3d.gaussians.losses import edge_weight
from eve3d.gaussians.render.projection import CameraTensors


@dataclass
class View:
    """One training image at the training resolution."""

    index: int
    camera: Camera
    cam: CameraTensors
    image: torch.Tensor
    """(H, W, 3) float in [0, 1]."""
    beyond: torch.Tensor | None = None
    """(H, W) bool: the pixels beyond the measured scene, where only the environment can be
    seen (``eve3d.gaussians.environment.scene_environment``); None when not known."""

    @functools.cached_property
    def grey(self) -> torch.Tensor:
        """(H, W, 1) the image's grey level (mean of the channels), for the NCC patches."""
        return self.image.mean(-1, keepdim=True)

    @functools.cached_property
    def edge_weight(self) -> torch.Tensor:
        """(H, W) the depth–normal loss's relaxation at the image's edges (:func:`edge_weight`),
        computed once: the image does not change."""
        return edge_weight(self.image)

    @functools.cached_property
    def contrast(self) -> torch.Tensor:
        """(H, W) the grey level's standard deviation over 5×5 pixels (a plain wall's is near 0)."""
        grey = self.grey[..., 0][None, None]
        mean = torch.nn.functional.avg_pool2d(grey, 5, 1, 2, count_include_pad=False)
        square = torch.nn.functional.avg_pool2d(grey * grey, 5, 1, 2, count_include_pad=False)
        return (square - mean * mean).clamp_min(0).sqrt()[0, 0]


def pick_device(setting: str) -> torch.device:
    """The device of a ``device`` setting: ``auto`` = CUDA when present, else CPU."""
    want_cuda = setting == "cuda" or (setting == "auto" and torch.cuda.is_available())
    return torch.device("cuda" if want_cuda else "cpu")


def model_device(rendering: RenderSettings) -> torch.device:
    """Where a model read from disk goes to be rendered as ``rendering`` says: the GPU for
    ``gsplat``, and for ``auto`` where there is one (``auto`` then picks gsplat); else the CPU."""
    return pick_device({"gsplat": "cuda", "auto": "auto"}.get(rendering.backend, "cpu"))


def load_views(scene: Scene, rendering: RenderSettings, device: torch.device,
               tone: np.ndarray | None = None) -> list[View]:
    """Every camera of ``scene`` at the training size (``rendering.sized``) with its photo
    at that size (``read_view``: from the image pyramid when there is one), its grey
    levels mapped through ``tone`` ((256,) uint8) when given."""
    views = []
    for i, cam in enumerate(tqdm(scene.cameras, desc="loading images", unit="img", leave=False)):
        if cam.image_path is None:
            raise Eve3dError(f"{scene.root}: view {cam.view_id} has no image")
        small = rendering.sized(cam)
        rgb = read_view(small)
        if tone is not None:
            rgb = tone[rgb]
        image = torch.from_numpy(rgb).to(device=device, dtype=torch.float32) / 255.0
        views.append(View(i, small, CameraTensors.from_camera(small, torch.float32, device), image))
    return views


def split_views(n: int, holdout: int) -> tuple[list[int], list[int]]:
    """(training, held-out) view indices: every ``holdout``-th view is held out."""
    test = [i for i in range(n) if holdout and i % holdout == 0]
    return [i for i in range(n) if i not in test], test


@dataclass
class Views:
    """Every view of a scene (indexed as ``scene.cameras``) and which of them train."""

    items: list[View]
    train_ids: list[int]
    test_ids: list[int]
    coarse: tuple[int, Views] | None = None
    """(until, views): coarse to fine, the smaller views the steps before ``until`` train on."""

    def at(self, i: int, step: int) -> View:
        """View ``i`` as step ``step`` trains on it."""
        return (self.coarse[1] if self.coarse and step < self.coarse[0] else self)[i]

    @classmethod
    def load(cls, scene: Scene, rendering: RenderSettings, holdout: int, device: torch.device,
             tone: np.ndarray | None = None) -> "Views":
        """:func:`load_views`, split by :func:`split_views`; refuses a split that leaves
        nothing to train on."""
        views = load_views(scene, rendering, device, tone)
        train_ids, test_ids = split_views(len(views), holdout)
        if not train_ids:
            raise Eve3dError(f"{scene.root}: no training views left after holding out every {holdout}th")
        return cls(views, train_ids, test_ids)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> View:
        return self.items[i]

    def __iter__(self) -> Iterator[View]:
        return iter(self.items)

    @property
    def cameras(self) -> list[Camera]:
        """The cameras at the training resolution."""
        return [v.camera for v in self.items]

    @property
    def images(self) -> list[torch.Tensor]:
        """The photos at the training resolution."""
        return [v.image for v in self.items]


def coarse_views(scene: Scene, settings: TrainSettings, device: torch.device,
                 tone: np.ndarray | None = None) -> tuple[int, Views] | None:
    """Coarse to fine (:attr:`Views.coarse`): every view at most ``settings.coarse_side`` px a
    side, its photo read at that size (from the pyramid); None when ``coarse_until`` is 0 or
    no view is trained larger. Densification's 2D gradients are in NDC units, so its
    thresholds hold at either size."""
    if not settings.coarse_until:
        return None
    side = settings.coarse_side
    coarse = replace(settings, max_side=min(settings.max_side, side) if settings.max_side else side)
    if all(coarse.scale(c) >= settings.scale(c) for c in scene.cameras):
        return None
    until = round(settings.coarse_until * settings.iterations)
    return until, Views.load(scene, coarse, settings.holdout, device, tone)
