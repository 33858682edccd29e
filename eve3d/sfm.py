"""SfM stage (``eve3d sfm``): images → undistorted PINHOLE COLMAP model, with pycolmap.

The photos are imported first (``eve3d.photos``: upright, longest side at most
``sfm.max_image_size``, unreadable files skipped with a warning), then SIFT extraction (one
shared camera by default, one per size when the photos differ), exhaustive or sequential
matching, incremental mapping, undistortion. A dataset that already has a COLMAP model with
distortion is only undistorted (its pixels as stored, as the model was made). Output:
``OUT/images``, ``OUT/sparse/0`` and the image pyramid ``OUT/images_{2,4,8}``.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from eve3d.fileio import atomic_dir
from eve3d.io.colmap import import_pycolmap
from eve3d.io.loader import METADATA, find_colmap_model
from eve3d.photos import import_photos, scan_photos, write_pyramid
from eve3d.scene import Camera, Eve3dError
from eve3d.settings import SfmSettings


def run_sfm(dataset: Path, out: Path, settings: SfmSettings | None = None) -> Path:
    """Reconstruct (or only undistort) ``dataset`` into ``out``; returns ``out``."""
    pycolmap = import_pycolmap()

    s = settings or SfmSettings()
    image_dir = dataset / "images"
    photos = scan_photos(image_dir)
    with atomic_dir(out) as tmp:
        model = find_colmap_model(dataset)
        if model is None:
            model = _reconstruct(photos, tmp / "work", s)
            image_dir = tmp / "work" / "images"
        pycolmap.undistort_images(str(tmp / "undistorted"), str(model), str(image_dir), output_type="COLMAP")
        (tmp / "sparse").mkdir()
        shutil.move(tmp / "undistorted" / "sparse", tmp / "sparse" / "0")
        shutil.move(tmp / "undistorted" / "images", tmp / "images")
        write_pyramid(tmp / "images")
        for scratch in ("undistorted", "work"):
            shutil.rmtree(tmp / scratch, ignore_errors=True)
        if (dataset / METADATA).exists():
            # Only the kind carries over: GT mesh and object size live in the dataset's own frame.
            kind = json.loads((dataset / METADATA).read_text()).get("kind")
            if kind:
                (tmp / METADATA).write_text(json.dumps({"kind": kind}, indent=2))
    return out


def _reconstruct(photos: list[Path], work: Path, s: SfmSettings) -> Path:
    """Import + SIFT + matching + incremental mapping; returns the folder of the largest
    model, whose images (``work/images``) are named as the photos' stems."""
    pycolmap = import_pycolmap()

    work.mkdir(parents=True)
    image_dir = work / "by_size"
    names = import_photos(photos, image_dir, s.max_image_size)
    pycolmap.set_random_seed(s.seed)
    db = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = s.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = s.max_image_size
    extraction.num_threads = s.threads
    pycolmap.extract_features(str(db), str(image_dir), image_names=names,
                              camera_mode=pycolmap.CameraMode.PER_FOLDER if s.single_camera else pycolmap.CameraMode.AUTO,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    match = pycolmap.match_exhaustive if s.matcher == "exhaustive" else pycolmap.match_sequential
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = s.threads
    match(str(db), matching_options=matching, device=pycolmap.Device.cpu)
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = s.seed
    options.num_threads = s.threads
    models = pycolmap.incremental_mapping(str(db), str(image_dir), str(work / "sparse"), options)
    if not models:
        raise Eve3dError(f"{photos[0].parent}: SfM could not register any image pair (too little texture or overlap?)")
    best_id, best = max(models.items(), key=lambda kv: kv[1].num_reg_images())
    registered = {img.name for img in best.images.values() if img.has_pose}
    print(f"SfM registered {len(registered)} of {len(names)} images, {best.num_points3D()} points")
    if len(registered) < s.min_registered_fraction * len(names):
        left_out = sorted(p.name for p, n in zip(photos, names) if n not in registered)
        raise Eve3dError(
            f"{photos[0].parent}: SfM registered {len(registered)} of {len(names)} images "
            f"(below the required fraction {s.min_registered_fraction:g}); left out: {', '.join(left_out)}"
        )
    # one flat folder, the images named as the photos' stems (the size folders only grouped the cameras)
    (work / "images").mkdir()
    for name in names:
        (image_dir / name).rename(work / "images" / Path(name).name)
    for img in best.images.values():
        img.name = Path(img.name).name
    model_dir = work / "sparse" / str(best_id)
    best.write_binary(str(model_dir))
    return model_dir


def triangulate_known_poses(cameras: list[Camera], image_dir: Path, work: Path, s: SfmSettings | None = None
                            ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Sparse points as SfM gives them to a user whose poses are known (DTU, a generated
    scene): SIFT features of the photos in ``image_dir`` (named as the cameras), matched
    (``s.matcher``) and triangulated by COLMAP's point triangulator with the cameras held
    fixed, outliers and all. Returns the points (N, 3), their colours (N, 3) uint8 and each
    point's views (indices into ``cameras``). ``work`` is scratch space (made, then removed)."""
    pycolmap = import_pycolmap()

    s = s or SfmSettings()
    work.mkdir(parents=True)
    db_path = work / "database.db"
    names = [c.name for c in cameras]
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = s.max_image_size
    extraction.num_threads = s.threads
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    pycolmap.set_random_seed(s.seed)
    pycolmap.extract_features(str(db_path), str(image_dir), image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = s.threads
    match = pycolmap.match_exhaustive if s.matcher == "exhaustive" else pycolmap.match_sequential
    match(str(db_path), matching_options=matching, device=pycolmap.Device.cpu)
    # the database's own ids, with our intrinsics and poses: the triangulator pairs them by id
    index = {name: i for i, name in enumerate(names)}
    known = pycolmap.Reconstruction()
    db = pycolmap.Database.open(str(db_path))
    try:
        for image in db.read_all_images():
            cam = cameras[index[image.name]]
            camera = db.read_camera(image.camera_id)
            camera.params = [cam.fx, cam.fy, cam.cx, cam.cy]
            db.update_camera(camera)
            known.add_camera_with_trivial_rig(camera)
            keypoints = db.read_keypoints(image.image_id)[:, :2]
            known.add_image_with_trivial_frame(
                pycolmap.Image(name=image.name, keypoints=keypoints, camera_id=image.camera_id, image_id=image.image_id),
                pycolmap.Rigid3d(np.hstack([cam.R, cam.t[:, None]])))
    finally:
        db.close()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = s.threads
    options.random_seed = s.seed
    result = pycolmap.triangulate_points(known, str(db_path), str(image_dir), str(work / "sparse"), options=options)
    shutil.rmtree(work, ignore_errors=True)
    by_id = {image_id: index[image.name] for image_id, image in result.images.items()}
    points = sorted(result.points3D.items())
    xyz = np.array([p.xyz for _, p in points]).reshape(-1, 3)
    colours = np.array([p.color for _, p in points], np.uint8).reshape(-1, 3)
    views = [np.unique([by_id[e.image_id] for e in p.track.elements]) for _, p in points]
    return xyz, colours, views
