"""The DTU layout of IDR/NeuS: ``cameras.npz`` (``world_mat_i``, ``scale_mat_i``),
``image/`` or ``images/``, ``mask/``.

Cameras are returned in the normalised frame (P = world_mat @ scale_mat), where the object
lies in the unit sphere; ``Scene.to_world`` is ``scale_mat``, which maps back to DTU mm.
IDR/NeuS cast rays through integer pixel coordinates (pixel centres at 0), so the principal
point moves by +0.5 px into our convention (centres at +0.5).

The 2DGS release adds a COLMAP model (``sparse/0``) in the same normalised frame, for
photos cropped from 1600×1200 to 1554×1162 while the masks and ``cameras.npz`` keep the full
frame. With a model there, the scene's cameras are the model's (they describe the photos as
stored) and the ``cameras.npz`` cameras, at the masks' size, become
``extras["mask_cameras"]``, which the DTU protocol culls with; the two sets must agree.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import check_image, list_images
from eve3d.core.io.loader import DatasetFormat
from eve3d.core.scene import Camera, Scene


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3×4 projection (any scale) → K (K[2,2] = 1, positive focal lengths), R, t."""
    import scipy.linalg  # here: every command imports the scene readers, only DTU's cameras need it

    P = np.asarray(P, dtype=np.float64)[:3, :4]
    if np.linalg.det(P[:, :3]) < 0:  # the overall scale of P may be negative
        P = -P
    K, R = scipy.linalg.rq(P[:, :3])
    signs = np.diag(np.sign(np.diag(K)))  # make the focal lengths positive
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def read_dtu(root: Path, check_images: bool = True) -> Scene:
    npz_path = root / "cameras.npz"
    try:
        cams = dict(np.load(npz_path, allow_pickle=False))
    except Exception as e:
        raise Eve3dError(f"{npz_path}: cannot read camera file ({e})") from None
    image_dir = next((root / d for d in ("image", "images") if (root / d).is_dir()), root / "image")
    images = list_images(image_dir)
    mask_dir = root / "mask"
    masks = list_images(mask_dir) if mask_dir.is_dir() else None
    if masks is not None and len(masks) != len(images):
        raise Eve3dError(f"{mask_dir}: {len(masks)} masks for {len(images)} images in {image_dir}")
    from eve3d.core.io.colmap import find_colmap_model

    model = find_colmap_model(root)
    # The npz cameras describe the frame the masks were drawn in (the photos too, unless a model describes them).
    width, height = check_image(masks[0] if model is not None and masks else images[0])
    cameras = []
    for i, path in enumerate(images):
        if f"world_mat_{i}" not in cams:
            raise Eve3dError(f"{npz_path}: no world_mat_{i} for image {path.name}")
        scale = cams.get(f"scale_mat_{i}", np.eye(4))
        K, R, t = decompose_projection((cams[f"world_mat_{i}"] @ scale)[:3])
        K[:2, 2] += 0.5  # integer pixel centres → centres at +0.5
        if check_images and model is None:
            check_image(path, (width, height))
        cameras.append(Camera(path.name, width, height, K, R, t, path, masks[i] if masks else None))
    scene = Scene(root=root, cameras=cameras, kind="object", to_world=cams.get("scale_mat_0", np.eye(4)),
                  extras={"object_radius": 1.0, "format": "dtu"})
    if model is not None:  # the model's cameras and sparse points, the npz cameras for the masks
        posed = _read_model(model, image_dir, cameras, check_images)
        scene.cameras, scene.extras["mask_cameras"] = posed.cameras, cameras
        scene.points, scene.point_colors, scene.point_views = posed.points, posed.point_colors, posed.point_views
    return scene


def _read_model(model: Path, image_dir: Path, npz_cameras: list[Camera], check_images: bool) -> Scene:
    """The COLMAP model, its cameras checked against the npz cameras (paired by order of
    name): an error names the first whose centre disagrees by more than 1 % of the
    normalised frame's unit sphere."""
    from eve3d.core.io.colmap import model_file, read_colmap

    scene = read_colmap(model, image_dir, check_images=check_images)
    posed = scene.cameras
    if len(posed) != len(npz_cameras):
        raise Eve3dError(f"{model_file(model, 'images')}: {len(posed)} posed images, cameras.npz has "
                         f"{len(npz_cameras)}")
    for cam, ref in zip(posed, npz_cameras):
        if np.linalg.norm(cam.center - ref.center) > 0.01:
            raise Eve3dError(f"{model_file(model, 'images')}: camera {cam.name} lies "
                             f"{np.linalg.norm(cam.center - ref.center):.3g} from its cameras.npz pose (the unit "
                             f"sphere's frame); the model and cameras.npz must describe the same normalised frame")
    return scene


FORMAT = DatasetFormat("dtu", lambda root: (root / "cameras.npz").exists(), read_dtu)
