"""The ``oracle`` depth source: exact depth of a scene with a known mesh, by ray casting.
An upper bound for every stereo backend."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_dir
from eve3d.core.maps import save_maps
from eve3d.core.raycast import MeshRaycaster
from eve3d.core.scene import Scene


def priors_from_mesh(scene: Scene, out_dir: Path, mesh: Path | None = None, preview: bool = True) -> None:
    """Write ``{view}.npz`` (depth, confidence = 1 where the ray hits, camera-space normal)."""
    mesh = mesh or scene.gt_mesh
    if mesh is None:
        raise Eve3dError(f"{scene.root}: the oracle depth source needs a ground-truth mesh (none is known for this scene)")
    caster = MeshRaycaster.from_file(mesh)
    with atomic_dir(out_dir) as tmp:
        for cam in tqdm(scene.cameras, desc="oracle depth", unit="view"):
            hits = caster.cast(cam)
            normal_cam = hits.normal @ cam.R.T
            save_maps(tmp / f"{cam.view_id}.npz", preview=preview, depth=hits.depth,
                      confidence=hits.valid.astype(np.float32), normal=normal_cam)
