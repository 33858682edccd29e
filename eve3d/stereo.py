"""Virtual stereo: the right cameras and views (``stereo_render``), and the depth priors of a
backend (``stereo_depth``; the backends live in ``eve3d.priors``, declared in
``PRIOR_BACKENDS``) with the confidence checks every backend passes through.

The right camera of a view has the same rotation and intrinsics, its centre moved by the
baseline B along the camera's own x axis, so a point at depth Z appears d = fx·B/Z pixels
further left in the right image (x_right = x_left − d) and Z = fx·B/d.
"""
from __future__ import annotations

import importlib
import json
from collections.abc import Callable
from dataclasses import asdict, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir, read_image, write_image
from eve3d.core.layout import TONE_FILE  # written by the pretrain beside its PLY; read here
from eve3d.core.maps import save_maps
from eve3d.core.photos import read_view
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings import RenderSettings
from eve3d.core.settings_fields import pick
from eve3d.core.settings_stereo import PRIOR_BACKENDS, BaselineSettings, MatchCheck, RealPairSettings, StereoSettings
from eve3d.core.timing import phase
from eve3d.gaussians.neighbours import select_neighbours
from eve3d.priors.matching import grey, local_std
from eve3d.priors.real_pairs import RectifiedPair, agreed_depth, pair_candidates


def right_camera(cam: Camera, baseline: float) -> Camera:
    """``cam`` moved by ``baseline`` along its x axis (same R and K): t_r = t − (B, 0, 0)."""
    return replace(cam, t=cam.t - np.array([baseline, 0.0, 0.0]), image_path=None, mask_path=None)


PAIRS_FILE = "pairs.json"


def margin_camera(cam: Camera, margin: int) -> Camera:
    """``cam`` with ``margin`` more columns on the left: a left pixel whose match lies up to
    ``margin`` px left of the frame is still inside the right image."""
    K = cam.K.copy()
    K[0, 2] += margin
    return replace(cam, width=cam.width + margin, K=K)


def render_right_views(scene: Scene, model_path: Path, out_dir: Path, baseline: BaselineSettings | None = None,
                       rendering: RenderSettings | None = None) -> dict:
    """``stereo_render``: the right view of every camera rendered by the pre-trained model
    at the size it was trained at (``right/{view}.png``, rasterised as it was trained:
    ``rendering``), and ``pairs.json``: per view the ``scale`` of that size (the photo is
    matched at it, so a model trained on smaller images is never asked for detail it does
    not have), the baseline, the disparity range to search (from the left view's rendered
    depth: 1st and 99th percentiles, with 25 % margins) and ``margin``, the columns the
    right view extends to the left of the photo's frame so that no left pixel's match falls
    outside it (a matcher's search range then costs no columns of the photo)."""
    import torch

    from eve3d.gaussians.model import GaussianModel
    from eve3d.gaussians.render import render_model
    from eve3d.gaussians.views import model_device

    baseline, rendering = baseline or BaselineSettings(), rendering or RenderSettings()
    model = GaussianModel.load_ply(model_path).to(model_device(rendering))
    # the right views come out in the model's grey levels: the photos are matched through the same curve
    tone_path = Path(model_path).with_name(TONE_FILE)
    tone = json.loads(tone_path.read_text()) if tone_path.exists() else list(range(256))
    info = {"baseline": asdict(baseline), "model": str(model_path), "tone_curve": tone, "views": {}}
    with atomic_dir(out_dir) as tmp, torch.no_grad():
        for full in tqdm(scene.cameras, desc="rendering right views", unit="view"):
            scale = rendering.scale(full)
            cam = rendering.sized(full)
            out = render_model(model, cam, rendering)
            depth = out.depth_expected[out.alpha > 0.5].cpu().numpy()
            near, median, far = (np.percentile(depth, [1, 50, 99]) if len(depth)
                                 else np.array([0.1, 1.0, 10.0]) * scene.radius)
            b = baseline.of_view(cam, scene.radius, float(median))
            d_min, d_max = 0.75 * cam.fx * b / far, 1.25 * cam.fx * b / max(near, 1e-6)
            margin = int(np.ceil(d_max)) + 16  # a matcher may round its range up (SGBM: to 16 px)
            right = render_model(model, margin_camera(right_camera(cam, b), margin), rendering)
            write_image(tmp / "right" / f"{cam.view_id}.png",
                        (right.rgb.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8))
            write_image(tmp / ALPHA_DIR / f"{cam.view_id}.png",
                        (out.alpha.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8))
            info["views"][cam.view_id] = {"scale": scale, "baseline": b, "min_disparity": float(np.floor(d_min)),
                                          "max_disparity": float(d_max), "margin": margin}
        (tmp / PAIRS_FILE).write_text(json.dumps(info, indent=2))
    return info


def warped_ncc(left: np.ndarray, right: np.ndarray, disp: np.ndarray, margin: int = 0,
               window: int = 7) -> np.ndarray:
    """NCC, per pixel over ``window``×``window``, between the left image and the right image
    sampled at each left pixel's match (x + margin − d, y) (:func:`_window_ncc`)."""
    import cv2

    h, w = disp.shape
    xs = np.arange(w, dtype=np.float32)[None, :] + margin - disp.astype(np.float32)
    ys = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w))
    warped = cv2.remap(grey(right), np.ascontiguousarray(xs), np.ascontiguousarray(ys), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return _window_ncc(grey(left), warped, window)


def neighbour_ncc(cam: Camera, photo: np.ndarray, depth: np.ndarray, neighbours: list[tuple[Camera, np.ndarray]],
                  window: int = 7) -> np.ndarray:
    """(K, H, W): per neighbour, the NCC over ``window``×``window`` between ``photo`` and the
    neighbour's photo sampled where ``depth`` sends each pixel; −1 where the point falls
    behind the neighbour or outside its image, or where the depth is 0. Real photos on both
    sides: a depth that the pretrained model got wrong (and rendered its right view with)
    does not bring them into agreement."""
    import cv2

    h, w = depth.shape
    points = cam.backproject(depth).reshape(-1, 3)
    photo_grey = grey(photo)
    out = np.full((len(neighbours), h, w), -1.0, np.float32)
    for k, (other, image) in enumerate(neighbours):
        uv, z = other.project(points)
        inside = other.in_image(uv, z).reshape(h, w) & (depth > 0)
        maps = (uv.reshape(h, w, 2) - 0.5).astype(np.float32)
        warped = cv2.remap(grey(image), np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out[k] = np.where(inside, _window_ncc(photo_grey, warped, window), -1)
    return out


def _window_ncc(photo: np.ndarray, other: np.ndarray, window: int) -> np.ndarray:
    """NCC of a photo and another image over every ``window``×``window`` window. A window
    the photo has no texture in (``FLAT_STD``) can neither confirm nor refute a depth and
    scores 1; a textured one against a flat one scores 0."""
    import cv2

    from eve3d.gaussians.losses import FLAT_STD, window_ncc

    ncc, var_photo, var_other = window_ncc(photo, other, lambda x: cv2.blur(x, (window, window)))
    flat = (FLAT_STD * 255) ** 2
    return np.where(var_photo > flat, np.where(var_other > flat, ncc, 0), 1).astype(np.float32)


def near_jump(disp: np.ndarray, valid: np.ndarray, jump: float, window: int) -> np.ndarray:
    """Pixels within a ``window``×``window`` box of a disparity jump: two adjacent pixels
    whose disparities differ by more than ``jump``, or a ``valid`` pixel beside one that
    is not."""
    import cv2

    edge = np.zeros(disp.shape, bool)
    for d, v, e in ((disp, valid, edge), (disp.T, valid.T, edge.T)):  # along rows, then along columns (views)
        jumps = (v[:, 1:] != v[:, :-1]) | (v[:, 1:] & (np.abs(d[:, 1:] - d[:, :-1]) > jump))
        e[:, 1:] |= jumps
        e[:, :-1] |= jumps
    kernel = np.ones((window, window), np.uint8)
    return cv2.dilate(edge.astype(np.uint8), kernel).astype(bool)


def rendered_surface(alpha: np.ndarray, min_alpha: float, window: int) -> np.ndarray:
    """Pixels whose whole ``window``×``window`` box the pretrained model covers with alpha
    ≥ ``min_alpha``."""
    import cv2

    low = cv2.erode(alpha.astype(np.float32), np.ones((max(window, 1),) * 2, np.uint8))
    return low >= min_alpha


def checked_confidence(left: np.ndarray, right: np.ndarray, disp: np.ndarray, confidence: np.ndarray,
                       search: tuple[float, float], margin: int = 0, check: MatchCheck | None = None,
                       alpha: np.ndarray | None = None) -> np.ndarray:
    """``confidence`` zeroed where a :class:`MatchCheck` fails; ``alpha``: the pretrained
    model's alpha in the left view (the ``min_alpha`` check; none without it)."""
    check = check or MatchCheck()
    ok = (disp > search[0] + check.range_margin) & (disp < search[1] - check.range_margin)
    if check.ncc_threshold > 0:
        ok &= warped_ncc(left, right, disp, margin, check.ncc_window) >= check.ncc_threshold
    matched = (disp > 0) & (confidence > 0)
    if check.flat_level > 0:  # before the edges: where an extrapolated band ends is an edge too
        matched &= interpolated(left, check.flat_level)
        ok &= matched
    if check.edge_window:
        ok &= ~near_jump(disp, matched, check.jump, check.edge_window)
    if alpha is not None and check.min_alpha > 0:
        ok &= rendered_surface(alpha, check.min_alpha, check.edge_window)
    if check.min_light > 0:
        ok &= lit(left, check.min_light)
    return np.where(ok, confidence, 0).astype(np.float32)


FLAT_WINDOW = 5
"""Window of the flat test (``MatchCheck.flat_level``), px: a matcher's block, about."""


def interpolated(photo: np.ndarray, flat_level: float) -> np.ndarray:
    """Pixels that are textured, or flat and enclosed by textured pixels on two opposite
    sides, in their row or in their column (``MatchCheck.flat_level``)."""
    import cv2

    box = np.ones((FLAT_WINDOW, FLAT_WINDOW), np.uint8)
    textured = ~cv2.dilate((local_std(photo, FLAT_WINDOW) < flat_level).astype(np.uint8), box).astype(bool)
    return textured | _between(textured) | _between(textured.T).T


def _between(textured: np.ndarray) -> np.ndarray:
    """Pixels with a ``textured`` pixel to their left and one to their right in their row."""
    left = np.logical_or.accumulate(textured, axis=1)
    right = np.logical_or.accumulate(textured[:, ::-1], axis=1)[:, ::-1]
    return left & right


def lit(photo: np.ndarray, min_light: float) -> np.ndarray:
    """Pixels whose 3×3 neighbourhood in ``photo`` has no grey level below ``min_light``."""
    import cv2

    return cv2.erode((grey(photo) >= min_light).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def stereo_priors(scene: Scene, stereo_dir: Path, out_dir: Path,
                  matcher: Callable[[np.ndarray, np.ndarray, tuple[float, float]], tuple[np.ndarray, np.ndarray]],
                  name: str, preview: bool = True, check: MatchCheck | None = None,
                  pairs: RealPairSettings | None = None) -> None:
    """``stereo_depth`` for a disparity backend: ``matcher(left, right, (min, max))`` gives
    the left disparity and its confidence on a pair (the photo at the pair's scale, padded
    on the left by the pair's margin, and its right image): its virtual right view, or its
    real neighbours rectified (``pairs``); the confidence passes through ``check``; depth
    Z = fx·B/d and normals from the depth are written for every view (``{view}.npz`` at the
    pair's size, and PNG previews; a stage reading them resamples them to its own size)."""
    import torch

    from eve3d.gaussians.geometry import depth_to_normal
    from eve3d.gaussians.render.projection import CameraTensors

    views, tone, cameras = read_pairs(stereo_dir, scene)
    check, pairs = check or MatchCheck(), pairs or RealPairSettings()
    neighbours = select_neighbours(scene, max(check.mv_neighbours, 2 * pairs.real_neighbours))
    real = pair_candidates(scene, neighbours, pairs.real_neighbours) if pairs.pairs != "virtual" else None
    # neighbours are mostly the views around: a few decoded photos serve several views
    photo = lru_cache(maxsize=max(map(len, neighbours), default=0) + 2)(lambda j: tone[read_view(cameras[j])])
    with atomic_dir(out_dir) as tmp:
        for i, cam in enumerate(tqdm(cameras, desc=name, unit="view")):
            pair = views[cam.view_id]
            with phase("read photos"):
                left = photo(i)
            alpha = left_alpha(stereo_dir, cam) if check.min_alpha > 0 else None
            # A view whose every neighbour stands along its line of sight (a capture walking
            # forward) has no pair that rectifies: it takes its virtual prior, which has none of
            # that geometry's trouble, rather than none.
            unpaired = real is not None and not real[i]
            if pairs.pairs != "real" or unpaired:
                depth, confidence = virtual_prior(cam, left, stereo_dir, pair, matcher, check, alpha)
            if real is not None and not unpaired:
                witness, trust = real_prior(cam, left, [(cameras[j], photo(j)) for j in real[i]], pair, matcher,
                                            check, pairs, alpha)
                if pairs.pairs == "real":
                    depth, confidence = witness, trust
                else:
                    agree = (trust > 0) & (np.abs(depth - witness) <= pairs.real_tolerance * witness)
                    confidence = np.where(agree, confidence, 0).astype(np.float32)
            near = neighbours[i][:check.mv_neighbours]
            if check.mv_ncc_threshold > 0 and len(near) >= check.mv_views:
                with phase("read photos"):
                    others = [(cameras[j], photo(j)) for j in near]
                with phase("checks"):
                    agree = (neighbour_ncc(cam, left, depth, others, check.ncc_window)
                             >= check.mv_ncc_threshold).sum(0)
                confidence = np.where(agree >= check.mv_views, confidence, 0).astype(np.float32)
            with phase("write"):
                normal = depth_to_normal(torch.from_numpy(depth), CameraTensors.from_camera(cam)).numpy()
                save_maps(tmp / f"{cam.view_id}.npz", preview=preview, depth=depth,
                          confidence=confidence.astype(np.float32), normal=normal)


def matched(left: np.ndarray, right: np.ndarray, margin: int, search: tuple[float, float], matcher
            ) -> tuple[np.ndarray, np.ndarray]:
    """``matcher``'s disparity and confidence of ``left`` against a ``right`` image ``margin``
    columns wider on the left: ``left`` padded to its width, the padding cut off again."""
    padded = np.pad(left, ((0, 0), (margin, 0)) + ((0, 0),) * (left.ndim - 2))
    with phase("match"):
        disp, confidence = matcher(padded, right, search)
    return disp[:, margin:], confidence[:, margin:]


def virtual_prior(cam: Camera, left: np.ndarray, stereo_dir: Path, pair: dict, matcher, check: MatchCheck,
                  alpha: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Depth and confidence of ``cam``'s photo ``left`` matched against its virtual right view."""
    margin, search = int(pair["margin"]), (float(pair["min_disparity"]), float(pair["max_disparity"]))
    right_path = stereo_dir / "right" / f"{cam.view_id}.png"
    right = read_image(right_path)
    if right.shape[0] != left.shape[0] or right.shape[1] != left.shape[1] + margin:
        raise Eve3dError(f"{right_path}: {right.shape[1]}×{right.shape[0]}, expected the photo's "
                         f"{left.shape[1]}×{left.shape[0]} plus {margin} columns on the left")
    disp, confidence = matched(left, right, margin, search, matcher)
    with phase("checks"):
        confidence = checked_confidence(left, right, disp, confidence, search, margin, check, alpha)
    depth = np.where(disp > 0, cam.fx * float(pair["baseline"]) / np.maximum(disp, 1e-6), 0).astype(np.float32)
    return depth, confidence


def real_prior(cam: Camera, left: np.ndarray, others: list[tuple[Camera, np.ndarray]], pair: dict, matcher,
               check: MatchCheck, settings: RealPairSettings, alpha: np.ndarray | None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Depth and confidence of ``cam``'s photo ``left`` from its real neighbours ``others``
    (camera, photo): each pair rectified, matched and checked, its depth carried back; kept
    where ``settings.real_views`` pairs agree. The depth range searched is the virtual
    pair's (the pretrained model's, with its margins)."""
    near = cam.fx * float(pair["baseline"]) / float(pair["max_disparity"])
    far = cam.fx * float(pair["baseline"]) / max(float(pair["min_disparity"]), 1e-6)
    depths, confidences = [], []
    for other, image in others:
        with phase("rectify"):
            rect = RectifiedPair.build(cam, left, other, image, (near, far), settings.real_max_disparity)
        disp, confidence = matched(rect.left, rect.right, rect.margin, rect.search, matcher)
        with phase("checks"):
            confidence = checked_confidence(rect.left, rect.right, disp, confidence, rect.search, rect.margin, check)
        depth, confidence = rect.carried_back(disp, confidence)
        depths.append(depth)
        confidences.append(confidence)
    if len(depths) < settings.real_views:
        return np.zeros(left.shape[:2], np.float32), np.zeros(left.shape[:2], np.float32)
    depth, confidence = agreed_depth(np.stack(depths), np.stack(confidences), settings.real_views,
                                     settings.real_tolerance)
    if alpha is not None and check.min_alpha > 0:
        confidence = np.where(rendered_surface(alpha, check.min_alpha, check.edge_window), confidence, 0)
    return depth, confidence.astype(np.float32)


PAIR_KEYS = {"baseline", "min_disparity", "max_disparity", "margin"}


def read_pairs(stereo_dir: Path, scene: Scene) -> tuple[dict[str, dict], np.ndarray, list[Camera]]:
    """``stereo-render``'s ``pairs.json`` in ``stereo_dir``, checked against ``scene``: each
    view's pair (``PAIR_KEYS``), the tone curve its right views were rendered with (256 grey
    levels), and the scene's cameras at the size of their pairs."""
    pairs_path = stereo_dir / PAIRS_FILE
    if not pairs_path.exists():
        raise Eve3dError(f"{pairs_path}: missing; run `eve3d stereo-render` first")
    pairs = json.loads(pairs_path.read_text())
    tone = np.asarray(pairs.get("tone_curve", range(256)))  # the pretrain's, which the right views have
    if tone.shape != (256,):
        raise Eve3dError(f"{pairs_path}: tone_curve must list 256 grey levels, got shape {tone.shape}")
    views = pairs.get("views", {})
    for cam in scene.cameras:
        if cam.view_id not in views:
            raise Eve3dError(f"{pairs_path}: no right view for {cam.view_id}")
        if not PAIR_KEYS <= views[cam.view_id].keys():
            raise Eve3dError(f"{pairs_path}: view {cam.view_id} lacks "
                             f"{', '.join(sorted(PAIR_KEYS - views[cam.view_id].keys()))}"
                             " (written by an older eve3d); run `eve3d stereo-render` again")
    # every view at the size its right view was rendered at
    # (no scale: written before priors were matched at the model's size, i.e. at the dataset's)
    scales = [float(views[c.view_id].get("scale", 1.0)) for c in scene.cameras]
    cameras = [c.scaled(f) if f != 1 else c for c, f in zip(scene.cameras, scales)]
    return views, tone.astype(np.uint8), cameras
ALPHA_DIR = "alpha"
"""The pretrained model's alpha in each left view (the photo's), 0–255 PNG at the pair's size."""


def left_alpha(stereo_dir: Path, cam: Camera) -> np.ndarray:
    """The pretrained model's alpha (0–1) in the left view of ``cam``'s pair."""
    path = stereo_dir / ALPHA_DIR / f"{cam.view_id}.png"
    if not path.is_file():
        raise Eve3dError(f"{path}: missing (stereo.min_alpha reads the pretrained model's alpha, which "
                         f"`eve3d stereo-render` writes); run `eve3d stereo-render` again, or set stereo.min_alpha: 0")
    alpha = read_image(path).astype(np.float32) / 255
    alpha = alpha if alpha.ndim == 2 else alpha[..., 0]
    if alpha.shape != (cam.height, cam.width):
        raise Eve3dError(f"{path}: {alpha.shape[1]}×{alpha.shape[0]}, expected the pair's {cam.width}×{cam.height}")
    return alpha


def run_stereo_render(settings: StereoSettings, rendering: RenderSettings, *, scene: Path, model: Path,
                      out: Path) -> None:
    """The ``stereo_render`` stage: right views of ``scene`` rendered by the pretrained ``model``
    (``rendering``: as it was trained) into ``out``."""
    from eve3d.core.io import load_scene

    with phase("read scene"):
        loaded = load_scene(scene)
    with phase("render right views"):
        info = render_right_views(loaded, Path(model), Path(out), pick(BaselineSettings, settings), rendering)
    b = [v["baseline"] for v in info["views"].values()]
    print(f"wrote {len(b)} right views to {out}/right (baseline {min(b):.4g} to {max(b):.4g})")


def run_stereo_depth(settings: StereoSettings, *, scene: Path, out: Path, stereo: Path | None = None,
                     gt_mesh: Path | None = None, preview: bool = True) -> None:
    """The ``stereo_depth`` stage: ``settings.backend``'s depth priors of ``scene`` into
    ``out`` (the backend's row in ``PRIOR_BACKENDS`` says where it lives and what it reads):
    from the right views in ``stereo``, or from ``gt_mesh`` (else the scene's own)."""
    from eve3d.core.io import load_scene

    backend = PRIOR_BACKENDS[settings.backend]
    with phase("read scene"):
        loaded, out = load_scene(scene), Path(out)
    if backend.reads == "pairs" and not stereo:
        raise Eve3dError(f"--backend {backend.name} needs --stereo (the output folder of `eve3d stereo-render`)")
    module = importlib.import_module(backend.module)
    if backend.reads == "gt_mesh":
        module.priors_from_mesh(loaded, out, Path(gt_mesh) if gt_mesh else None, preview=preview, settings=settings)
    else:
        with phase("load model"):
            matcher = module.matcher(settings)
        stereo_priors(loaded, Path(stereo), out, matcher, backend.label, preview=preview,
                      check=pick(MatchCheck, settings), pairs=pick(RealPairSettings, settings))
    print(f"wrote {len(loaded.cameras)} depth maps to {out}")


def run_export_stereo(size: tuple[int, int] | None, max_disparity: int, *, weights: str | None, out: str) -> None:
    """``eve3d export-stereo psmnet``: PSMNet to ONNX at ``size`` (HEIGHT, WIDTH; None: any)
    with ``max_disparity`` levels, into ``out``, and the config that uses it."""
    import yaml

    from eve3d.priors.psmnet import SPEC_FILE, export_psmnet

    config = export_psmnet(weights, out, size, max_disparity)
    model = Path(config["stereo"]["onnx"]["model"])
    print(f"wrote {model} and {model.parent / SPEC_FILE}; use it with --config {model.parent / SPEC_FILE}, "
          "or paste into your config:")
    print(yaml.safe_dump(config, sort_keys=False, default_flow_style=None), end="")

