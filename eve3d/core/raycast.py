"""Exact depth and normals of a triangle mesh seen by a ``Camera`` (open3d ray casting).

Used to render synthetic scenes and as the ``oracle`` depth source.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eve3d.core.chunking import chunks
from eve3d.core.scene import Camera


@dataclass
class Hits:
    """Per-ray results; arrays are shaped like the rays' leading dimensions."""

    depth: np.ndarray
    """Camera z of the hit (0 where the ray misses)."""
    normal: np.ndarray
    """World-space unit face normal, flipped to face the camera (0 on a miss)."""
    geometry: np.ndarray
    """Index of the mesh part hit (-1 on a miss)."""
    points: np.ndarray
    """World-space hit points."""
    triangle: np.ndarray
    """Index of the triangle hit within its part (-1 on a miss)."""
    direction: np.ndarray
    """World-space unit direction of each ray (what a miss sees of the background)."""

    @property
    def valid(self) -> np.ndarray:
        return self.geometry >= 0


class MeshRaycaster:
    """A set of triangle meshes (parts) to cast camera rays against."""

    def __init__(self, parts: list) -> None:
        import open3d as o3d

        self._scene = o3d.t.geometry.RaycastingScene()
        ids = []
        for mesh in parts:
            tmesh = o3d.t.geometry.TriangleMesh.from_legacy(mesh) if isinstance(mesh, o3d.geometry.TriangleMesh) else mesh
            ids.append(self._scene.add_triangles(tmesh))
        self._part_of_id = np.full(max(ids) + 1, -1, dtype=np.int64)  # open3d geometry id → part index
        self._part_of_id[ids] = np.arange(len(ids))

    @classmethod
    def from_file(cls, path: str | Path) -> MeshRaycaster:
        from eve3d.core.fileio import read_mesh

        return cls([read_mesh(Path(path))])

    def cast(self, cam: Camera, pixel_offsets: np.ndarray | None = None) -> Hits:
        """One ray per pixel through its centre (arrays (H,W,...)), or one per pixel and
        offset (dx,dy) within the pixel in ``pixel_offsets`` (arrays (S,H,W,...))."""
        offsets = np.array([[0.5, 0.5]]) if pixel_offsets is None else np.asarray(pixel_offsets)
        u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
        uv = np.stack([u[None] + offsets[:, 0, None, None], v[None] + offsets[:, 1, None, None]], axis=-1)
        hits = self.cast_uv(cam, uv)
        if pixel_offsets is None:
            hits = Hits(hits.depth[0], hits.normal[0], hits.geometry[0], hits.points[0], hits.triangle[0],
                        hits.direction[0])
        return hits

    def hit_distances(self, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Ray parameter t of the first hit of each ray origin + t·direction (inf on a miss):
        the light query when only occlusion matters."""
        import open3d as o3d

        rays = np.empty((len(directions), 6), dtype=np.float32)
        rays[:, :3], rays[:, 3:] = origin, directions
        return self._scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()

    def cast_uv(self, cam: Camera, uv: np.ndarray) -> Hits:
        """Rays through continuous pixel coordinates ``uv`` (...,2) (pixel centres at +0.5)."""
        import open3d as o3d

        uv = np.asarray(uv, dtype=np.float64)
        pix = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
        # Directions with camera z = 1, so the ray parameter of a hit is its camera depth.
        dirs = (pix @ np.linalg.inv(cam.K).T @ cam.R).reshape(-1, 3)
        origins = np.broadcast_to(cam.center, dirs.shape)
        rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=-1).astype(np.float32))
        out = self._scene.cast_rays(rays)
        t = out["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(t)
        geom = np.where(hit, self._part_of_id[np.where(hit, out["geometry_ids"].numpy().astype(np.int64), 0)], -1)
        normal = out["primitive_normals"].numpy().astype(np.float64)
        normal = np.where((np.sum(normal * dirs, axis=1) > 0)[:, None], -normal, normal)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        depth = np.where(hit, t, 0.0)
        points = cam.center + dirs * depth[:, None]
        triangle = np.where(hit, out["primitive_ids"].numpy().astype(np.int64), -1)
        shape = uv.shape[:-1]
        unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        return Hits(depth.reshape(shape), np.where(hit[:, None], normal, 0).reshape(shape + (3,)),
                    geom.reshape(shape), points.reshape(shape + (3,)), triangle.reshape(shape), unit.reshape(shape + (3,)))


def seen_by(caster: MeshRaycaster, cams: list[Camera], points: np.ndarray, stop_at: int | None = None,
            rel_tol: float = 1e-4):
    """Yield (camera index, indices of the points it sees): a camera sees a point that lies
    in front of it, inside its image, with no surface more than ``rel_tol`` of the way
    along the ray from its centre (a ray that meets nothing at all passed a triangle edge:
    seen). Points already seen by ``stop_at`` cameras are not tested against the rest.
    Each camera projects and casts a chunk of points at a time (:mod:`eve3d.core.chunking`; a
    ray's results alone are 32 bytes)."""
    points = np.asarray(points, dtype=np.float64)
    count = np.zeros(len(points), dtype=np.int64)
    for ci, cam in enumerate(cams):
        todo = np.arange(len(points)) if stop_at is None else np.flatnonzero(count < stop_at)
        seen = []
        for part in chunks(len(todo)):
            part = todo[part]
            part = part[cam.in_image(*cam.project(points[part]))]
            # Rays from the centre with the point at t = 1.
            seen.append(part[caster.hit_distances(cam.center, points[part] - cam.center) >= 1 - rel_tol])
        seen = np.concatenate(seen) if seen else np.zeros(0, dtype=np.int64)
        count[seen] += 1
        yield ci, seen


def seen_counts(caster: MeshRaycaster, cams: list[Camera], points: np.ndarray, stop_at: int | None = None) -> np.ndarray:
    """How many of ``cams`` see each point (at most ``stop_at``), see ``seen_by``."""
    count = np.zeros(len(points), dtype=np.int64)
    for _, seen in seen_by(caster, cams, points, stop_at):
        count[seen] += 1
    return count
