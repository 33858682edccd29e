"""The report's 3D view of a scene (``scenes3d/{scene}.html``): each method's mesh, its
precision and recall points coloured by distance on the error maps' scale, the GT surface
and the cameras, in one plotly figure a reader turns and zooms in the browser, offline
(plotly.js is embedded in the page).

Methods are switched on one view: a button per method shows its mesh and error points and
keeps the camera where the reader left it, so the same spot is compared; the legend toggles
each part on its own. What a page holds is reduced so that a browser turns it smoothly and
the report stays small: :data:`MESH_TRIANGLES` a mesh (vertex clustering), :data:`ERROR_POINTS`
an error map and :data:`GT_POINTS` of a GT point cloud (uniform subsets); the page's title says
how many of each it kept.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eve3d.core.colormap import hot_r, hot_r_fraction
from eve3d.core.scene import Camera

MESH_TRIANGLES = 40_000
"""Triangles a method's mesh (or a GT mesh) keeps on the page at most (vertex clustering)."""
ERROR_POINTS = 15_000
"""Points an error map (precision or recall) keeps on the page at most."""
GT_POINTS = 40_000
"""Points a GT point cloud (DTU's stl, T&T's ply) keeps on the page at most."""
METHOD_COLOURS = ("#9ecae9", "#ffbf79", "#88d27a", "#d6a5c9", "#d8b5a5", "#ff9d98", "#83bcb6", "#e0d6d0")
"""Each method's mesh colour, in the methods' order."""
LIGHTING = {"ambient": 0.55, "diffuse": 0.6, "specular": 0.05, "fresnel": 0.0}
"""Smooth shading (plotly's default): its ``flatshading`` draws every face dark in software
WebGL (headless Chromium's SwiftShader)."""
LIGHT = {"x": 1e5, "y": 1e5, "z": 1e5}
BACKGROUND = "rgb(205,208,218)"
"""Light blue grey: both ends of the error scale (white, black) stand out on it."""


@dataclass
class Reduced:
    """A mesh or point set as the page holds it, and how many it had."""

    vertices: np.ndarray
    faces: np.ndarray | None
    """(F, 3) triangles; None for points."""
    original: int
    """Triangles (or points) before the reduction."""

    @property
    def kept(self) -> int:
        return len(self.faces) if self.faces is not None else len(self.vertices)

    def note(self, what: str) -> str:
        unit = "triangles" if self.faces is not None else "points"
        if self.kept == self.original:
            return f"{what}: {self.kept:,} {unit}"
        return f"{what}: {self.kept:,} of {self.original:,} {unit}"


def reduced_surface(path: Path, triangles: int = MESH_TRIANGLES, points: int = GT_POINTS) -> Reduced:
    """The mesh at ``path`` decimated to ``triangles`` at most, or, for a file without
    triangles (a GT point cloud), a uniform subset of ``points`` of its points."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles):
        original = len(mesh.triangles)
        if original > triangles:  # vertex clustering: far quicker than quadric decimation (docs/results.md)
            voxel = float(np.sqrt(2 * mesh.get_surface_area() / triangles))  # a cell holds about two triangles
            for _ in range(4):
                reduced = mesh.simplify_vertex_clustering(voxel)
                if len(reduced.triangles) <= triangles:
                    break
                voxel *= float(np.sqrt(len(reduced.triangles) / triangles)) * 1.05
            mesh = reduced
        mesh.remove_unreferenced_vertices()
        return Reduced(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.triangles, np.int32), original)
    cloud = np.asarray(o3d.io.read_point_cloud(str(path)).points, np.float32)
    return Reduced(cloud[uniform_subset(len(cloud), points)], None, len(cloud))


def uniform_subset(n: int, count: int) -> np.ndarray:
    """Indices of ``count`` of ``n`` items at most, drawn uniformly (the same every time), in order."""
    return np.sort(np.random.default_rng(0).permutation(n)[:count])


def error_points(path: Path, count: int = ERROR_POINTS) -> tuple[Reduced, np.ndarray]:
    """An error map's points (a uniform subset of ``count``) and each one's distance as a
    fraction of the map's scale, read back from its colour."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    points, colours = np.asarray(cloud.points, np.float32), np.asarray(cloud.colors)
    keep = uniform_subset(len(points), count)
    return Reduced(points[keep], None, len(points)), hot_r_fraction(colours[keep]).astype(np.float32)


def frusta(cameras: Sequence[Camera], size: float) -> np.ndarray:
    """Line segments of a small pyramid per camera (apex at its centre, ``size`` deep), as
    one polyline with NaN breaks (N·16, 3)."""
    lines = []
    for cam in cameras:
        corners = np.array([[0, 0], [cam.width, 0], [cam.width, cam.height], [0, cam.height]], float)
        rays = np.c_[(corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy, np.ones(4)]
        base = cam.center + (rays * size) @ cam.R  # camera → world: Rᵀ·x, written as x·R
        centre = cam.center
        for a, b in zip(range(4), (1, 2, 3, 0)):
            lines += [centre, base[a], base[b], [np.nan] * 3]
    return np.array(lines, dtype=np.float32).reshape(-1, 3)


def scene_figure(scene: str, meshes: Mapping[str, Path], errors: Mapping[str, tuple[Path, Path]],
                 top: float | None, unit: str, gt: Path | None, cameras: Sequence[Camera],
                 frames: Mapping[str, np.ndarray] | None = None):
    """The plotly figure of the module docstring. ``meshes``: method → mesh; ``errors``:
    method → (precision.ply, recall.ply); ``frames``: method → the 4×4 transform from the
    frame its error maps and the GT are in to the scene's (T&T scores in the GT's frame;
    none: the scene's own); ``top``: the distance at the end of their colour
    scale, in ``unit``; ``gt``: the GT surface (a mesh or a point cloud)."""
    import plotly.graph_objects as go

    traces, owner, notes = [], [], []
    for k, (method, path) in enumerate(meshes.items()):
        mesh = reduced_surface(path)
        notes.append(mesh.note(method))
        own = method_traces(method, mesh, METHOD_COLOURS[k % len(METHOD_COLOURS)], errors.get(method, ()),
                            (frames or {}).get(method), top, unit)
        traces += own
        owner += [method] * len(own)
    if gt is not None:
        surface = reduced_surface(gt)
        notes.append(surface.note("GT"))
        traces.append(gt_trace(surface, next(iter((frames or {}).values()), None)))
        owner.append(None)
    if cameras:
        traces.append(cameras_trace(cameras))
        owner.append(None)
    methods = list(meshes)
    for trace, who in zip(traces, owner):  # the first method's mesh is what a reader sees first
        if who is not None and who != (methods[0] if methods else None):
            trace.visible = "legendonly"
    buttons = [{"label": method, "method": "restyle",
                "args": [{"visible": [_visible_on_button(t, who, method) for t, who in zip(traces, owner)]}]}
               for method in methods]
    fig = go.Figure(traces)
    fig.update_layout(
        title={"text": f"{scene}: {' · '.join(notes)}", "font": {"size": 12}},
        paper_bgcolor=BACKGROUND, margin={"l": 0, "r": 0, "t": 40, "b": 0}, height=760,
        scene={"aspectmode": "data", "bgcolor": BACKGROUND, "camera": first_view(cameras), "xaxis": {"visible": False},
               "yaxis": {"visible": False}, "zaxis": {"visible": False}},
        legend={"itemsizing": "constant", "groupclick": "toggleitem"}, uirevision="keep",
        updatemenus=[{"type": "buttons", "direction": "right", "x": 0, "y": 1.0, "xanchor": "left",
                      "buttons": buttons, "showactive": True}] if len(buttons) > 1 else [])
    return fig


def method_traces(method: str, mesh: Reduced, colour: str, errors: Sequence[Path], frame: np.ndarray | None,
                  top: float | None, unit: str) -> list:
    """A method's traces: its ``mesh`` in ``colour``, then its precision and recall points
    (``errors``, carried by ``frame`` into the scene's frame) coloured by distance up to ``top``."""
    import plotly.graph_objects as go

    scale = [[i / 16, f"rgb{tuple(int(255 * c) for c in hot_r(np.array([i / 16]))[0])}"] for i in range(17)]
    v, f = mesh.vertices, mesh.faces
    traces = [go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], name=f"{method} mesh",
                        color=colour, legendgroup=method, showlegend=True,
                        lighting=LIGHTING, lightposition=LIGHT, hoverinfo="name")]
    for side, ply in zip(("precision", "recall"), errors):
        points, fraction = error_points(ply)
        p = to_scene(points.vertices, frame)
        traces.append(go.Scatter3d(
            x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", name=f"{method} {side} errors", legendgroup=method,
            visible="legendonly",
            marker={"size": 1.6, "color": fraction * (top or 1.0), "colorscale": scale, "cmin": 0,
                    "cmax": top or 1.0, "showscale": True,  # shown traces' bars coincide
                    "colorbar": {"title": {"text": f"distance ({unit})" if top else "distance / scale"},
                                 "len": 0.6, "x": 0.01, "xanchor": "left", "y": 0.4}},  # left: the legend is right
            hoverinfo="name"))
    return traces


def gt_trace(surface: Reduced, frame: np.ndarray | None):
    """The GT ``surface``, a mesh or points carried by ``frame`` into the scene's frame, hidden at first."""
    import plotly.graph_objects as go

    v = to_scene(surface.vertices, frame)
    if surface.faces is not None:
        f = surface.faces
        return go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], name="GT",
                         color="#eeeeee", visible="legendonly", showlegend=True, lighting=LIGHTING,
                         lightposition=LIGHT, hoverinfo="name")
    return go.Scatter3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="markers", name="GT",
                        marker={"size": 1.2, "color": "#666666"}, visible="legendonly", hoverinfo="name")


def cameras_trace(cameras: Sequence[Camera]):
    """The cameras as frusta, sized to a twentieth of the spread of their centres."""
    import plotly.graph_objects as go

    centres = np.array([c.center for c in cameras])
    size = 0.05 * float(np.ptp(centres, axis=0).max() or 1.0)
    line = frusta(cameras, size)
    return go.Scatter3d(x=line[:, 0], y=line[:, 1], z=line[:, 2], mode="lines", name="cameras",
                        line={"color": "#333333", "width": 2}, hoverinfo="name")


def to_scene(points: np.ndarray, transform: np.ndarray | None) -> np.ndarray:
    """``points`` (N, 3) carried by the 4×4 ``transform`` (None: as they are)."""
    if transform is None:
        return points
    return (points @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)


def first_view(cameras: Sequence[Camera]) -> dict:
    """plotly's scene camera from the first camera's side, looking along its direction at
    the middle of the data, its image up as up (as the scene sheets show its photo first).
    The eye is in plotly's units (the data's half extent, from its centre)."""
    if not cameras:
        return {}
    look, up = cameras[0].R[2], -cameras[0].R[1]  # camera z and −y (image y points down), in the world
    return {"eye": dict(zip("xyz", map(float, -1.2 * look))), "up": dict(zip("xyz", map(float, up)))}


def _visible_on_button(trace, who: str | None, method: str):
    """A trace's visibility when ``method``'s button is pressed: its mesh shown, its error
    points in the legend (one click away), the other methods in the legend; the GT and
    cameras as they were."""
    if who is None:
        return trace.visible if trace.visible is not None else True
    if who != method:
        return "legendonly"
    return True if trace.type == "mesh3d" else "legendonly"


def write_scene_view(fig, out: Path) -> None:
    """``fig`` as a self-contained HTML page (plotly.js inside), written atomically."""
    from eve3d.core.fileio import atomic_path

    with atomic_path(out) as tmp:
        tmp.write_text(fig.to_html(include_plotlyjs=True, full_html=True, config={"displaylogo": False}))


def scene_view(layout, scene: str, methods: Sequence[str], unit: tuple[str, float], gt: Path | None,
               cameras: Sequence[Camera], out: Path) -> bool:
    """The page of ``scene`` at ``out`` from what its ``methods`` left in ``layout`` (their
    meshes, error maps and the scale in their metrics), its GT surface and cameras; ``unit``:
    the distances' unit as the tables show it and the factor to it. False (nothing written)
    when no method has a mesh."""
    import json

    meshes = {m: layout.mesh(scene, m) for m in methods if layout.mesh(scene, m).is_file()}
    if not meshes:
        return False
    errors, frames, top = {}, {}, None
    for method in meshes:
        folder = layout.method(scene, method)
        maps = (folder / "precision.ply", folder / "recall.ply")
        if all(p.is_file() for p in maps):
            errors[method] = maps
            try:
                record = json.loads(layout.metrics(scene, method).read_text())
            except (OSError, ValueError):
                continue  # no scale recorded (older results): the colour bar reads in fractions of it
            top = top or record.get("error_map_top")
            if "transformation" in record:  # T&T: ours → the GT's frame, where it scored
                frames[method] = np.linalg.inv(np.asarray(record["transformation"], dtype=np.float64))
    fig = scene_figure(scene, meshes, errors, top * unit[1] if top else None, unit[0],
                       gt if gt is not None and gt.is_file() else None, cameras, frames)
    write_scene_view(fig, out)
    return True
