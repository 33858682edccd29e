"""The environment at infinity: a learnable colour per direction, behind the Gaussians.

A photo's sky or far background has no parallax: its colour depends on the ray's direction
alone. The environment is that colour, an equirectangular (latitude–longitude) map whose
pole is the scene's up (the mean of the cameras' up directions, so the horizon lies on the
equator, where the map is finest). A view composites C + (1 − α)·env(d), d the world
direction of each pixel's ray; a constant background is the map of one colour. Since only
the direction enters, the virtual right view of a stereo pair (the same rotation) sees the
environment at zero disparity.

The map holds the logits of its colours, as 3DGS holds opacities: a colour stays within
[0, 1], so the map cannot turn dark to cancel a bright Gaussian painted in front of a dark
sky (unbounded, it did: the Gaussians then covered a black background whole).

Saved beside a model's PLY as ``environment.npz`` (``logits`` (h, w, 3) float32, ``frame``
(3, 3): rows the map's x, y and up axes in world coordinates, and ``seen`` (h, w) bool where
known: the texels a training photo showed) with ``environment.png``, its colours.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path, write_image
from eve3d.core.hull import measured_hull
from eve3d.core.scene import Scene
from eve3d.core.settings import TrainSettings
from eve3d.core.timing import phase
from eve3d.gaussians.render.projection import T_MIN, CameraTensors

if TYPE_CHECKING:
    from eve3d.gaussians.views import Views

PREVIEW_SUFFIX = ".png"
FILL = 2
"""Texels a new map fills from the nearest one a ray beyond the scene fell in: the small gaps
between the training views' rays (a held-out view's sky)."""


def up_frame(rotations: np.ndarray) -> np.ndarray:
    """(3, 3) world-to-map rotation whose third row is the cameras' mean up direction
    (−y of each world-to-camera rotation ``rotations`` (N, 3, 3)); world z where they cancel."""
    up = -np.asarray(rotations)[:, 1, :].mean(axis=0)
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-6 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, up)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(up, x), up])


def logit(colour: torch.Tensor) -> torch.Tensor:
    """The logits of colours in [0, 1] (clipped to 1e-4 of either end: black is −9.2)."""
    colour = colour.clamp(1e-4, 1 - 1e-4)
    return torch.log(colour / (1 - colour))


class Environment:
    """Colour at infinity by direction (module docstring). ``logits`` (h, w, 3): the logits of
    the texels' colours, row 0 the map's zenith, columns the azimuth from −π to π; ``frame``
    (3, 3) world-to-map rotation; ``seen`` (h, w) bool: the texels a training photo showed
    beyond the scene (None: all of them)."""

    def __init__(self, logits: torch.Tensor, frame: torch.Tensor, seen: torch.Tensor | None = None):
        if logits.ndim != 3 or logits.shape[2] != 3 or logits.shape[1] != 2 * logits.shape[0]:
            raise Eve3dError(f"environment map must be (h, 2h, 3), got {tuple(logits.shape)}")
        self.logits, self.frame, self.seen = logits, frame.to(logits), seen

    @property
    def colours(self) -> torch.Tensor:
        """(h, w, 3) the texels' colours in [0, 1]."""
        return torch.sigmoid(self.logits)

    @classmethod
    def constant(cls, colour, height: int, frame: np.ndarray) -> "Environment":
        """A map of ``height`` × 2·``height`` texels of one ``colour``."""
        logits = logit(torch.tensor(colour, dtype=torch.float32)).expand(height, 2 * height, 3).contiguous()
        return cls(logits, torch.as_tensor(frame, dtype=torch.float32))

    def to(self, device: torch.device | str) -> "Environment":
        """The same map on ``device``, float32, without autograd history."""
        return Environment(self.logits.detach().to(device).float().contiguous(), self.frame.detach().to(device),
                           None if self.seen is None else self.seen.to(device))

    def filled(self) -> "Environment":
        """The map to show views it was not trained on: each texel no training photo showed
        takes the colour of the nearest one that it did (a held-out view's sky in a direction
        between the training views' was black: 1.6 dB of monstree's held-out PSNR). While
        training those texels keep the background, behind the surfaces (:func:`photo_environment`).
        ``seen`` stays: what was shown, not guessed (:func:`explained`)."""
        if self.seen is None or not self.seen.any() or self.seen.all():
            return self
        from scipy.ndimage import distance_transform_edt

        _, (rows, columns) = distance_transform_edt(~self.seen.cpu().numpy(), return_indices=True)
        logits = self.logits.detach()[torch.from_numpy(rows).to(self.logits.device),
                                      torch.from_numpy(columns).to(self.logits.device)]
        return Environment(logits, self.frame, self.seen)

    def coordinates(self, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The map's (row, column) coordinates of world ``directions`` (..., 3), texel centres
        at integers: row 0 at the zenith, columns from azimuth −π, in [−0.5, w − 0.5)."""
        d = torch.nn.functional.normalize(directions.to(self.frame) @ self.frame.T, dim=-1)
        azimuth = torch.atan2(d[..., 1], d[..., 0])  # −π … π
        polar = torch.acos(d[..., 2].clamp(-1, 1))  # 0 at the zenith
        h, w = self.logits.shape[:2]
        return polar / math.pi * h - 0.5, (azimuth + math.pi) / (2 * math.pi) * w - 0.5

    def pixel_coordinates(self, cam: CameraTensors) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`coordinates` of ``cam``'s pixel rays (H, W), once per camera and map frame."""
        key = ("environment", tuple(self.logits.shape[:2]), tuple(self.frame.flatten().tolist()))
        return cam.memo(key, lambda: self.coordinates(cam.world_rays()))

    def __call__(self, directions: torch.Tensor) -> torch.Tensor:
        """Colours (..., 3) seen along world ``directions`` (..., 3), any length (:meth:`at`)."""
        return self.at(*self.coordinates(directions))

    def at(self, row: torch.Tensor, column: torch.Tensor) -> torch.Tensor:
        """Colours (..., 3) at the map's coordinates ``row``, ``column`` (...; :meth:`coordinates`):
        the logits bilinear in the map, the azimuth wrapping round, then their sigmoid."""
        h, w = self.logits.shape[:2]
        # the map with its first column repeated after its last: the azimuth wraps without a seam
        wrapped = torch.cat([self.logits, self.logits[:, :1]], dim=1).permute(2, 0, 1)[None]
        x = (2 * torch.remainder(column, w) + 1) / (w + 1) - 1  # grid_sample's coordinates (align_corners=False)
        y = (2 * row + 1) / h - 1
        grid = torch.stack([x, y], -1).reshape(1, 1, -1, 2)
        out = torch.nn.functional.grid_sample(wrapped, grid, mode="bilinear", padding_mode="border",
                                              align_corners=False)
        return torch.sigmoid(out[0, :, 0].T.reshape(*row.shape, 3))

    def image(self, cam: CameraTensors) -> torch.Tensor:
        """(H, W, 3) what the camera sees of the environment at its pixel centres."""
        return self(cam.world_rays())

    def behind(self, cam: CameraTensors, alpha: torch.Tensor, fit: torch.Tensor | None = None) -> torch.Tensor:
        """(H, W, 3) the environment behind Gaussians of ``alpha`` (H, W): looked up only
        where they leave more than ``T_MIN`` of it seen (elsewhere 0: it would add less than
        the rasteriser's own last contribution), with a gradient to the map only through
        the pixels of ``fit`` (H, W) when given. Most pixels of a view are surface, and the
        lookup's backward is the cost (16 ms a 512×384 view on 2 cores, whole)."""
        seen = (1 - alpha.detach()) > T_MIN
        learn = seen if fit is None else seen & fit
        out = alpha.new_zeros(*alpha.shape, 3)
        row, column = self.pixel_coordinates(cam)
        if fit is not None:
            with torch.no_grad():
                out[seen & ~learn] = self.at(row[seen & ~learn], column[seen & ~learn])
        out[learn] = self.at(row[learn], column[learn])
        return out

    def save(self, path: Path) -> None:
        """``path`` (.npz, written atomically) and its preview beside it (PNG, 0–255)."""
        path = Path(path)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            seen = {} if self.seen is None else {"seen": self.seen.cpu().numpy()}
            np.savez(f, logits=self.logits.detach().cpu().float().numpy(), frame=self.frame.detach().cpu().numpy(),
                     **seen)
        write_image(path.with_suffix(PREVIEW_SUFFIX),
                    (self.colours.detach().cpu().numpy() * 255).round().astype(np.uint8))

    @classmethod
    def load(cls, path: Path) -> "Environment":
        """The map saved at ``path`` (:meth:`save`)."""
        try:
            with np.load(path, allow_pickle=False) as data:
                logits, frame = data["logits"], data["frame"]
                seen = torch.from_numpy(data["seen"].astype(bool)) if "seen" in data.files else None
        except (OSError, ValueError, KeyError) as e:
            raise Eve3dError(f"{path}: not an environment map ({e})") from None
        if frame.shape != (3, 3):
            raise Eve3dError(f"{path}: frame must be 3×3, got {frame.shape}")
        if seen is not None and seen.shape != logits.shape[:2]:
            raise Eve3dError(f"{path}: seen must be {logits.shape[:2]}, got {tuple(seen.shape)}")
        return cls(torch.from_numpy(logits).float(), torch.from_numpy(frame).float(), seen)


def texel(env: Environment, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The (row, column) of ``env``'s texel nearest each of ``directions`` (..., 3), int64."""
    row, column = env.coordinates(directions)
    h, w = env.logits.shape[:2]
    return row.round().long().clamp(0, h - 1), torch.remainder(column.round().long(), w)


def explained(env: Environment, cam: CameraTensors, photo: torch.Tensor, tolerance: float) -> torch.Tensor:
    """(H, W) bool: the pixels of ``photo`` (H, W, 3, in [0, 1]) that ``env`` alone explains,
    its colour within ``tolerance`` of the photo's (the largest channel's difference, over
    3×3 pixels), in a direction a training photo showed beyond the scene (``seen``; a
    texel filled from its neighbours is a guess, which a facade's colours cross by
    chance): a sky, whatever Gaussians painted in front of it."""
    rays = cam.world_rays()
    difference = (photo.to(env.logits) - env(rays)).abs().amax(-1)
    mean = torch.nn.functional.avg_pool2d(difference[None, None], 3, stride=1, padding=1,
                                          count_include_pad=False)[0, 0]
    sky = mean < tolerance
    if env.seen is not None:
        sky &= env.seen[texel(env, rays)]
    return sky


def photo_environment(photos: list[tuple[CameraTensors, torch.Tensor, torch.Tensor]], height: int,
                      frame: np.ndarray, background) -> Environment:
    """The map that explains what ``photos`` ((camera, (H, W, 3) image, (H, W) mask)
    triples) show in their masked pixels (the rays beyond the measured scene): each texel
    the mean colour of the masked pixels whose ray falls in it, or of the nearest such
    texel up to ``FILL`` texels away; the ``background`` colour elsewhere, as behind a
    surface (a sky colour there would explain an uncovered pale surface, and the
    Gaussians would not grow onto it). A sky is then explained from the first step,
    before densification could grow Gaussians to paint it."""
    from scipy.ndimage import distance_transform_edt

    env = Environment.constant(background, height, frame)
    h, w = env.logits.shape[:2]
    total, count = torch.zeros(h * w, 3), torch.zeros(h * w)
    for cam, image, mask in photos:
        row, column = texel(env, cam.rays().cpu()[mask.cpu()] @ cam.R.cpu().float())
        index = row * w + column
        total.index_add_(0, index, image.detach().cpu().float()[mask.cpu()])
        count.index_add_(0, index, torch.ones(len(index)))
    seen = (count > 0).reshape(h, w).numpy()
    if seen.any():
        mean = (total / count.clamp_min(1)[:, None]).reshape(h, w, 3)
        distance, (rows, columns) = distance_transform_edt(~seen, return_indices=True)
        near = torch.from_numpy(distance <= FILL)
        env.logits[near] = logit(mean[torch.from_numpy(rows), torch.from_numpy(columns)][near])
        env.seen = near
    return env


def scene_environment(scene: Scene, views: Views, settings: TrainSettings) -> Environment | None:
    """The environment a training stage learns behind the Gaussians of ``scene``: each of
    ``views`` (and its coarse views) marks its pixels beyond the measured scene
    (``View.beyond``), and the map starts as what the training views show there
    (:func:`photo_environment`). None where nothing lies beyond (a room seen from inside, no
    sparse points) or ``settings.environment`` is 0: the constant ``background`` then.

    Beyond are the rays that miss ``measured_hull`` grown by ``settings.sky_margin``, but
    for those that only the hull with SfM's two-view points meets: there a pixel is beyond
    only if the map explains it (:func:`explained`, ``settings.sky_tolerance``; the map
    then fitted again). A floor's far rim that SfM saw in two views only shows another
    colour than the sky the other views see in its direction, so it stays the Gaussians'
    to cover; the sky there stays beyond (docs/method.md, "The environment at infinity")."""
    hull = measured_hull(scene, settings.sky_margin) if settings.environment else None
    if hull is None:
        return None
    with phase("environment"):
        groups = [views] + ([views.coarse[1]] if views.coarse else [])
        for group in groups:
            for view in group:
                view.beyond = torch.from_numpy(hull.missed(view.camera)).to(view.image.device)
        frame = up_frame(np.stack([cam.R for cam in scene.cameras]))

        def fitted() -> Environment:
            photos = [(views[i].cam, views[i].image, views[i].beyond) for i in views.train_ids]
            return photo_environment(photos, settings.environment, frame, settings.background)

        env = fitted()
        wider = measured_hull(scene, settings.sky_margin, two_view=True) if settings.sky_tolerance else None
        if wider is None:
            return env
        changed = False
        for group in groups:
            for view in group:
                missed = torch.from_numpy(wider.missed(view.camera)).to(view.beyond.device)
                if not (view.beyond & ~missed).any():  # the two-view points add nothing here
                    continue
                sky = explained(env, view.cam, view.image, settings.sky_tolerance)  # on the map's device
                view.beyond &= missed | sky.to(missed.device)
                changed = True
        return fitted() if changed else env
