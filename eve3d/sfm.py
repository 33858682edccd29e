"""SfM stage (``eve3d sfm``): images → undistorted PINHOLE COLMAP model, with pycolmap.

The photos are imported first (``eve3d.core.photos``: upright, longest side at most
``sfm.max_image_size``, unreadable files skipped with a warning), then SIFT extraction (one
shared camera by default, one per size when the photos differ), matching (every pair up to
``sfm.exhaustive_up_to`` photos, above that each with the next ones by name), incremental
mapping, undistortion. A dataset that already has a COLMAP model with distortion is only
undistorted (its pixels as stored, as the model was made). Output:
``OUT/images``, ``OUT/sparse/0`` and the image pyramid ``OUT/images_{2,4,8}``.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir
from eve3d.core.io.colmap import (extraction_options, find_colmap_model, import_pycolmap, mapping_options,
                                  match_features)
from eve3d.core.io.loader import METADATA
from eve3d.core.photos import import_photos, scan_photos, write_pyramid
from eve3d.core.settings import SfmSettings
from eve3d.core.timing import phase


def run_sfm(settings: SfmSettings, *, dataset: Path, out: Path) -> None:
    """The ``sfm`` stage: ``dataset``'s photos reconstructed (or a model given with them only
    undistorted) into an undistorted model in ``out``."""
    pycolmap = import_pycolmap()

    dataset, out = Path(dataset), Path(out)
    image_dir = dataset / "images"
    photos = scan_photos(image_dir)
    with atomic_dir(out) as tmp:
        model = find_colmap_model(dataset)
        if model is None:
            model = _reconstruct(photos, tmp / "work", settings)
            image_dir = tmp / "work" / "images"
        with phase("undistort"):
            pycolmap.undistort_images(str(tmp / "undistorted"), str(model), str(image_dir), output_type="COLMAP")
        (tmp / "sparse").mkdir()
        shutil.move(tmp / "undistorted" / "sparse", tmp / "sparse" / "0")
        shutil.move(tmp / "undistorted" / "images", tmp / "images")
        with phase("pyramid"):
            write_pyramid(tmp / "images")
        for scratch in ("undistorted", "work"):
            shutil.rmtree(tmp / scratch, ignore_errors=True)
        if (dataset / METADATA).exists():
            # Only the kind carries over: GT mesh and object size live in the dataset's own frame.
            kind = json.loads((dataset / METADATA).read_text()).get("kind")
            if kind:
                (tmp / METADATA).write_text(json.dumps({"kind": kind}, indent=2))
    print(f"wrote {out}")


def _reconstruct(photos: list[Path], work: Path, settings: SfmSettings) -> Path:
    """Import + SIFT + matching + incremental mapping; returns the folder of the largest
    model, whose images (``work/images``) are named as the photos' stems."""
    pycolmap = import_pycolmap()

    work.mkdir(parents=True)
    image_dir = work / "by_size"
    with phase("import photos"):
        names = import_photos(photos, image_dir, settings.max_image_size)
    pycolmap.set_random_seed(settings.seed)
    db = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = settings.camera_model
    with phase("features"):
        pycolmap.extract_features(str(db), str(image_dir), image_names=names,
                                  camera_mode=(pycolmap.CameraMode.PER_FOLDER if settings.single_camera
                                               else pycolmap.CameraMode.AUTO),
                                  reader_options=reader, extraction_options=extraction_options(settings),
                                  device=pycolmap.Device.cpu)
    with phase("matching"):
        match_features(db, settings, names)
    with phase("mapping"):
        models = pycolmap.incremental_mapping(str(db), str(image_dir), str(work / "sparse"), mapping_options(settings))
    if not models:
        raise Eve3dError(f"{photos[0].parent}: SfM could not register any image pair (too little texture or overlap?)")
    best_id, best = max(models.items(), key=lambda kv: kv[1].num_reg_images())
    registered = {img.name for img in best.images.values() if img.has_pose}
    print(f"SfM registered {len(registered)} of {len(names)} images, {best.num_points3D()} points")
    if len(registered) < settings.min_registered_fraction * len(names):
        left_out = sorted(p.name for p, n in zip(photos, names) if n not in registered)
        hint = ""
        if settings.matcher_for(len(names)) == "sequential":
            why = ("sfm.matcher: sequential" if settings.matcher == "sequential"
                   else f"more than sfm.exhaustive_up_to {settings.exhaustive_up_to} photos")
            hint = (f"; they were matched in sequence, by name ({why}): if their names do not follow the order "
                    f"they were taken in, set sfm.matcher: exhaustive")
        raise Eve3dError(
            f"{photos[0].parent}: SfM registered {len(registered)} of {len(names)} images "
            f"(below the required fraction {settings.min_registered_fraction:g}); left out: {', '.join(left_out)}{hint}"
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
