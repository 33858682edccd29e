"""COLMAP models (binary or text) ↔ ``Scene``, through pycolmap."""
from __future__ import annotations

import functools
import mmap
import re
import shutil
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera, Scene
from eve3d.core.settings import SfmSettings, job_threads

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")


def import_pycolmap():
    """pycolmap, imported after open3d. In the other order (pycolmap 4.2, open3d 0.20), the
    first PNG or npz write after an open3d ray cast aborts in zlib's deflateEnd. The training
    stages read their scene on a GPU machine that may have pycolmap and not open3d."""
    try:
        import open3d  # noqa: F401
    except ImportError:
        pass
    import pycolmap

    return pycolmap


class NeedsUndistortion(Eve3dError):
    """The model has cameras with distortion: ``eve3d sfm`` undistorts them to PINHOLE."""


def find_colmap_model(root: Path) -> Path | None:
    """The COLMAP model folder of a dataset: ``sparse/0``, ``sparse`` or the folder itself."""
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if (cand / "cameras.bin").exists() or (cand / "cameras.txt").exists():
            return cand
    return None


def colmap_model(root: Path) -> Path:
    """:func:`find_colmap_model`, or an error saying how to make one."""
    model = find_colmap_model(root)
    if model is None:
        raise Eve3dError(f"{root}: no poses (no cameras.npz, no COLMAP model in sparse/0): run `eve3d sfm` first")
    return model


def model_file(model_dir: Path, what: str) -> Path:
    """The file of a model that holds ``what`` ('cameras', 'images', 'points3D')."""
    binary = model_dir / f"{what}.bin"
    return binary if binary.exists() else model_dir / f"{what}.txt"


def read_reconstruction(model_dir: Path):
    """pycolmap.Reconstruction of ``model_dir``, with a clear error when it cannot be read."""
    pycolmap = import_pycolmap()

    if not model_file(model_dir, "cameras").exists():
        raise Eve3dError(f"{model_dir}: no COLMAP model here (cameras.bin or cameras.txt)")
    check_model_files(model_dir)
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises plain RuntimeError/ValueError with C++ text
        raise Eve3dError(f"{model_dir}: cannot read COLMAP model: {str(e).strip().splitlines()[-1]}") from None


def check_model_files(model_dir: Path) -> None:
    """Refuse a model whose files are cut short or are not COLMAP's, before pycolmap reads
    them: its binary reader does not check for the end of a file (a cut or garbage
    ``points3D.bin`` asks for gigabytes, a garbage ``frames.bin`` loops for minutes, a cut
    ``cameras.bin`` gives cameras of zeros), and its text reader drops a last image whose
    POINTS2D line is missing and stops at the end of a cut ``images.txt`` without a word."""
    if all((model_dir / f"{what}.bin").exists() for what in ("cameras", "images", "points3D")):
        for what, (noun, size, record) in _BINARY_RECORDS.items():
            if (model_dir / f"{what}.bin").exists():
                _walk_binary(model_dir / f"{what}.bin", noun, size, record)
    elif (model_dir / "images.txt").exists():
        check_images_txt(model_dir / "images.txt")


class _BadRecord(Exception):
    """What is wrong with one record of a binary model file (``_walk_binary`` names it)."""


@functools.cache
def _camera_params() -> dict[int, int]:
    """COLMAP camera model id → its number of parameters."""
    pycolmap = import_pycolmap()
    return {int(mid): len(pycolmap.Camera.create_from_model_name(1, name, 1.0, 1, 1).params)
            for name, mid in pycolmap.CameraModelId.__members__.items() if name != "INVALID"}


def _camera_record(buf, off: int) -> int:
    _, model, _, _ = struct.unpack_from("<IiQQ", buf, off)
    if model not in _camera_params():
        raise _BadRecord(f"camera model id {model}, which COLMAP does not define")
    return off + 24 + 8 * _camera_params()[model]


def _image_record(buf, off: int) -> int:
    end = buf.find(b"\0", off + 64)  # id, pose (7 doubles), camera id, then the name up to a NUL
    if end < 0:
        raise struct.error("no end of the image name")
    (points,) = struct.unpack_from("<Q", buf, end + 1)
    return end + 9 + 24 * points


def _point_record(buf, off: int) -> int:
    (track,) = struct.unpack_from("<Q", buf, off + 43)  # after id, xyz, rgb, error
    return off + 51 + 8 * track


def _rig_record(buf, off: int) -> int:
    _, sensors = struct.unpack_from("<II", buf, off)
    off += 16 if sensors else 8  # the reference sensor (type, id)
    for _ in range(max(sensors - 1, 0)):  # the others: type, id, has a pose, the pose
        (has_pose,) = struct.unpack_from("<B", buf, off + 8)
        off += 9 + (56 if has_pose else 0)
    return off


def _frame_record(buf, off: int) -> int:
    (data,) = struct.unpack_from("<I", buf, off + 64)  # after id, rig id, pose
    return off + 68 + 16 * data


_BINARY_RECORDS: dict[str, tuple[str, int, Callable[..., int]]] = {
    "cameras": ("camera", 24, _camera_record), "images": ("image", 73, _image_record),
    "points3D": ("point", 51, _point_record), "rigs": ("rig", 8, _rig_record), "frames": ("frame", 68, _frame_record)}
"""A binary model file → what its records are, their smallest size, and a function that
returns the offset after the record at an offset (COLMAP's layout, as pycolmap 4.2 writes it)."""


def _walk_binary(path: Path, noun: str, smallest: int, record: Callable[..., int]) -> None:
    """Walk the records of a COLMAP binary file (a count, then the records) without keeping
    them: an error names the file and the record that runs past its end or makes no sense."""
    size = path.stat().st_size
    if size < 8:
        raise Eve3dError(f"{path}: {size} bytes, too short for a COLMAP {path.name}: truncated?")
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        (count,) = struct.unpack_from("<Q", buf, 0)
        counted = f"{count} {noun}" + ("" if count == 1 else "s")
        if count * smallest > size - 8:
            raise Eve3dError(f"{path}: declares {counted}, more than its {size} bytes can hold: truncated, or not a "
                             f"COLMAP {path.name}")
        off = 8
        for i in range(count):
            try:
                off = record(buf, off)
            except struct.error:
                off = size + 1
            except _BadRecord as e:
                raise Eve3dError(f"{path}: {noun} {i + 1} of {count}: {e}: not a COLMAP {path.name}?") from None
            if off > size:
                raise Eve3dError(f"{path}: {noun} {i + 1} of the {counted} it declares runs past the end of the file "
                                 f"({size} bytes): truncated, or not a COLMAP {path.name}")
    if off != size:
        raise Eve3dError(f"{path}: {size - off} bytes after its {counted}: not a COLMAP {path.name}?")


_DECLARED_IMAGES = re.compile(r"#\s*Number of images:\s*(\d+)")


def check_images_txt(path: Path) -> None:
    """A COLMAP ``images.txt`` whose records are whole: each image a pose line and the
    POINTS2D line after it (which may be empty), as many images as its header declares
    (``# Number of images: N``, when it has one), the last POINTS2D line whole triples."""
    declared, images, last = None, 0, None
    with open(path, errors="replace") as f:
        lines = enumerate(f, 1)
        for number, line in lines:
            text = line.strip()
            if text.startswith("#"):
                found = _DECLARED_IMAGES.match(text)
                declared = int(found[1]) if found else declared
                continue
            if not text:
                continue  # blank lines between images (COLMAP skips them too)
            fields = text.split()
            if len(fields) < 10:
                raise Eve3dError(f"{path}: line {number}: an image line has 10 fields (IMAGE_ID, QW, QX, QY, QZ, "
                                 f"TX, TY, TZ, CAMERA_ID, NAME), this one {len(fields)}: truncated?")
            last = next(lines, None)
            if last is None:
                raise Eve3dError(f"{path}: line {number}: image {fields[9]!r} has no POINTS2D line after it (the file "
                                 f"ends there): truncated?")
            images += 1
    if last is not None and len(last[1].split()) % 3:
        raise Eve3dError(f"{path}: line {last[0]}: the POINTS2D line ends inside an (X, Y, POINT3D_ID) triple: "
                         f"truncated?")
    if declared is not None and declared != images:
        raise Eve3dError(f"{path}: its header declares {declared} images, the file holds {images}: truncated?")


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
    from eve3d.core.fileio import check_image

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


def sfm_threads(settings: SfmSettings) -> int:
    """``settings.threads``, with -1 (every core) read as the job's share where the workflow
    gives one (``OMP_NUM_THREADS``): pycolmap's -1 is every core of the machine."""
    return (job_threads() or -1) if settings.threads == -1 else settings.threads


def extraction_options(settings: SfmSettings):
    """SIFT's options: images scaled to at most ``settings.max_image_size``, affine shapes
    as ``settings.affine_features`` says, on ``settings.threads`` threads."""
    pycolmap = import_pycolmap()

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = settings.max_image_size
    extraction.sift.estimate_affine_shape = settings.affine_features
    extraction.num_threads = sfm_threads(settings)
    return extraction


def mapping_options(settings: SfmSettings):
    """The mapper's and the triangulator's options: ``settings.threads`` threads, seeded."""
    pycolmap = import_pycolmap()

    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = sfm_threads(settings)
    options.random_seed = settings.seed
    return options


SEQUENTIAL_OVERLAP = 10
"""COLMAP's sequential matching: each image with its next 10, and (quadratic) with those 2^k
ahead, k < 10."""


def sequential_pairs(names: list[str], overlap: int = SEQUENTIAL_OVERLAP) -> list[tuple[str, str]]:
    """COLMAP's sequential pairs of ``names`` in the order given. COLMAP's own generator orders
    the images by their whole name, where ours start with a folder per photo size: a capture
    of portrait and landscape photos would be matched as two sequences."""
    steps = sorted({1 + k for k in range(overlap)} | {1 << k for k in range(overlap)})
    return [(a, names[i + d]) for i, a in enumerate(names) for d in steps if i + d < len(names)]


def match_features(db_path: Path, settings: SfmSettings, names: list[str]) -> None:
    """Match the features of the images ``names`` (in the order they were taken) in the
    database ``db_path`` (``settings.matcher_for``) and verify each pair's two-view geometry
    (at most ``settings.ransac_trials`` RANSAC trials), on ``settings.threads`` threads."""
    pycolmap = import_pycolmap()

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = sfm_threads(settings)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.max_num_trials = settings.ransac_trials
    options = dict(matching_options=matching, verification_options=verification, device=pycolmap.Device.cpu)
    matcher = settings.matcher_for(len(names))
    if matcher != settings.matcher:
        print(f"{len(names)} photos: {matcher} matching (sfm.matcher auto: exhaustive up to "
              f"{settings.exhaustive_up_to})", flush=True)
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(str(db_path), **options)
        return
    pairs = db_path.with_name("pairs.txt")
    pairs.write_text("".join(f"{a} {b}\n" for a, b in sequential_pairs(names)))
    pycolmap.match_image_pairs(str(db_path), pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(pairs)),
                               **options)


def triangulate_known_poses(cameras: list[Camera], image_dir: Path, work: Path, settings: SfmSettings | None = None
                            ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Sparse points as SfM gives them to a user whose poses are known (DTU, a generated
    scene): SIFT features of the photos in ``image_dir`` (named as the cameras), matched
    (``settings.matcher``) and triangulated by COLMAP's point triangulator with the cameras
    held fixed, outliers and all. Returns the points (N, 3), their colours (N, 3) uint8 and each
    point's views (indices into ``cameras``). ``work`` is scratch space (made, then removed)."""
    pycolmap = import_pycolmap()

    settings = settings or SfmSettings()
    work.mkdir(parents=True)
    db_path = work / "database.db"
    names = [c.name for c in cameras]
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    pycolmap.set_random_seed(settings.seed)
    pycolmap.extract_features(str(db_path), str(image_dir), image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction_options(settings),
                              device=pycolmap.Device.cpu)
    match_features(db_path, settings, names)
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
    result = pycolmap.triangulate_points(known, str(db_path), str(image_dir), str(work / "sparse"),
                                         options=mapping_options(settings))
    shutil.rmtree(work, ignore_errors=True)
    by_id = {image_id: index[image.name] for image_id, image in result.images.items()}
    points = sorted(result.points3D.items())
    xyz = np.array([p.xyz for _, p in points]).reshape(-1, 3)
    colours = np.array([p.color for _, p in points], np.uint8).reshape(-1, 3)
    views = [np.unique([by_id[e.image_id] for e in p.track.elements]) for _, p in points]
    return xyz, colours, views
