"""Helpers shared by several test modules (fixtures live in conftest.py). No test module
imports another test module or conftest: what two modules need lives here."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent


# -- running the CLI and the workflow ----------------------------------------------------------

def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``python -m eve3d ARGS`` in a fresh process, as the workflow does."""
    return subprocess.run([sys.executable, "-m", "eve3d", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or REPO)


def snakemake(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    """Run this checkout's workflow (``Snakefile``) with ``args``."""
    return subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), *args],
                          capture_output=True, text=True, cwd=cwd)


def write_config(tmp_path: Path, **overrides) -> Path:
    """A workflow config in ``tmp_path``: the cpu preset, results under ``tmp_path``, the
    oracle on a 12-view 160×120 generated object (``tiny``), keys overridden by ``overrides``."""
    config = {"preset": "cpu", "results": str(tmp_path / "results"), "methods": ["oracle"],
              "scenes": {"tiny": {"synthetic": {"kind": "object", "views": 12, "width": 160, "height": 120}}},
              "mesh": {"coarsen": 8}}
    config.update(overrides)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


# -- training --------------------------------------------------------------------------------

def joint_settings(**kw):
    """Short joint-stage settings for the 8-view 64×48 scene (``tiny_scene``): 60 iterations
    of ``pgsr``, densification from 10 to 50; ``kw`` overrides any field."""
    from eve3d.settings import DensifySettings, JointSettings

    base = dict(method="pgsr", iterations=60, sh_degree=1, sh_degree_interval=20, checkpoint_every=25,
                dn_from=20, mv_from=20, ncc_pixels=256, previews=1,
                densify=DensifySettings(refine_start=10, refine_every=10, refine_stop=50, reset_every=0))
    base.update(kw)
    return JointSettings(**base)


# -- stereo ----------------------------------------------------------------------------------

def shifted_pair(disparity: int, h: int = 96, w: int = 128, grain: int = 4):
    """A textured pair with a constant disparity: random values upsampled ``grain`` times."""
    import cv2

    rng = np.random.default_rng(1)
    tex = cv2.resize(rng.integers(0, 255, (h // grain, (w + disparity) // grain, 3)).astype(np.uint8),
                     (w + disparity, h), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, disparity:])  # x_right = x_left − d


def stereo_scene(tmp_path: Path, disparity: int, baseline: float = 0.5):
    """One view (fx = 100) and its right view, a constant-disparity textured pair; the pair
    file is written only on request (see the test of its absence)."""
    import cv2

    from eve3d.scene import Camera, Scene
    from eve3d.stereo import PAIRS_FILE

    left, right = shifted_pair(disparity)
    cv2.imwrite(str(tmp_path / "v.png"), left[..., ::-1])
    (tmp_path / "stereo/right").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "stereo/right/v.png"), right[..., ::-1])
    K = np.array([[100.0, 0, 64], [0, 100, 48], [0, 0, 1]])
    scene = Scene(tmp_path, [Camera("v.png", 128, 96, K, np.eye(3), np.zeros(3), image_path=tmp_path / "v.png")])
    pairs = {"views": {"v": {"baseline": baseline, "min_disparity": 0, "max_disparity": 3 * disparity, "margin": 0}}}
    return scene, lambda: (tmp_path / "stereo" / PAIRS_FILE).write_text(json.dumps(pairs))


# -- DTU layout ------------------------------------------------------------------------------

def write_dtu_layout(scene, root: Path, scale_mat: np.ndarray, images: str = "image") -> None:
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


def write_dtu_ground_truth(scene, root: Path, scan: int, scale_mat: np.ndarray, points: int = 400_000) -> dict:
    """DTU's official evaluation files of ``scene`` as the download lays them out under
    ``root`` (``Points/stl/stl{scan:03d}_total.ply``, ``ObsMask/ObsMask{scan}_10.mat``,
    ``ObsMask/Plane{scan}.mat``), in 'mm' = scale_mat·x: like a structured-light scan, the
    STL points cover the GT surface the cameras see; the ObsMask marks the 4 mm voxels they
    fall in; the plane lies just above the scene's lowest point. Returns the three paths."""
    import open3d as o3d
    from scipy.io import savemat

    from eve3d.evaluate.common import read_mesh
    from eve3d.evaluate.synthetic import visible_surface_samples

    stl, _ = visible_surface_samples(read_mesh(scene.gt_mesh), scene.cameras, points, 1, np.random.default_rng(0))
    stl = stl @ scale_mat[:3, :3].T + scale_mat[:3, 3]
    files = {"stl": root / "Points" / "stl" / f"stl{scan:03d}_total.ply",
             "obs_mask": root / "ObsMask" / f"ObsMask{scan}_10.mat", "plane": root / "ObsMask" / f"Plane{scan}.mat"}
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


def write_dtu_release(scene, root: Path, scan: int = 24, crop: int = 4, stl_points: int = 100_000) -> Path:
    """A miniature DTU download under ``root`` as the 2DGS release and the official
    evaluation files lay it out: ``scan{scan}/`` with ``images/`` cropped by ``crop`` px on
    every side (2DGS crops 1600×1200 to 1554×1162), full-size ``mask/``, ``cameras.npz`` of
    the full frame and a COLMAP model of the cropped photos in the same normalised frame;
    ``Points/stl`` and ``ObsMask`` beside the scan folders. Returns the scan folder."""
    from dataclasses import replace

    from eve3d.fileio import read_image, write_image
    from eve3d.io.colmap import write_colmap
    from eve3d.scene import Scene

    folder = root / f"scan{scan}"
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
    """A 4×4 similarity: ``scale`` × the rotation by ``angle`` about ``axis``, then ``translation``."""
    import open3d as o3d

    m = np.eye(4)
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    m[:3, :3] = scale * o3d.geometry.get_rotation_matrix_from_axis_angle(axis * angle)
    m[:3, 3] = translation
    return m


def write_crop(path: Path, polygon, axis_min: float, axis_max: float) -> None:
    """A T&T crop file: the polygon (x, y) extruded along z from ``axis_min`` to ``axis_max``."""
    path.write_text(json.dumps({
        "class_name": "SelectionPolygonVolume", "orthogonal_axis": "Z", "axis_min": axis_min,
        "axis_max": axis_max, "bounding_polygon": [[x, y, 0.0] for x, y in polygon],
        "version_major": 1, "version_minor": 0}))


def write_log(path: Path, poses) -> None:
    """A T&T/Redwood ``.log`` trajectory of camera-to-world poses."""
    with open(path, "w") as f:
        for i, pose in enumerate(poses):
            f.write(f"{i} {i} 0\n" + "\n".join(" ".join(f"{v:.12f}" for v in row) for row in pose) + "\n")


TNT_OFFICIAL = similarity(2.0, [0.3, -1.0, 0.5], 0.7, [1.0, -2.0, 0.5])
"""The official COLMAP frame → the GT frame of the miniature T&T scenes (``_trans.txt``)."""


def write_tnt_release(scene, root: Path, name: str = "Barn", gt_points: int = 200_000) -> Path:
    """A miniature T&T download under ``root`` as the GOF/2DGS COLMAP release with the
    official evaluation files beside it: ``{name}/images``, ``sparse/0`` (the scene's own
    frame, which is the GT frame here), ``{name}_COLMAP_SfM.log`` (the same cameras in the
    'official COLMAP frame'), ``{name}_trans.txt`` (that frame → GT), ``{name}.ply`` (GT
    points) and ``{name}.json`` (a crop box around the GT). Returns the scene folder."""
    import open3d as o3d

    from eve3d.evaluate.common import read_mesh
    from eve3d.io.colmap import write_colmap
    from eve3d.scene import Scene
    from eve3d.surface import sample_surface

    folder = root / name
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
    write_log(folder / f"{name}_COLMAP_SfM.log", poses)
    np.savetxt(folder / f"{name}_trans.txt", TNT_OFFICIAL)
    gt = read_mesh(scene.gt_mesh)
    v, tri = np.asarray(gt.vertices), np.asarray(gt.triangles)
    points = sample_surface(v, tri, gt_points, np.random.default_rng(0))
    o3d.io.write_point_cloud(str(folder / f"{name}.ply"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    lo, hi = points.min(0), points.max(0)
    pad = 0.05 * (hi - lo)
    (x0, y0, z0), (x1, y1, z1) = lo - pad, hi + pad
    write_crop(folder / f"{name}.json", [(x0, y0), (x1, y0), (x1, y1), (x0, y1)], z0, z1)
    return folder


def write_mipnerf360_release(scene, root: Path, name: str = "room") -> Path:
    """A miniature Mip-NeRF 360 scene under ``root`` as 360_v2.zip lays it out:
    ``{name}/images`` (JPEG, upper-case suffix as released), ``images_{2,4,8}`` (area
    downscaled copies), ``sparse/0`` and ``poses_bounds.npy``. Returns the scene folder."""
    import cv2
    from dataclasses import replace

    from eve3d.fileio import read_image
    from eve3d.io.colmap import write_colmap
    from eve3d.scene import Scene

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
    bounds = np.array([[cam.R.T.ravel().tolist() + cam.center.tolist()] for cam in cameras]).reshape(len(cameras), -1)
    np.save(folder / "poses_bounds.npy", np.hstack([bounds, np.zeros((len(cameras), 5))]))
    return folder


# -- the report in a browser -----------------------------------------------------------------

CHROMIUM = Path("/usr/lib/chromium/chromium-headless-shell")
"""Debian's chromium-headless-shell (the set-up installs it), driven by Playwright."""
BENIGN_CONSOLE = ("cdn.tailwindcss.com should not be used in production",)
"""A warning Snakemake's report logs about its inlined stylesheet framework."""


def decodes(data_uri: str) -> bool:
    """Whether the raster image of a ``data:`` URI decodes whole (PIL)."""
    import base64
    import io

    from PIL import Image

    head, _, data = data_uri.partition(",")
    try:
        with Image.open(io.BytesIO(base64.b64decode(data) if head.endswith(";base64") else data.encode())) as im:
            im.load()
        return True
    except Exception:
        return False


def open_report(report: Path, screenshot: Path | None = None) -> dict:
    """Load Snakemake's HTML report in headless Chromium and read what a person sees: the
    rows of the summary page's ``#summary`` table (its cells), how many image results it
    holds and how many of them failed to decode once shown, and every resource that failed
    to load, console error, page error or request that left the file."""
    from playwright.sync_api import expect, sync_playwright

    problems: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.on("console", lambda m: m.type == "error" and not m.text.startswith(BENIGN_CONSOLE)
                and problems.append(f"console: {m.text}"))
        page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        page.on("requestfailed", lambda r: problems.append(f"failed: {r.url[:120]} {r.failure}"))
        page.on("request", lambda r: r.url.startswith("http") and problems.append(f"external: {r.url}"))
        page.goto(report.resolve().as_uri())
        expect(page.get_by_text("1 Summary", exact=True)).to_be_visible()  # the app has rendered
        results = page.evaluate("Object.keys(results).map(p => [p, results[p].mime_type])")
        summary = next(path for path, mime in results if path.endswith("report/summary.html"))
        page.evaluate("p => app.setView({content: 'html', contentPath: results[p].data_uri, resultPath: p})", summary)
        table = page.frame_locator("iframe").locator("table#summary")
        expect(table).to_be_visible()
        header = table.locator("thead th").all_inner_texts()
        rows = [dict(zip(header, row.split("\t"))) for row in table.locator("tbody tr").all_inner_texts()]
        if screenshot is not None:
            page.screenshot(path=str(screenshot), full_page=True)
        images, broken = [path for path, mime in results if mime.startswith("image/")], []
        for path in images:  # each image shown as the result list's eye button shows it
            uri = page.evaluate("p => results[p].data_uri", path)
            page.evaluate("p => app.setView({content: 'img', contentPath: results[p].data_uri, resultPath: p})", path)
            img = page.locator(f"img[src='{uri}']")
            expect(img).to_be_visible()
            shown = img.evaluate("i => i.decode().then(() => i.naturalWidth > 0, () => false)")
            # A browser shows what it can of a truncated PNG; the embedded bytes must decode whole.
            if not shown or not decodes(uri):
                broken.append(path)
        if screenshot is not None and images:
            page.screenshot(path=str(screenshot.with_name(screenshot.stem + "_image.png")))
        browser.close()
    return {"rows": rows, "images": images, "broken": broken, "problems": problems}
