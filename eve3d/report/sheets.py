"""The report's scene sheets (``scenes/{scene}/{method}.png``): one per scene and method, the
photo of its first view, the stereo prior, the refined prior D̂ (methods that learn it), the
rendered depth, normals and alpha, the environment at infinity behind the Gaussians (what was
taken for sky), the shaded mesh, and the precision / recall error maps (the points
scored, coloured by distance, seen along z) or the held-out renders beside their photos."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core.layout import ENVIRONMENT_FILE, HELD_OUT_DIR, MESH_VIEWS_DIR, Layout
from eve3d.report.charts import pyplot, save_figure

HELD_OUT_SHOWN = 8
"""Held-out views a scene sheet shows at most (render beside photo), in view order."""

ERROR_MAP_PIXELS = 240
"""Longest side, in pixels, of an error map's picture on a scene sheet."""

ERROR_MAP_BACKGROUND = (0.8, 0.8, 0.88)
"""Where no scored point falls: a light blue grey, off the white–black scale."""


def error_map(path: Path) -> np.ndarray | None:
    """An error map (``precision.ply`` / ``recall.ply``: points coloured by distance, already
    thinned by ``evaluate.common.write_error_maps``) seen from above, along −z: an RGB image
    in which each pixel takes the colour of its highest point; None when the map is empty.
    Drawn as an image rather than as 200,000 matplotlib markers, which are slow to draw
    (docs/results.md, "Figures behind the code's choices")."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    points, colours = np.asarray(cloud.points), np.asarray(cloud.colors)
    if not len(points):
        return None
    low, extent = points[:, :2].min(0), np.ptp(points[:, :2], axis=0)
    scale = (ERROR_MAP_PIXELS - 1) / max(extent.max(), 1e-12)
    width, height = (np.floor(extent * scale).astype(int) + 1)
    col, row = np.floor((points[:, :2] - low) * scale).astype(int).T
    row = height - 1 - row  # +y up, as on a plot
    pixel = row * width + col
    order = np.lexsort((-points[:, 2], pixel))  # by pixel, the highest point first
    first = order[np.r_[True, pixel[order][1:] != pixel[order][:-1]]]
    image = np.empty((height * width, 3))
    image[:] = ERROR_MAP_BACKGROUND
    image[pixel[first]] = colours[first]
    return image.reshape(height, width, 3)


def scene_panels(layout: Layout, scene: str, method: str, photo: Path | None, backend: str) -> list[tuple[str, object]]:
    """(title, image path or error-map image) of one scene and method, those that exist."""
    folder = layout.method(scene, method)
    candidates = []
    if photo is not None:  # the maps of the photo's view
        view = photo.stem
        candidates = [("photo", photo),
                      ("stereo prior D* (the scene's)", layout.priors(scene, backend) / f"{view}.depth.png"),
                      ("refined prior D̂", layout.learned_priors(scene, method) / f"{view}.depth.png"),
                      ("rendered depth", layout.depth(scene, method) / f"{view}.depth.png"),
                      ("rendered normals", layout.depth(scene, method) / f"{view}.normal.png"),
                      ("rendered alpha (black: the environment's, not fused)",
                       layout.depth(scene, method) / f"{view}.confidence.png")]
    candidates.append(("environment at infinity (azimuth across, zenith on top)",
                       folder / Path(ENVIRONMENT_FILE).with_suffix(".png")))
    candidates.append(("shaded mesh", folder / MESH_VIEWS_DIR / "overview.png"))
    panels = [(title, path) for title, path in candidates if path.is_file()]
    held = sorted((folder / HELD_OUT_DIR).glob("*.png"))
    panels += [(f"held out {path.stem}: render | photo", path) for path in held[:HELD_OUT_SHOWN]]
    for name in ("precision", "recall"):
        if (folder / f"{name}.ply").is_file():
            image = error_map(folder / f"{name}.ply")
            if image is not None:
                panels.append((f"{name} errors (white 0, black ≥ 3τ; DTU 10 mm), along z", image))
    return panels


def scene_sheet(panels: list[tuple[str, object]], title: str, out: Path) -> None:
    """The panels side by side, two rows when there are many."""
    from eve3d.core.fileio import read_image

    cols = min(4, max(1, len(panels)))
    rows = max(1, -(-len(panels) // cols))
    fig, axes = pyplot().subplots(rows, cols, figsize=(3.2 * cols, 2.7 * rows + 0.4), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (name, item) in zip(axes.ravel(), panels):
        ax.imshow(item if isinstance(item, np.ndarray) else read_image(Path(item)))
        ax.set_title(name, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, out, dpi=90)
