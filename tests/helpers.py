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

def write_dtu_layout(scene, root: Path, scale_mat: np.ndarray) -> None:
    """Write a scene in the IDR/NeuS DTU layout, its cameras expressed in 'mm' = scale_mat·x."""
    (root / "image").mkdir(parents=True)
    (root / "mask").mkdir()
    inv = np.linalg.inv(scale_mat)
    arrays = {}
    for i, cam in enumerate(scene.cameras):
        shutil.copy(cam.image_path, root / "image" / f"{i:06d}.png")
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
