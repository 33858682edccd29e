"""Benchmark downloads stood in for by generated scenes: a scene of ``eve3d.synth`` written
in a benchmark's released layout with its ground-truth files (``eve3d bench standin``). To
try a benchmark config without the download, to time it at the benchmark's size, and for
the tests (a miniature of each download runs through its config end to end).

* DTU: the 2DGS release (photos cropped, a COLMAP model beside ``cameras.npz`` and the
  full-size masks) and the official ``Points/stl`` and ``ObsMask`` files, in "mm".
* Tanks and Temples: the GOF/2DGS COLMAP release and the official evaluation files: the
  trajectory in an "official COLMAP frame", the transform from it to the GT frame, the GT
  points and a crop box.
* Mip-NeRF 360: ``images``, ``images_{2,4,8}`` (JPEG, as released), ``sparse/0``.
"""
from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Scene


def write_dtu_layout(scene: Scene, root: Path, scale_mat: np.ndarray, images: str = "image") -> None:
    """Write a scene in the IDR/NeuS DTU layout, its cameras expressed in 'mm' = scale_mat·x."""
    (root / images).mkdir(parents=True)
    (root / "mask").mkdir()
    inv = np.linalg.inv(scale_mat)
    arrays = {}
    for i, cam in enumerate(scene.cameras):
        shutil.copy(cam.image_path, root / images / f"{i:06d}.png")
        shutil.copy(scene.root / "masks" / cam.name, root / "mask" / f"{i:03d}.png")
        world_mat = np.eye(4)
        idr_k = cam.K.copy()
        idr_k[:2, 2] -= 0.5  # IDR/NeuS put pixel centres at integer coordinates
        world_mat[:3] = idr_k @ cam.world_to_camera[:3] @ inv  # maps mm points to pixels
        arrays[f"world_mat_{i}"] = world_mat
        arrays[f"scale_mat_{i}"] = scale_mat
    np.savez(root / "cameras.npz", **arrays)


def dtu_scale_mat() -> np.ndarray:
    s = np.diag([50.0, 50.0, 50.0, 1.0])
    s[:3, 3] = [10.0, -20.0, 600.0]
    return s


def write_dtu_ground_truth(scene: Scene, root: Path, scan: int, scale_mat: np.ndarray,
                           points: int = 400_000) -> dict[str, Path]:
    """DTU's official evaluation files of ``scene`` as the download lays them out under
    ``root`` (``Points/stl/stl{scan:03d}_total.ply``, ``ObsMask/ObsMask{scan}_10.mat``,
    ``ObsMask/Plane{scan}.mat``), in 'mm' = scale_mat·x: like a structured-light scan, the
    STL points cover the GT surface the cameras see; the ObsMask marks the 4 mm voxels they
    fall in; the plane lies just above the scene's lowest point. Returns the three paths."""
    import open3d as o3d
    from scipy.io import savemat

    from eve3d.core.datasets import dtu_files
    from eve3d.core.fileio import read_mesh
    from eve3d.evaluate.synthetic import visible_surface_samples

    stl, _ = visible_surface_samples(read_mesh(scene.gt_mesh), scene.cameras, points, 1, np.random.default_rng(0))
    stl = stl @ scale_mat[:3, :3].T + scale_mat[:3, 3]
    files = dtu_files(root, f"scan{scan}")
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
    o3d.io.write_point_cloud(str(files["stl"]), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(stl)))
    res, lo = 4.0, stl.min(0) - 8
    shape = np.ceil((stl.max(0) + 8 - lo) / res).astype(int)
    obs = np.zeros(shape, dtype=np.uint8)
    idx = np.round((stl - lo) / res).astype(int)
    obs[idx[:, 0], idx[:, 1], idx[:, 2]] = 1
    savemat(files["obs_mask"], {"ObsMask": obs, "BB": np.stack([lo, lo + shape * res]), "Res": res})
    savemat(files["plane"], {"P": np.array([0, 0, 1.0, -(scale_mat[2, 3] + 0.001 * scale_mat[2, 2])])})
    return files


def write_dtu_release(scene: Scene, root: Path, name: str = "scan24", crop: int = 4, stl_points: int = 100_000
                      ) -> Path:
    """A miniature DTU download under ``root`` as the 2DGS release and the official
    evaluation files lay it out: ``{name}/`` (``scan24``) with ``images/`` cropped by ``crop`` px on
    every side (2DGS crops 1600×1200 to 1554×1162), full-size ``mask/``, ``cameras.npz`` of
    the full frame and a COLMAP model of the cropped photos in the same normalised frame;
    ``Points/stl`` and ``ObsMask`` beside the scan folders. Returns the scan folder."""
    from dataclasses import replace

    from eve3d.core.datasets import dtu_scan
    from eve3d.core.fileio import read_image, write_image
    from eve3d.core.io.colmap import write_colmap

    scan, folder = dtu_scan(name), root / name
    scale = dtu_scale_mat()
    write_dtu_layout(scene, folder, scale, images="images")
    cropped = []
    for i, cam in enumerate(scene.cameras):
        path = folder / "images" / f"{i:06d}.png"
        write_image(path, read_image(path)[crop:-crop, crop:-crop])
        K = cam.K.copy()
        K[:2, 2] -= crop
        cropped.append(replace(cam, name=path.name, width=cam.width - 2 * crop, height=cam.height - 2 * crop, K=K,
                               image_path=path, mask_path=None))
    write_colmap(Scene(root=folder, cameras=cropped, points=scene.points, point_colors=scene.point_colors,
                       point_views=scene.point_views), folder / "sparse" / "0")
    write_dtu_ground_truth(scene, root, scan, scale, stl_points)
    return folder


def similarity(scale: float, axis, angle: float, translation) -> np.ndarray:
    """A 4×4 similarity: ``scale`` × the rotation by ``angle`` (radians) about ``axis``
    (Rodrigues), then ``translation``."""
    x, y, z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    m = np.eye(4)
    m[:3, :3] = scale * (np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k)
    m[:3, 3] = translation
    return m


def write_crop(path: Path, polygon: list[tuple[float, float]], axis_min: float, axis_max: float) -> None:
    """A T&T crop file: the polygon (x, y) extruded along z from ``axis_min`` to ``axis_max``."""
    path.write_text(json.dumps({
        "class_name": "SelectionPolygonVolume", "orthogonal_axis": "Z", "axis_min": axis_min,
        "axis_max": axis_max, "bounding_polygon": [[x, y, 0.0] for x, y in polygon],
        "version_major": 1, "version_minor": 0}))


def write_log(path: Path, poses: list[np.ndarray]) -> None:
    """A T&T/Redwood ``.log`` trajectory of camera-to-world poses."""
    with open(path, "w") as f:
        for i, pose in enumerate(poses):
            f.write(f"{i} {i} 0\n" + "\n".join(" ".join(f"{v:.12f}" for v in row) for row in pose) + "\n")


TNT_OFFICIAL = similarity(2.0, [0.3, -1.0, 0.5], 0.7, [1.0, -2.0, 0.5])
"""The official COLMAP frame → the GT frame of the miniature T&T scenes (``_trans.txt``)."""


def write_tnt_release(scene: Scene, root: Path, name: str = "Barn", gt_points: int = 200_000) -> Path:
    """A miniature T&T download under ``root`` as the GOF/2DGS COLMAP release with the
    official evaluation files beside it: ``{name}/images``, ``sparse/0`` (the scene's own
    frame, which is the GT frame here), ``{name}_COLMAP_SfM.log`` (the same cameras in the
    'official COLMAP frame'), ``{name}_trans.txt`` (that frame → GT), ``{name}.ply`` (GT
    points) and ``{name}.json`` (a crop box around the GT). Returns the scene folder."""
    import open3d as o3d

    from eve3d.core.fileio import read_mesh
    from eve3d.core.io.colmap import write_colmap
    from eve3d.core.io.tnt import ground_truth_files
    from eve3d.core.surface import sample_surface

    folder = root / name
    files = ground_truth_files(folder, name)
    shutil.copytree(scene.root / "images", folder / "images")
    write_colmap(Scene(root=folder, cameras=scene.cameras, points=scene.points, point_colors=scene.point_colors,
                       point_views=scene.point_views), folder / "sparse" / "0")
    to_official = np.linalg.inv(TNT_OFFICIAL)
    rotation = TNT_OFFICIAL[:3, :3] / np.cbrt(np.linalg.det(TNT_OFFICIAL[:3, :3]))
    poses = []
    for cam in scene.cameras:
        pose = np.eye(4)
        pose[:3, :3] = rotation.T @ cam.R.T
        pose[:3, 3] = to_official[:3, :3] @ cam.center + to_official[:3, 3]
        poses.append(pose)
    write_log(files["trajectory"], poses)
    np.savetxt(files["trans"], TNT_OFFICIAL)
    gt = read_mesh(scene.gt_mesh)
    v, tri = np.asarray(gt.vertices), np.asarray(gt.triangles)
    points = sample_surface(v, tri, gt_points, np.random.default_rng(0))
    o3d.io.write_point_cloud(str(files["gt_points"]), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    lo, hi = points.min(0), points.max(0)
    pad = 0.05 * (hi - lo)
    (x0, y0, z0), (x1, y1, z1) = lo - pad, hi + pad
    write_crop(files["crop"], [(x0, y0), (x1, y0), (x1, y1), (x0, y1)], z0, z1)
    return folder


def write_mipnerf360_release(scene: Scene, root: Path, name: str = "room") -> Path:
    """A miniature Mip-NeRF 360 scene under ``root`` as 360_v2.zip lays it out:
    ``{name}/images`` (JPEG, upper-case suffix as released), ``images_{2,4,8}`` (area
    downscaled copies), ``sparse/0`` and ``poses_bounds.npy``. Returns the scene folder."""
    from dataclasses import replace

    import cv2

    from eve3d.core.fileio import read_image
    from eve3d.core.io.colmap import write_colmap

    folder = root / name
    cameras = []
    for i, cam in enumerate(scene.cameras):
        rgb = read_image(cam.image_path)
        image = f"DSC{i:05d}.JPG"
        for factor in (1, 2, 4, 8):
            out = folder / ("images" if factor == 1 else f"images_{factor}") / image
            out.parent.mkdir(parents=True, exist_ok=True)
            small = cv2.resize(rgb, (cam.width // factor, cam.height // factor), interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(out), small[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        cameras.append(replace(cam, name=image, image_path=folder / "images" / image))
    write_colmap(Scene(root=folder, cameras=cameras, points=scene.points, point_colors=scene.point_colors,
                       point_views=scene.point_views), folder / "sparse" / "0")
    # LLFF's poses and depth bounds (N×17): part of the layout, never read here; a placeholder
    np.save(folder / "poses_bounds.npy", np.zeros((len(cameras), 17)))
    return folder


def standin(benchmark: str) -> tuple[Callable[..., Path], str]:
    """The writer of ``benchmark``'s stand-in and the released scene it writes
    (``eve3d.core.datasets.BENCHMARKS``: its ``standin``)."""
    from eve3d.core.datasets import BENCHMARKS

    writer, name = BENCHMARKS[benchmark].standin.split(":")
    return globals()[writer], name


def write_standin(benchmark: str, scene: Scene, root: Path) -> Path:
    """``scene`` written under ``root`` as the download of ``benchmark`` lays out its
    stand-in scene; returns that scene's folder."""
    writer, name = standin(benchmark)
    return writer(scene, root, name)


def run_bench_standin(benchmark: str, root: Path, views: int = 49, width: int = 1600, height: int = 1200) -> None:
    """``eve3d bench standin``: a generated object in ``benchmark``'s layout under ``root``."""
    import tempfile

    from eve3d.core.io import load_scene
    from eve3d.synth import generate

    root, name = Path(root), standin(benchmark)[1]
    if (root / name).exists():
        raise Eve3dError(f"{root / name}: already there; give an empty folder")
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_scene(generate("object", Path(tmp) / "object", views=views, width=width, height=height))
        folder = write_standin(benchmark, scene, root)
    print(f"wrote a stand-in {name} ({views} views, {width}×{height}) to {folder}; run it:\n"
          f"  snakemake -c2 --configfile config/benchmarks/{benchmark}.yaml --replace-workflow-config "
          f"--config root={root} 'only=[{name}]'")
