"""The ``synthetic`` protocol: a mesh against a known GT mesh in the scene's frame.

* **Visible GT.** The GT surface is sampled uniformly (``evaluate.samples`` points) and a
  sample counts when ``evaluate.min_views`` cameras (default 2: what multi-view
  reconstruction can triangulate) see it: in front of the camera, inside its image, and
  the ray from the camera's centre meets no GT surface before it (open3d ray casting, with
  occlusion). Completeness is measured over these samples only, so the inside of a closed
  object, the underside of a table and walls behind the cameras are never charged.
* **Exact distances.** Reconstruction samples → the GT *mesh* (accuracy, precision) and
  visible-GT samples → the reconstructed *mesh* (completeness, recall) are point-to-triangle
  distances (open3d's BVH query), so the result does not depend on how densely either
  surface is sampled; the sample count only sets the sampling noise and bounds the memory.
* **Crop.** The reconstruction outside the visible GT's bounding box grown by τ is left
  out (its share of the area is reported).
* **τ.** ``evaluate.tau`` when given, else ``tau_fraction`` × the diagonal of the visible
  GT's bounding box: the same rule for an object on a table and a room seen from inside.
* **Error maps.** ``precision.ply`` and ``recall.ply`` beside ``metrics.json``: the samples
  scored, coloured by distance (white 0, black from 3τ), as the T&T protocol writes them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_mesh
from eve3d.core.raycast import MeshRaycaster, seen_counts
from eve3d.core.surface import sample_surface
from eve3d.evaluate.common import COLOUR_RANGE, GIVEN_TAU, distance_metrics, mesh_distances, write_error_maps
from eve3d.evaluate.protocol import EvalInputs, Protocol

MAX_DRAWS = 8
"""Batches of ``evaluate.samples`` drawn at most per surface while too few samples are kept."""


def samples_where(mesh, keep, count: int, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Up to ``count`` uniform samples of ``mesh`` that ``keep`` (points → bool) accepts,
    drawn in batches of ``count`` (at most ``MAX_DRAWS``) so that a surface mostly outside
    the kept region still gets enough; and the fraction of the area that is kept."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    kept, drawn = [], 0
    for _ in range(MAX_DRAWS):
        batch = sample_surface(v, f, count, rng)
        kept.append(batch[keep(batch)])
        drawn += count
        if sum(map(len, kept)) >= count:
            break
    points = np.concatenate(kept)
    return points[:count], len(points) / drawn


def visible_surface_samples(gt_mesh, cameras, count: int, min_views: int,
                            rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Uniform samples of the GT surface that at least ``min_views`` cameras see, and the
    fraction of the GT's area they represent."""
    caster = MeshRaycaster([gt_mesh])
    return samples_where(gt_mesh, lambda p: seen_counts(caster, cameras, p, min_views) >= min_views, count, rng)


def evaluate_synthetic(inputs: EvalInputs) -> dict:
    """The protocol of the module docstring; distances in scene units."""
    settings, cameras = inputs.settings, inputs.scene.cameras
    if settings.min_views > len(cameras):
        raise Eve3dError(f"evaluate.min_views: {settings.min_views} cameras must see a GT point, "
                         f"the scene has {len(cameras)}")
    rng = np.random.default_rng(0)
    gt_mesh, recon_mesh = read_mesh(inputs.gt), read_mesh(inputs.reconstruction)
    gt, visible_fraction = visible_surface_samples(gt_mesh, cameras, settings.samples, settings.min_views, rng)
    if not len(gt):
        raise Eve3dError(f"{inputs.gt}: no part of the GT mesh is seen by the cameras of {inputs.scene.root}; "
                         f"is it in the same frame as the poses?")
    lo, hi = gt.min(axis=0), gt.max(axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    if settings.tau is not None:
        tau, rule = float(settings.tau), GIVEN_TAU
    else:
        tau = settings.tau_fraction * diagonal
        rule = f"{settings.tau_fraction:g} x visible-GT bounding-box diagonal ({diagonal:.5g})"
    recon, inside_fraction = samples_where(recon_mesh, lambda p: np.all((p >= lo - tau) & (p <= hi + tau), axis=1),
                                           settings.samples, rng)
    to_gt, to_recon = mesh_distances(gt_mesh, recon), mesh_distances(recon_mesh, gt)
    metrics = distance_metrics(to_gt, to_recon, tau)
    maps = write_error_maps(Path(inputs.out).parent, recon, to_gt, gt, to_recon, COLOUR_RANGE * tau)
    return {"tau": tau, "tau_rule": rule, **metrics, **maps, "n_recon": int(len(recon)), "n_gt": int(len(gt)),
            "visible_gt_fraction": visible_fraction, "visible_rule": f"seen by at least {settings.min_views} camera(s)",
            "crop": {"box_min": (lo - tau).tolist(), "box_max": (hi + tau).tolist(),
                     "rule": "visible-GT bounding box grown by tau", "recon_area_fraction_left_out": 1 - inside_fraction}}


PROTOCOL = Protocol("synthetic", "GT mesh: visible GT surface, exact point-to-triangle distances, F-score at τ",
                    "mesh", evaluate_synthetic, {"gt": "gt_mesh"}, default_of=("colmap",), own_poses=True,
                    unit="scene units")
