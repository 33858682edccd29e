"""COLMAP models (binary or text) ↔ ``Scene``, through pycolmap."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.scene import Camera, Eve3dError, Scene

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")


def import_pycolmap():
    """pycolmap, imported after open3d. In the other order (pycolmap 4.2, open3d 0.20), the
    first PNG or npz write after an open3d ray cast aborts in zlib's deflateEnd."""
    import open3d  # noqa: F401
    import pycolmap

    return pycolmap


class NeedsUndistortion(Eve3dError):
    """The model has cameras with distortion: ``eve3d sfm`` undistorts them to PINHOLE."""


def model_file(model_dir: Path, what: str) -> Path:
    """The file of a model that holds ``what`` ('cameras', 'images', 'points3D')."""
    binary = model_dir / f"{what}.bin"
    return binary if binary.exists() else model_dir / f"{what}.txt"


def read_reconstruction(model_dir: Path):
    """pycolmap.Reconstruction of ``model_dir``, with a clear error when it cannot be read."""
    pycolmap = import_pycolmap()

    if not model_file(model_dir, "cameras").exists():
        raise Eve3dError(f"{model_dir}: no COLMAP model here (cameras.bin or cameras.txt)")
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises plain RuntimeError/ValueError with C++ text
        raise Eve3dError(f"{model_dir}: cannot read COLMAP model: {str(e).strip().splitlines()[-1]}") from None


def intrinsics(camera) -> np.ndarray:
    """3×3 K of a pinhole pycolmap camera."""
    p = np.asarray(camera.params, dtype=np.float64)
    if camera.model_name == "SIMPLE_PINHOLE":
        f, cx, cy = p
        fx = fy = f
    else:
        fx, fy, cx, cy = p
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def check_pinhole(rec, model_dir: Path) -> None:
    """Raise ``NeedsUndistortion`` (or a plain error for models that cannot be undistorted)."""
    for cam_id, cam in rec.cameras.items():
        if cam.model_name in PINHOLE_MODELS:
            continue
        where = model_file(model_dir, "cameras")
        if not cam.is_perspective():
            raise Eve3dError(
                f"{where}: camera {cam_id} uses model {cam.model_name}, which cannot be "
                f"undistorted to PINHOLE (only perspective models can)"
            )
        raise NeedsUndistortion(
            f"{where}: camera {cam_id} uses model {cam.model_name}; run `eve3d sfm` to undistort to PINHOLE"
        )


def read_colmap(model_dir: Path, image_dir: Path, root: Path | None = None, check_images: bool = True) -> Scene:
    """Read a PINHOLE/SIMPLE_PINHOLE COLMAP model whose images live in ``image_dir``."""
    from eve3d.fileio import check_image

    rec = read_reconstruction(model_dir)
    check_pinhole(rec, model_dir)
    if not image_dir.is_dir():
        raise Eve3dError(f"{image_dir}: image folder not found (the COLMAP model {model_dir} needs it)")
    cameras: list[Camera] = []
    index_of_image: dict[int, int] = {}
    for image_id, img in sorted(rec.images.items(), key=lambda kv: kv[1].name):
        if not img.has_pose:
            continue
        cam = rec.cameras[img.camera_id]
        path = image_dir / img.name
        if not path.is_file():
            raise Eve3dError(
                f"{model_file(model_dir, 'images')}: names image {img.name!r}, which is not in {image_dir}"
            )
        if check_images:
            check_image(path, (cam.width, cam.height))
        pose = img.cam_from_world().matrix()
        index_of_image[image_id] = len(cameras)
        cameras.append(Camera(img.name, cam.width, cam.height, intrinsics(cam), pose[:, :3], pose[:, 3], path))
    if not cameras:
        raise Eve3dError(f"{model_dir}: the COLMAP model has no posed images")
    points = colors = views = None
    if rec.num_points3D():
        ids = sorted(rec.points3D)
        points = np.array([rec.points3D[i].xyz for i in ids], dtype=np.float64)
        colors = np.array([rec.points3D[i].color for i in ids], dtype=np.uint8)
        views = [
            np.unique([index_of_image[e.image_id] for e in rec.points3D[i].track.elements if e.image_id in index_of_image])
            for i in ids
        ]
    return Scene(root=root or model_dir, cameras=cameras, points=points, point_colors=colors, point_views=views)


def write_colmap(scene: Scene, out_dir: Path, binary: bool = True) -> None:
    """Write ``scene`` as a COLMAP model (PINHOLE cameras, one per distinct intrinsics).

    Sparse points are written with their tracks; each observation becomes a 2D point at the
    projection of the 3D point.
    """
    pycolmap = import_pycolmap()

    rec = pycolmap.Reconstruction()
    camera_ids: dict[tuple, int] = {}
    observations: list[list[tuple[int, int]]] = [[] for _ in range(0 if scene.points is None else len(scene.points))]
    for idx, cam in enumerate(scene.cameras):
        key = (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            rec.add_camera_with_trivial_rig(
                pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                                params=[cam.fx, cam.fy, cam.cx, cam.cy], camera_id=camera_ids[key])
            )
        keypoints = np.zeros((0, 2))
        if scene.points is not None and scene.point_views is not None:
            seen = [i for i, v in enumerate(scene.point_views) if idx in v]
            keypoints = cam.project(scene.points[seen])[0] if seen else keypoints
            for k, i in enumerate(seen):
                observations[i].append((idx + 1, k))
        img = pycolmap.Image(name=cam.name, keypoints=keypoints, camera_id=camera_ids[key], image_id=idx + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.hstack([cam.R, cam.t[:, None]])))
    if scene.points is not None:
        colors = scene.point_colors if scene.point_colors is not None else np.full((len(scene.points), 3), 128, np.uint8)
        for xyz, rgb, obs in zip(scene.points, colors, observations):
            track = pycolmap.Track()
            for image_id, point2d_idx in obs:
                track.add_element(image_id, point2d_idx)
            rec.add_point3D(np.asarray(xyz, np.float64), track, np.asarray(rgb, np.uint8))
    out_dir.mkdir(parents=True, exist_ok=True)
    (rec.write_binary if binary else rec.write_text)(str(out_dir))
