"""Helpers shared by several test modules (fixtures live in conftest.py). No test module
imports another test module or conftest: what two modules need lives here."""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from eve3d.config import REPO, SNAKEFILE  # this checkout and its workflow, which the tests run


# -- running the CLI and the workflow ----------------------------------------------------------

def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``eve3d ARGS`` as the workflow runs it (``eve3d.cli.main``, its exit status, stdout and
    stderr), but in this process: a fresh interpreter would import torch and open3d again for
    each call. The workflow tests run the real ``python -m eve3d`` processes."""
    from eve3d.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(map(str, args)))
        except SystemExit as e:  # argparse's usage errors
            code = e.code if isinstance(e.code, int) else 1
    return subprocess.CompletedProcess(["eve3d", *map(str, args)], code, out.getvalue(), err.getvalue())


WORKFLOW_CORES = "-c1" if "PYTEST_XDIST_WORKER" in os.environ else "-c2"
"""The cores a workflow test's real run gets: under ``make test``'s workers (three on two
cores, each torch on one thread, tests/conftest.py) a worker's share, both cores when the test
runs alone. At ``-c2`` there, each run's two-thread training jobs competed with the other
workers for the cores (docs/development.md, "Tests"); jobs side by side stay tested by the
Slurm run (``--jobs 4``)."""


def snakemake(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    """Run this checkout's workflow (``workflow/Snakefile``) with ``args``."""
    return subprocess.run([sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), *args],
                          capture_output=True, text=True, cwd=cwd)


TINY_START = 3000
"""Exact surface samples as the sparse points of the tests' tiny generated scenes: SIFT finds
too little to triangulate in a few views of 160×120 or less (48 points on 12 views of the
object at 160×120, and a pretrain of 300 steps collapses from them), and these tests are about
the pipeline, not the start (tests/test_sfm.py is)."""


EVAL_SAMPLES = 100_000
"""Surface samples a side that the workflow tests score a tiny scene on: the default 500,000
took an evaluate job there from 3.6 to 5.0 s, and F moved by 0.0001 (eve3d on the tiny run)."""


def write_config(tmp_path: Path, **overrides) -> Path:
    """A workflow config in ``tmp_path``: the cpu preset, results under ``tmp_path``, the
    oracle on a 12-view 160×120 generated object (``tiny``), keys overridden by ``overrides``.
    Tiny scenes start from exact surface samples (``TINY_START``) and are scored on
    ``EVAL_SAMPLES`` samples a side. A key overridden by None is left out (the default's)."""
    config = {"preset": "cpu", "results": str(tmp_path / "results"), "methods": ["oracle"],
              "scenes": {"tiny": {"synthetic": {"kind": "object", "views": 12, "width": 160, "height": 120}}},
              "synthetic": {"surface_samples": TINY_START},
              "mesh": {"coarsen": 8}, "evaluate": {"samples": EVAL_SAMPLES}}
    config.update(overrides)
    config = {key: value for key, value in config.items() if value is not None}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


# -- photos --------------------------------------------------------------------------------

ORIENTATION = 274
"""The EXIF tag of the orientation; 6 ("upper-right", a phone held upright) asks a viewer to
rotate the stored pixels 90° clockwise."""


def save_sideways(upright: np.ndarray, path, quality: int = 95) -> None:
    """Store ``upright`` as a phone does: pixels turned 90° counter-clockwise, tag 6."""
    from PIL import Image

    exif = Image.Exif()
    exif[ORIENTATION] = 6
    Image.fromarray(np.ascontiguousarray(np.rot90(upright))).save(path, exif=exif, quality=quality)


# -- training --------------------------------------------------------------------------------

def joint_settings(**kw):
    """Short joint-stage settings for the 8-view 64×48 scene (``tiny_scene``): 60 iterations
    of ``pgsr``, densification from 10 to 50; ``kw`` overrides any field."""
    from eve3d.core.settings import DensifySettings, JointSettings

    base = dict(method="pgsr", iterations=60, sh_degree=1, sh_degree_interval=20, checkpoint_every=25,
                dn_from=20, mv_from=20, ncc_pixels=256, previews=1,
                densify=DensifySettings(refine_start=10, refine_every=10, refine_stop=50, reset_every=0))
    base.update(kw)
    return JointSettings(**base)


# -- multi-view geometry: a textured plane ------------------------------------------------

def plane_views(tilt: float = 0.0, xs: tuple[float, ...] = (0.0, 0.3)):
    """Views at x = ``xs`` of a textured plane 3 units ahead (tilted about y by ``tilt``
    rad), with the first (reference) view's exact depth: ``(list[View], depth)``."""
    import torch

    from eve3d.core.scene import Camera
    from eve3d.gaussians.render.projection import CameraTensors
    from eve3d.gaussians.views import View

    K = np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]])
    n = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])  # faces the cameras
    views, depth_ref = [], None
    for i, x in enumerate(xs):
        cam = Camera(f"{i}.png", 64, 48, K, np.eye(3), np.array([-x, 0.0, 0.0]))
        ct = CameraTensors.from_camera(cam, torch.float64)
        rays = ct.rays().numpy()
        centre = np.array([x, 0.0, 0.0])
        # plane n·X = −3 (X world); ray X = c + s·r: s = (−3 − n·c) / (n·r)
        s = (-3 - centre @ n) / (rays @ n)
        p = centre + rays * s[..., None]
        tex = 0.5 + 0.25 * np.sin(7 * p[..., 0]) * np.cos(5 * p[..., 1]) + 0.2 * np.sin(11 * p[..., 0] + 3 * p[..., 1])
        image = torch.tensor(np.repeat(tex[..., None], 3, -1))
        views.append(View(i, cam, ct, image))
        if i == 0:
            depth_ref = torch.tensor(s)  # z of the reference camera (R = I)
    return views, depth_ref


def plane_view_pair(tilt: float = 0.0):
    """Two views 0.3 apart along x of the plane of :func:`plane_views`: reference, neighbour, depth."""
    (ref, nbr), depth = plane_views(tilt)
    return ref, nbr, depth


def plane_seen_twice():
    """A textured plane z = 3 seen by two cameras; exact depth, normal, distance, images."""
    import torch

    from eve3d.core.scene import Camera
    from eve3d.gaussians.render.projection import CameraTensors

    K = np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]])
    ry = np.radians(8)
    R2 = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    cams = [Camera("a.png", 64, 48, K, np.eye(3), np.zeros(3)),
            Camera("b.png", 64, 48, K, R2, np.array([-0.4, 0.05, 0.0]))]
    out = []
    for cam in cams:
        rays = cam.pixel_rays()
        c = cam.center
        s = (3.0 - c[2]) / rays[..., 2]
        p = c + rays * s[..., None]
        tex = 0.5 + 0.25 * np.sin(3 * p[..., 0]) * np.cos(2 * p[..., 1]) + 0.2 * np.sin(5 * p[..., 0] + 1.3 * p[..., 1])
        depth = (p @ cam.R.T + cam.t)[..., 2]
        out.append((CameraTensors.from_camera(cam, torch.float64), torch.tensor(depth),
                    torch.tensor(np.repeat(tex[..., None], 3, -1))))
    normal_a = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand(48, 64, 3)
    return out, normal_a, torch.full((48, 64), 3.0, dtype=torch.float64)


# -- meshes --------------------------------------------------------------------------------

def split_long_edges(tri: np.ndarray, max_edge: float) -> np.ndarray:
    """Triangles (T,3,3) halved across their longest edge until no edge exceeds ``max_edge``."""
    while True:
        edges = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=-1)  # edge k: vertex k → k+1
        long = edges.max(axis=1) > max_edge
        if not long.any():
            return tri
        t, k = tri[long], edges[long].argmax(axis=1)
        a, b, c = (t[np.arange(len(t)), (k + j) % 3] for j in range(3))
        m = (a + b) / 2
        tri = np.concatenate([tri[~long], np.stack([a, m, c], 1), np.stack([m, b, c], 1)])


def tilted_plane(path: Path | None = None):
    """A camera at the origin (fx = fy = 50, 40×30, looking down +z) and a quad of the plane
    z = 2 + x/2 that covers the left half of its image (x ≤ 0), written to ``path`` when given.
    Returns the camera, the mesh and the plane's exact depth per pixel (the right half: 0)."""
    import open3d as o3d

    from eve3d.core.scene import Camera

    cam = Camera("v.png", 40, 30, np.array([[50.0, 0, 20], [0, 50, 15], [0, 0, 1]]), np.eye(3), np.zeros(3))
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector([[-3, -3, 0.5], [0, -3, 2], [0, 3, 2], [-3, 3, 0.5]]),
                                     o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))
    if path is not None:
        o3d.io.write_triangle_mesh(str(path), mesh)
    u = np.arange(40) + 0.5
    dx = (u - 20) / 50  # the ray (dx, dy, 1) meets z = 2 + x/2 at z = 2 / (1 - dx/2)
    depth = np.where(dx < 0, 2 / (1 - dx / 2), 0.0)
    return cam, mesh, np.tile(depth, (30, 1))


# -- stereo ----------------------------------------------------------------------------------

HITNET_DIRS = [Path(d) for d in (os.environ.get("EVE3D_HITNET_DIR"), Path.home() / ".cache/eve3d/hitnet",
                                   REPO.parent / "shared/models/hitnet_eth3d") if d]
"""Where the tests look for HITNet's ONNX exports (data, never in the repository):
``$EVE3D_HITNET_DIR``, ``~/.cache/eve3d/hitnet``, the shared models folder beside the
checkout. The tests that run the network read it from there only."""


def hitnet_model(size: str) -> Path:
    """HITNet's export at ``size`` (``HxW``); the test is skipped where it is not on the machine."""
    import pytest

    name = f"hitnet_eth3d_{size}.onnx"
    for folder in HITNET_DIRS:
        if (folder / name).is_file():
            return folder / name
    pytest.skip(f"{name}: HITNet's weights are not on this machine (looked in {', '.join(map(str, HITNET_DIRS))})")


def shifted_pair(disparity: int, h: int = 96, w: int = 128, grain: int = 4):
    """A textured pair with a constant disparity: random values upsampled ``grain`` times."""
    import cv2

    rng = np.random.default_rng(1)
    tex = cv2.resize(rng.integers(0, 255, (h // grain, (w + disparity) // grain, 3)).astype(np.uint8),
                     (w + disparity, h), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, disparity:])  # x_right = x_left − d


def dim(image: np.ndarray) -> np.ndarray:
    """A dark, low-contrast copy: 0–255 squeezed into 20–25 (a dim wall's texture)."""
    return (20 + image.astype(np.float32) * 5 / 255).round().astype(np.uint8)


def virtual_pairs():
    """``stereo.pairs: virtual``: the tests of a backend on the right views a model renders,
    whose figures were measured on those."""
    from eve3d.core.settings_stereo import RealPairSettings

    return RealPairSettings(pairs="virtual")


def sgbm_priors(scene, stereo_dir: Path, out: Path, preview: bool = True, check=None) -> None:
    """``stereo_depth --backend sgbm`` on the virtual pairs, with the default settings and ``check``."""
    from eve3d.priors.sgbm import SgbmStereo
    from eve3d.stereo import stereo_priors

    stereo_priors(scene, stereo_dir, out, SgbmStereo(), "SGBM", preview=preview, check=check, pairs=virtual_pairs())


def plane_pair(tilt_deg: float, disparity: float, margin: int = 48) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The ``plane`` kind's textured plane 2 units in front of a camera, turned by
    ``tilt_deg`` about the camera's x axis (depth changing from top to bottom), and its exact right view (ray-cast, 2×2
    supersampled, as the photos are) with a baseline giving ``disparity`` px at 2 units.
    Returns left, right (``margin`` columns wider), exact depth, fx and the baseline."""
    from eve3d.core.raycast import MeshRaycaster
    from eve3d.core.scene import Camera
    from eve3d.stereo import margin_camera, right_camera
    from eve3d.synth import KINDS, shade

    W, H = 320, 240
    f = 1.1 * W
    cam = Camera("a.png", W, H, np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]), np.eye(3), np.zeros(3))
    a = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    parts = KINDS["plane"].parts()
    mesh = parts[0].mesh
    mesh.vertices = type(mesh.vertices)(np.asarray(mesh.vertices) @ rot.T + [0, 0, 2.0])
    caster = MeshRaycaster([mesh])
    baseline = disparity * 2.0 / f
    supersample = np.stack(np.meshgrid([0.25, 0.75], [0.25, 0.75]), -1).reshape(-1, 2)

    def image(c):
        return np.clip(shade(parts, caster.cast(c, supersample), 0).mean(0) * 255 + 0.5, 0, 255).astype(np.uint8)

    right = image(margin_camera(right_camera(cam, baseline), margin))
    return image(cam), right, caster.cast(cam).depth, f, baseline


def stereo_scene(tmp_path: Path, disparity: int, baseline: float = 0.5):
    """One view (fx = 100) and its right view, a constant-disparity textured pair; the pair
    file is written only on request (see the test of its absence)."""
    import cv2

    from eve3d.core.scene import Camera, Scene
    from eve3d.stereo import PAIRS_FILE

    left, right = shifted_pair(disparity)
    cv2.imwrite(str(tmp_path / "v.png"), left[..., ::-1])
    (tmp_path / "stereo/right").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "stereo/right/v.png"), right[..., ::-1])
    (tmp_path / "stereo/alpha").mkdir()
    cv2.imwrite(str(tmp_path / "stereo/alpha/v.png"), np.full(left.shape[:2], 255, np.uint8))  # a model covering it all
    K = np.array([[100.0, 0, 64], [0, 100, 48], [0, 0, 1]])
    scene = Scene(tmp_path, [Camera("v.png", 128, 96, K, np.eye(3), np.zeros(3), image_path=tmp_path / "v.png")])
    pairs = {"views": {"v": {"baseline": baseline, "min_disparity": 0, "max_disparity": 3 * disparity, "margin": 0}}}
    return scene, lambda: (tmp_path / "stereo" / PAIRS_FILE).write_text(json.dumps(pairs))


# -- the report in a browser -----------------------------------------------------------------

CHROMIUM = Path("/usr/lib/chromium/chromium-headless-shell")
"""Debian's chromium-headless-shell (the set-up installs it), driven by Playwright."""
BENIGN_CONSOLE = ("cdn.tailwindcss.com should not be used in production",)
"""A warning Snakemake's report logs about its inlined stylesheet framework."""


def decodes(uri: str, folder: Path) -> bool:
    """Whether the raster image of a ``data:`` URI, or of a file a folder report holds at
    ``uri`` (relative to its ``folder``), decodes whole (PIL)."""
    import base64
    import io

    from PIL import Image

    head, _, data = uri.partition(",")
    try:
        if not uri.startswith("data:"):
            raw = (folder / uri).read_bytes()
        else:
            raw = base64.b64decode(data) if head.endswith(";base64") else data.encode()
        with Image.open(io.BytesIO(raw)) as im:
            im.load()
        return True
    except Exception:
        return False


def open_report(report: Path, screenshot: Path | None = None, views3d: bool = True) -> dict:
    """Load Snakemake's HTML report in headless Chromium (the single file, or the
    ``report.html`` of a folder report unpacked from ``--report FILE.zip``) and read what a
    person sees: the rows of the summary page's tables (``table.summary``: their cells), how
    many image results it holds and how many of them failed to decode once shown, with
    ``views3d`` the share of each 3D view's picture that is not its background (a folder
    report's: the single file cannot show them, README), and every resource that failed to
    load, console error, page error or request that left the file."""
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
        tables = page.frame_locator("iframe").locator("table.summary")
        expect(tables.first).to_be_visible()
        rows = []
        for table in tables.all():  # one a protocol, and one of the failed jobs
            header = table.locator("thead th").all_inner_texts()
            rows += [dict(zip(header, row.split("\t"))) for row in table.locator("tbody tr").all_inner_texts()]
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
            if not shown or not decodes(uri, report.parent):
                broken.append(path)
        if screenshot is not None and images:
            page.screenshot(path=str(screenshot.with_name(screenshot.stem + "_image.png")))
        seen3d = {}
        for path in [path for path, mime in results if views3d and "/scenes3d/" in path]:  # as a reader opens it
            page.evaluate("p => app.setView({content: 'html', contentPath: results[p].data_uri, resultPath: p})", path)
            view = page.frame_locator("iframe").locator(".gl-container canvas").first
            view.wait_for(timeout=60_000)
            page.wait_for_timeout(1000)
            seen3d[path] = nonbackground(view.screenshot(), VIEW3D_BACKGROUND)
            if screenshot is not None:
                page.screenshot(path=str(screenshot.with_name(f"{screenshot.stem}_3d_{Path(path).stem}.png")))
        browser.close()
    return {"rows": rows, "images": images, "broken": broken, "problems": problems, "views3d": seen3d}


def folder_report(archive: Path) -> Path:
    """The ``report.html`` of Snakemake's folder report ``archive`` (``--report FILE.zip``),
    unpacked beside it as ``make demo`` does: into the folder the archive is named after."""
    import zipfile

    zipfile.ZipFile(archive).extractall(archive.parent)
    return archive.with_suffix("") / "report.html"


VIEW3D_BACKGROUND = (205, 208, 218)
"""eve3d.report.views3d.BACKGROUND, as RGB."""


def nonbackground(png: bytes, background: tuple[int, int, int]) -> float:
    """The fraction of a screenshot's pixels more than 12 grey levels off ``background``."""
    import io

    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    return float((np.abs(image - background).max(-1) > 12).mean())


def pinhole_camera(width: int = 24, height: int = 18, dtype=None, tilt: float = 0.0):
    """A rasteriser camera (``CameraTensors``) at the origin looking down +z (optionally rotated
    about x), float64 unless ``dtype``."""
    import torch

    from eve3d.gaussians.render.projection import CameraTensors

    dtype = dtype or torch.float64
    c, s = math.cos(tilt), math.sin(tilt)
    R = torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=dtype)
    f = 1.1 * width
    return CameraTensors(R, torch.zeros(3, dtype=dtype), f, f * 1.05, width / 2 + 0.3, height / 2 - 0.2, width, height)


def random_gaussians(n: int, dtype=None, seed: int = 0, spread: float = 0.5, scale=(0.03, 0.12)):
    """``n`` random Gaussians (means, quats, scales, opacities, colours) in a cube of half-side
    ``spread`` 2.5 in front of :func:`pinhole_camera`, float64 unless ``dtype``."""
    import torch

    dtype = dtype or torch.float64
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) - 0.5) * 2 * spread + torch.tensor([0, 0, 2.5], dtype=dtype)
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = scale[0] + (scale[1] - scale[0]) * torch.rand(n, 3, generator=g, dtype=dtype)
    opacities = 0.2 + 0.75 * torch.rand(n, generator=g, dtype=dtype)
    colors = torch.rand(n, 3, generator=g, dtype=dtype)
    return means, quats, scales, opacities, colors

