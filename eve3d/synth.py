"""Procedural synthetic scenes with exact ground truth (``eve3d synth KIND OUT``).

Meshes are textured with solid (3D) textures and Lambertian shading under a fixed light, so
colours do not depend on the view, and rendered by open3d ray casting on the CPU. Each scene
mixes the cases stereo priors exist for: a textureless region (``flat``) and a repetitive
pattern (``tiles``), beside value-noise textures that SfM can match.

Kinds (``KINDS``): ``object`` (a DTU-like object on a table, cameras around and above it),
``room`` (a Meetingroom-like room, cameras on a loop inside it), ``vase`` (a hollow vase and a
box on the ground: surfaces no camera sees, inside the vase and under the box) and
``inside-room`` (the room seen from cameras clustered near its centre, looking outwards),
``dark-room`` (the same capture of the room with dark, low-contrast walls and ceiling) and
``plane`` (one textured plane 2 units in front of the cameras: the simplest geometry, where
a depth bias has nowhere to hide).

Output, laid out the way a user brings data:
``images/*.png``, ``sparse/0/`` (COLMAP model with the exact poses and the points SfM triangulates;
under ``gt/sparse/0/`` instead with ``images_only``), ``masks/`` (object scenes), ``gt/mesh.ply``
(the whole scene, hidden surfaces included: the evaluator finds what the cameras see) and
``eve3d_scene.json``.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.core.fileio import atomic_dir, write_image
from eve3d.core.io.colmap import triangulate_known_poses, write_colmap
from eve3d.core.io.loader import METADATA
from eve3d.core.raycast import MeshRaycaster, seen_by
from eve3d.core.scene import Camera, Scene, look_at
from eve3d.core.settings import SfmSettings, SyntheticSettings
from eve3d.core.surface import sample_surface
from eve3d.core.timing import phase

LIGHT = np.array([0.3, -0.5, 1.0]) / np.linalg.norm([0.3, -0.5, 1.0])


@dataclass
class Material:
    """Solid texture: 'noise' (value-noise fBm between two colours), 'tiles' (a checker of
    the given period, lightly modulated by noise) or 'flat' (one colour: textureless)."""

    pattern: str
    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 8.0
    """Noise frequency (cells per unit) or tile period (units)."""

    def albedo(self, p: np.ndarray, seed: int) -> np.ndarray:
        a, b = np.asarray(self.color_a), np.asarray(self.color_b)
        if self.pattern == "flat":
            return np.broadcast_to(a, p.shape).copy()
        if self.pattern == "tiles":
            cell = np.floor(p / self.scale + 0.5).astype(np.int64).sum(axis=-1) % 2
            w = cell[..., None] * 0.8 + 0.2 * fbm(p * 6.0 / self.scale, seed, octaves=2)[..., None]
            return a * (1 - w) + b * w
        w = np.clip((fbm(p * self.scale, seed) - 0.5) * 2.2 + 0.5, 0, 1)[..., None]
        return a * (1 - w) + b * w


LATTICE_KEYS = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9))
"""Each lattice axis's odd multiplier in the hash of a lattice point."""


def _mix(h: np.ndarray) -> np.ndarray:
    """A lattice point's combined key (uint64, changed in place) → uniform [0,1) (a splitmix64-style mix)."""
    with np.errstate(over="ignore"):
        h ^= h >> np.uint64(31)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(29)
    return (h >> np.uint64(11)).astype(np.float64) / float(2**53)


def value_noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Smooth trilinear value noise in [0,1) at points p (...,3). The hash of a lattice point
    XORs one key per axis, so each axis's two keys (and weights) are computed once for the
    eight corners."""
    i = np.floor(p).astype(np.int64)
    f = p - i
    f = f * f * (3 - 2 * f)
    with np.errstate(over="ignore"):
        keys = [[(i[..., axis] + d).astype(np.uint64) * key for d in (0, 1)] for axis, key in enumerate(LATTICE_KEYS)]
        salt = np.uint64(seed * 0x27D4EB2F165667C5 & (2**64 - 1))
    keys[2] = [k ^ salt for k in keys[2]]
    weights = [(1 - f[..., axis], f[..., axis]) for axis in range(3)]
    out = np.zeros(p.shape[:-1])
    for dx in (0, 1):
        for dy in (0, 1):
            key_xy, weight_xy = keys[0][dx] ^ keys[1][dy], weights[0][dx] * weights[1][dy]
            for dz in (0, 1):
                out += weight_xy * weights[2][dz] * _mix(key_xy ^ keys[2][dz])
    return out


def fbm(p: np.ndarray, seed: int, octaves: int = 4) -> np.ndarray:
    """Fractal sum of value noise, normalised to [0,1)."""
    total, amp, norm = np.zeros(p.shape[:-1]), 1.0, 0.0
    for k in range(octaves):
        total += amp * value_noise(p * 2.0**k, seed + 101 * k)
        norm += amp
        amp *= 0.5
    return total / norm


@dataclass
class Part:
    mesh: object
    """open3d legacy TriangleMesh."""
    material: Material
    foreground: bool = False
    """Counts as the object in masks (object scenes)."""


def _box(size, center):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(np.asarray(center) - np.asarray(size) / 2)
    return m


def _quad(corners):
    """An inward/outward agnostic rectangle from 4 corners (counter-clockwise)."""
    import open3d as o3d

    m = o3d.geometry.TriangleMesh()
    m.vertices = o3d.utility.Vector3dVector(np.asarray(corners, dtype=np.float64))
    m.triangles = o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]]))
    return m


def object_parts() -> list[Part]:
    """A DTU-like object (in the unit sphere) standing on a tiled table."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(0.32, resolution=48)
    sphere.translate([-0.35, 0.15, 0.28])  # parts sink into the table: one connected object
    torus = o3d.geometry.TriangleMesh.create_torus(0.28, 0.09, radial_resolution=64, tubular_resolution=24)
    torus.rotate(o3d.geometry.get_rotation_matrix_from_xyz([np.pi / 2, 0, 0.4]), center=[0, 0, 0])
    torus.translate([0.05, -0.35, 0.33])
    cylinder = o3d.geometry.TriangleMesh.create_cylinder(0.14, 0.75, resolution=48, split=4)
    cylinder.translate([0.42, 0.38, 0.375])
    return [
        Part(_box((3.0, 3.0, 0.1), (0, 0, -0.05)), Material("tiles", (0.85, 0.82, 0.75), (0.25, 0.3, 0.45), scale=0.2)),
        Part(sphere, Material("noise", (0.9, 0.5, 0.2), (0.2, 0.1, 0.05), scale=7.0), True),
        Part(torus, Material("noise", (0.2, 0.6, 0.3), (0.9, 0.9, 0.6), scale=9.0), True),
        Part(cylinder, Material("noise", (0.3, 0.3, 0.8), (0.95, 0.8, 0.8), scale=8.0), True),
        Part(_box((0.42, 0.36, 0.5), (0.45, -0.05, 0.25)), Material("flat", (0.75, 0.72, 0.7)), True),
    ]


def room_parts(dark: bool = False) -> list[Part]:
    """A Meetingroom-like box room with a table and furniture, seen from inside. ``dark``:
    walls and ceiling dark and of low contrast (colours at 30 %, their noise at a third of
    its contrast), the hard case for stereo matching."""
    import open3d as o3d

    X, Y, Z = 3.0, 2.5, 2.6
    surround = _dim if dark else (lambda m: m)
    wall = surround(Material("noise", (0.8, 0.75, 0.65), (0.35, 0.3, 0.25), scale=4.0))
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.2, resolution=32)
    sphere.translate([0.3, 0.2, 0.95])
    return [
        Part(_quad([(-X, -Y, 0), (X, -Y, 0), (X, Y, 0), (-X, Y, 0)]), Material("tiles", (0.8, 0.8, 0.78), (0.3, 0.25, 0.2), scale=0.5)),
        Part(_quad([(-X, -Y, Z), (-X, Y, Z), (X, Y, Z), (X, -Y, Z)]),
             surround(Material("noise", (0.9, 0.9, 0.88), (0.6, 0.6, 0.6), scale=2.0))),
        Part(_quad([(X, -Y, 0), (X, -Y, Z), (X, Y, Z), (X, Y, 0)]), surround(Material("flat", (0.82, 0.84, 0.86)))),
        Part(_quad([(-X, -Y, 0), (-X, Y, 0), (-X, Y, Z), (-X, -Y, Z)]), wall),
        Part(_quad([(-X, Y, 0), (X, Y, 0), (X, Y, Z), (-X, Y, Z)]),
             surround(Material("noise", (0.5, 0.6, 0.75), (0.15, 0.2, 0.3), scale=4.0))),
        Part(_quad([(-X, -Y, 0), (-X, -Y, Z), (X, -Y, Z), (X, -Y, 0)]), wall),
        Part(_box((1.6, 0.9, 0.08), (0.2, 0.1, 0.75)), Material("noise", (0.55, 0.35, 0.2), (0.3, 0.15, 0.05), scale=6.0)),
        Part(_box((1.3, 0.7, 0.71), (0.2, 0.1, 0.355)), Material("noise", (0.35, 0.2, 0.1), (0.6, 0.45, 0.3), scale=6.0)),
        Part(_box((0.6, 1.6, 0.9), (-2.4, -0.6, 0.45)), Material("noise", (0.6, 0.15, 0.15), (0.9, 0.6, 0.5), scale=5.0)),
        Part(_box((0.9, 0.5, 1.8), (2.3, 1.9, 0.9)), Material("tiles", (0.9, 0.9, 0.9), (0.2, 0.2, 0.25), scale=0.15)),
        Part(sphere, Material("noise", (0.9, 0.8, 0.2), (0.3, 0.2, 0.1), scale=10.0)),
    ]


def _dim(m: Material, level: float = 0.3, contrast: float = 1 / 3) -> Material:
    """``m`` darker (colours × ``level``) and of lower contrast (its second colour moved
    toward the first, keeping ``contrast`` of the difference)."""
    a, b = np.asarray(m.color_a) * level, np.asarray(m.color_b) * level
    return Material(m.pattern, tuple(a), tuple(a + contrast * (b - a)), m.scale)


def _lathe(profile: list[tuple[float, float]], segments: int = 64):
    """A surface of revolution about the z axis from a closed (r, z) profile whose first
    and last points lie on the axis (bottom and inner bottom)."""
    import open3d as o3d

    prof = np.asarray(profile, dtype=np.float64)
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    verts = np.stack([prof[:, None, 0] * np.cos(a), prof[:, None, 0] * np.sin(a),
                      np.broadcast_to(prof[:, None, 1], (len(prof), segments))], -1).reshape(-1, 3)
    tris = []
    for i in range(len(prof) - 1):
        for j in range(segments):
            v00, v01 = i * segments + j, i * segments + (j + 1) % segments
            v10, v11 = v00 + segments, v01 + segments
            tris += [[v00, v01, v11], [v00, v11, v10]]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(np.array(tris)))
    mesh.remove_duplicated_vertices()  # the poles
    mesh.remove_degenerate_triangles()
    return mesh


def vase_parts() -> list[Part]:
    """A hollow vase (walls 6 cm thick, open at the top) and a box standing on a ground
    plane: the inside of the vase is partly visible, the box's underside and the vase's
    bottom never are."""
    height, wall = 0.75, 0.06
    z = np.linspace(0.0, height, 16)
    outer = 0.2 + 0.14 * np.sin(np.pi * z / height * 0.9) - 0.04 * (z / height) ** 2
    profile = [(0.0, 0.0)] + [(r, h) for r, h in zip(outer, z)]
    profile += [(r - wall, h) for r, h in zip(outer[::-1], z[::-1]) if h >= wall] + [(0.0, wall)]
    vase = _lathe(profile)
    vase.translate([-0.3, 0.1, 0.0])
    return [
        Part(_box((3.0, 3.0, 0.1), (0, 0, -0.05)), Material("tiles", (0.8, 0.78, 0.72), (0.3, 0.32, 0.4), scale=0.2)),
        Part(vase, Material("noise", (0.75, 0.45, 0.25), (0.25, 0.15, 0.1), scale=8.0), True),
        Part(_box((0.4, 0.5, 0.35), (0.4, -0.25, 0.175)), Material("noise", (0.3, 0.5, 0.7), (0.9, 0.9, 0.8), scale=9.0),
             True),
    ]


def plane_parts() -> list[Part]:
    """One textured plane, z = 0, 8 × 8 units (wider than any camera's view of it)."""
    return [Part(_quad([(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)]),
                 Material("noise", (0.85, 0.7, 0.5), (0.2, 0.15, 0.25), scale=6.0))]


def object_cameras(n: int, width: int, height: int, rng: np.random.Generator, arc: float = 360.0) -> list[Camera]:
    """Cameras 3 units from the object on a spiral over ``arc`` degrees of azimuth whose
    elevation swings smoothly between 28° and 58°, so that neighbours overlap well."""
    f = 1.1 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    cams = []
    for i in range(n):
        frac = i / n if arc >= 360 else i / max(n - 1, 1)
        elev = np.radians(43 - 15 * np.cos(4 * np.pi * frac) + rng.uniform(-2, 2))
        azim = np.radians(arc) * (frac - (0 if arc >= 360 else 0.5)) + rng.uniform(-0.02, 0.02)
        center = 3.0 * np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
        R, t = look_at(center, np.array([0, 0, 0.2]) + rng.normal(0, 0.03, 3), np.array([0, 0, 1.0]))
        cams.append(Camera(f"{i:03d}.png", width, height, K, R, t))
    return cams


def room_cameras(n: int, width: int, height: int, rng: np.random.Generator, arc: float = 360.0) -> list[Camera]:
    """Cameras on a loop around the room (about 2 m across) looking along and across it, slightly downwards."""
    f = 0.6 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    cams = []
    for i in range(n):
        a = np.radians(arc) * i / n
        center = np.array([1.9 * np.cos(a) - 0.2, 1.4 * np.sin(a), 1.5 + rng.uniform(-0.15, 0.15)])
        yaw = a + np.pi / 2 * (1 if i % 2 else -0.3) + rng.uniform(-0.2, 0.2)
        target = center + np.array([np.cos(yaw), np.sin(yaw), -0.35 + rng.uniform(-0.1, 0.1)])
        R, t = look_at(center, target, np.array([0, 0, 1.0]))
        cams.append(Camera(f"{i:03d}.png", width, height, K, R, t))
    return cams


def inside_cameras(n: int, width: int, height: int, rng: np.random.Generator, arc: float = 360.0) -> list[Camera]:
    """Cameras clustered within 25 cm of a point near the room's centre, each looking
    outwards in its own direction (a capture from one spot: the camera radius is far
    smaller than the room)."""
    f = 0.6 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    cams = []
    for i in range(n):
        yaw = np.radians(arc) * i / n + rng.uniform(-0.1, 0.1)
        center = np.array([-0.6, -0.4, 1.55]) + rng.uniform(-0.25, 0.25, 3) * [1, 1, 0.4]
        pitch = -0.45 + 0.35 * np.sin(5 * yaw) + rng.uniform(-0.05, 0.05)
        target = center + np.array([np.cos(yaw), np.sin(yaw), pitch])
        R, t = look_at(center, target, np.array([0, 0, 1.0]))
        cams.append(Camera(f"{i:03d}.png", width, height, K, R, t))
    return cams


def plane_cameras(n: int, width: int, height: int, rng: np.random.Generator, arc: float = 360.0) -> list[Camera]:
    """Cameras 2 units above the plane on a circle of radius 0.5, each looking at the plane
    near the point below the circle's centre, tilted by up to about 15°."""
    f = 1.1 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    cams = []
    for i in range(n):
        a = np.radians(arc) * i / n
        center = np.array([0.5 * np.cos(a), 0.5 * np.sin(a), 2.0 + rng.uniform(-0.1, 0.1)])
        R, t = look_at(center, np.array([0.0, 0.0, 0.0]) + rng.normal(0, 0.05, 3) * [1, 1, 0], np.array([0, 1.0, 0]))
        cams.append(Camera(f"{i:03d}.png", width, height, K, R, t))
    return cams


@dataclass(frozen=True)
class Kind:
    """A synthetic scene: its parts, its camera layout and the scene kind it is read as."""

    parts: Callable[[], list[Part]]
    cameras: Callable[..., list[Camera]]
    scene_kind: str
    """``object`` (masks are written; object radius 1) or ``scene``."""


KINDS: dict[str, Kind] = {
    "object": Kind(object_parts, object_cameras, "object"),
    "room": Kind(room_parts, room_cameras, "scene"),
    "vase": Kind(vase_parts, object_cameras, "object"),
    "inside-room": Kind(room_parts, inside_cameras, "scene"),
    "dark-room": Kind(lambda: room_parts(dark=True), inside_cameras, "scene"),
    "plane": Kind(plane_parts, plane_cameras, "scene"),
}


SKY = ((0.83, 0.87, 0.92), (0.56, 0.70, 0.89))
"""The ``sky`` background's colour at the nadir and at the zenith: a pale blue, brighter
below, a faint gradient (about 30 grey levels across a view)."""
BACKDROP = Material("noise", (0.42, 0.48, 0.38), (0.80, 0.76, 0.66), scale=12.0)
"""The ``backdrop`` background: value noise on the sphere of directions (foliage, a far
street), about 4 px for its finest detail at the generated sizes."""


def background_colour(directions: np.ndarray, kind: str, seed: int) -> np.ndarray:
    """The colour (N, 3) of ``kind`` (``BACKGROUNDS``) seen along unit ``directions`` (N, 3):
    it depends on the direction alone, as a background at infinity does."""
    if kind == "sky":
        up = (directions[:, 2:3] + 1) / 2
        return np.asarray(SKY[0]) * (1 - up) + np.asarray(SKY[1]) * up
    if kind == "backdrop":
        return BACKDROP.albedo(directions, seed + 104729)
    return np.zeros_like(directions)


def shade(parts: list[Part], hits, seed: int, background: str = "black") -> np.ndarray:
    """Lambertian colour under a fixed light (view independent); ``background``: what a ray
    that meets no surface sees (``BACKGROUNDS``)."""
    rgb = np.zeros(hits.depth.shape + (3,))
    if background != "black":
        rgb[~hits.valid] = background_colour(hits.direction[~hits.valid], background, seed)
    for k, part in enumerate(parts):
        sel = hits.geometry == k
        if sel.any():
            albedo = part.material.albedo(hits.points[sel], seed + 7919 * k)
            rgb[sel] = albedo * (0.35 + 0.65 * np.clip(hits.normal[sel] @ LIGHT, 0, 1))[:, None]
    return rgb


def surface_points(mesh, cams: list[Camera], caster: MeshRaycaster, count: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, list[np.ndarray]]:
    """A stand-in for SfM points: surface samples seen (unoccluded) by at least two views."""
    pts = sample_surface(np.asarray(mesh.vertices), np.asarray(mesh.triangles), 4 * count, rng)
    seen = np.zeros((len(pts), len(cams)), dtype=bool)
    for ci, idx in seen_by(caster, cams, pts):
        seen[idx, ci] = True
    keep = np.flatnonzero(seen.sum(axis=1) >= 2)[:count]
    return pts[keep], [np.flatnonzero(seen[i]) for i in keep]


def point_colors(parts: list[Part], caster: MeshRaycaster, cams: list[Camera], pts: np.ndarray,
                 pviews: list[np.ndarray], seed: int) -> np.ndarray:
    """Shaded colour of each sparse point as its first observing view sees it."""
    colors = np.zeros((len(pts), 3), np.uint8)
    first = np.array([v[0] for v in pviews])
    for ci, cam in enumerate(cams):
        sel = first == ci
        if sel.any():
            hits = caster.cast_uv(cam, cam.project(pts[sel])[0])
            colors[sel] = np.clip(shade(parts, hits, seed) * 255 + 0.5, 0, 255).astype(np.uint8)
    return colors


def generate(kind: str, out: Path, views: int = 32, width: int = 320, height: int = 240, seed: int = 0,
             images_only: bool = False, supersample: int = 2, arc: float = 360.0, matcher: str = "exhaustive",
             surface_samples: int = 0, background: str = "black", capture: bool = False) -> Path:
    """Render the synthetic scene ``kind`` into ``out`` (written atomically); ``arc`` limits
    the cameras' azimuth range in degrees (a DTU-like front arc for object scenes); ``background``:
    what the photos show where no surface is (``BACKGROUNDS``; the ground truth is the same).

    The sparse points are what a user's SfM gives for known poses: features of the rendered
    photos matched (``matcher``: ``exhaustive`` or ``sequential``, the cameras' order) and
    triangulated with pycolmap, outliers included (``eve3d.core.io.colmap.triangulate_known_poses``).
    ``surface_samples`` > 0 puts that many exact surface samples in their place instead: a
    benchmark's fixed model size (``eve3d bench training``), never a method's input.
    ``capture``: the scene as a user brings a posed capture (a COLMAP text model beside the
    images, no masks, no ``eve3d_scene.json``: read as any COLMAP folder), its GT mesh in
    ``gt/mesh.ply`` for a config's ``gt_mesh``."""
    import open3d as o3d

    if kind not in KINDS:
        raise ValueError(f"unknown synthetic scene kind {kind!r}; choose one of {', '.join(KINDS)}")
    rng = np.random.default_rng(seed)
    spec = KINDS[kind]
    parts = spec.parts()
    cams = spec.cameras(views, width, height, rng, arc)
    caster = MeshRaycaster([p.mesh for p in parts])
    grid = (np.arange(supersample) + 0.5) / supersample
    offsets = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    with atomic_dir(out) as tmp:
        for cam in tqdm(cams, desc=f"synth {kind}", unit="view"):
            with phase("render views"):
                hits = caster.cast(cam, offsets)
                rgb = shade(parts, hits, seed, background).mean(axis=0)
                if spec.scene_kind == "object":
                    fg = np.isin(caster.cast(cam).geometry, [k for k, p in enumerate(parts) if p.foreground])
            write_image(tmp / "images" / cam.name, np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8))
            if spec.scene_kind == "object" and not capture:
                write_image(tmp / "masks" / cam.name, (fg * 255).astype(np.uint8))
        mesh = o3d.geometry.TriangleMesh()
        for part in parts:
            mesh += part.mesh
        with phase("sparse points"):
            if surface_samples:
                pts, pviews = surface_points(mesh, cams, caster, surface_samples, rng)
                colors = point_colors(parts, caster, cams, pts, pviews, seed)
            else:  # one thread: a benchmark's sparse points come out the same each run
                pts, colors, pviews = triangulate_known_poses(cams, tmp / "images", tmp / "sfm",
                                                              SfmSettings(matcher=matcher, seed=seed, threads=1))
        scene = Scene(root=out, cameras=cams, points=pts, point_colors=colors, point_views=pviews)
        write_colmap(scene, tmp / ("gt/sparse/0" if images_only else "sparse/0"), binary=not capture)
        (tmp / "gt").mkdir(exist_ok=True)
        o3d.io.write_triangle_mesh(str(tmp / "gt" / "mesh.ply"), mesh)
        if capture:
            return out
        meta = {"kind": spec.scene_kind, "gt_mesh": "gt/mesh.ply",
                "generator": {"kind": kind, "views": views, "width": width, "height": height, "seed": seed,
                              "arc": arc, "background": background}}
        if spec.scene_kind == "object":
            meta["object_radius"] = 1.0
        (tmp / METADATA).write_text(json.dumps(meta, indent=2))
    return out


def run_synth(settings: SyntheticSettings, *, kind: str, out: Path, images_only: bool = False,
              capture: bool = False) -> None:
    """The ``synth`` stage: the generated scene ``kind``, sized by ``settings``, into ``out``
    (``capture``: as a user's posed capture, :func:`generate`)."""
    with phase("generate"):
        generate(kind, Path(out), views=settings.views, width=settings.width, height=settings.height,
                 seed=settings.seed, images_only=images_only, arc=settings.arc,
                 surface_samples=settings.surface_samples, background=settings.background, capture=capture)
    print(f"wrote {out}")
