"""``python -m eve3d.tools.sky_cover SCENE MESH...``: how much of each mesh hangs in the sky.

A photo's pixel whose ray misses the measured scene (``eve3d.core.hull``, grown by the
training's ``train.sky_margin``) sees beyond it: a sky, a far background. Any mesh the ray
meets there is surface that no sparse point measured, the sheet a model leaves where it
painted the sky at a finite depth. Printed per mesh: the share of those pixels, over every
view, that the mesh covers, and the views where it covers more than 1 %.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.core.hull import measured_hull
from eve3d.core.io.loader import load_scene
from eve3d.core.settings import TrainSettings

WIDTH = 320
"""Each view is cast at about this width: the figure is a share of pixels, not a detail."""
SHEET = 0.01
"""A view carries a sheet where the mesh covers more than this share of its sky pixels."""


def sky_cover(scene, mesh_path: Path, margin: float) -> tuple[float, int]:
    """(share of the beyond pixels of every view that the mesh covers, views above SHEET)."""
    import open3d as o3d

    hull = measured_hull(scene, margin)
    if hull is None:
        raise SystemExit(f"{scene.root}: no measured hull (a room seen from inside, or no sparse points)")
    raycast = o3d.t.geometry.RaycastingScene()
    raycast.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(str(mesh_path))))
    covered = beyond = sheets = 0
    for cam in scene.cameras:
        cam = cam.scaled(min(1.0, WIDTH / cam.width))
        missed = hull.missed(cam)
        directions = cam.pixel_rays()[missed]
        if not len(directions):
            continue
        rays = np.concatenate([np.broadcast_to(cam.center, directions.shape), directions], axis=1)
        hit = np.isfinite(raycast.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy())
        covered, beyond = covered + hit.sum(), beyond + len(hit)
        sheets += hit.mean() > SHEET
    return covered / max(beyond, 1), sheets


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="the scene's folder (for photos: the sfm stage's output)")
    parser.add_argument("meshes", type=Path, nargs="+")
    parser.add_argument("--margin", type=float, default=TrainSettings().sky_margin)
    args = parser.parse_args(argv)
    try:
        scene = load_scene(args.scene, check_images=False)
        missing = [str(path) for path in args.meshes if not path.is_file()]
        if missing:
            raise Eve3dError(f"{', '.join(missing)}: mesh not found")
    except Eve3dError as e:
        parser.error(str(e))  # the message and the usage, exit 2
    print(f"| mesh | sky pixels covered | views with a sheet (of {len(scene.cameras)}) |\n|---|---|---|")
    for path in args.meshes:
        share, sheets = sky_cover(scene, path, args.margin)
        print(f"| {path} | {100 * share:.1f} % | {sheets} |")


if __name__ == "__main__":
    main()
