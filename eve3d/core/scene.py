"""The one scene/camera type every stage shares.

Conventions (DESIGN §5): OpenCV/COLMAP cameras (x right, y down, z forward), world-to-camera
``x_cam = R @ x_world + t``, intrinsics ``K`` in pixels with pixel centres at +0.5.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

SceneKind = Literal["object", "scene"]


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of an OpenCV camera at ``eye`` looking at ``target``, ``up``
    pointing up in its image."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ eye


@dataclass
class Camera:
    """One posed pinhole view."""

    name: str
    """Image file name relative to the scene's image folder; its stem is the view id."""
    width: int
    height: int
    K: np.ndarray
    """3×3 intrinsics in pixels (skew kept when a dataset has it, e.g. DTU)."""
    R: np.ndarray
    """3×3 world-to-camera rotation."""
    t: np.ndarray
    """3-vector world-to-camera translation."""
    image_path: Path | None = None
    mask_path: Path | None = None
    """Foreground mask (white = object), when the dataset has one (DTU)."""

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)

    @property
    def view_id(self) -> str:
        return Path(self.name).stem

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def world_to_camera(self) -> np.ndarray:
        """4×4 world-to-camera matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def projection(self) -> np.ndarray:
        """3×4 projection matrix K [R | t]."""
        return self.K @ self.world_to_camera[:3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N,3) → pixel coordinates (N,2) and camera-space depth z (N,)."""
        cam = points @ self.R.T + self.t
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = cam @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, z

    def in_image(self, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Which projections (from ``project``) lie in front of the camera and inside the image."""
        with np.errstate(invalid="ignore"):
            return (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < self.width) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height)

    def pixel_rays(self, rows: slice = slice(None)) -> np.ndarray:
        """World-space ray directions (H,W,3) through pixel centres, scaled so that a
        point at ray parameter s has camera depth z = s; of the image rows ``rows`` only
        when given (the same values: the products go row by row either way)."""
        u, v = np.meshgrid(np.arange(self.width) + 0.5, (np.arange(self.height) + 0.5)[rows])
        pix = np.stack([u, v, np.ones_like(u)], axis=-1)
        cam_dirs = pix @ np.linalg.inv(self.K).T
        return cam_dirs @ self.R

    def backproject(self, depth: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
        """Depth map (H,W) of camera z → world points (H,W,3); of its rows ``rows`` only
        when given (float64: 24 bytes a pixel, so a large image goes a band at a time)."""
        return self.center + self.pixel_rays(rows) * depth[rows][..., None]

    def scaled(self, factor: float) -> Camera:
        """The same view at image size × factor (training at a reduced resolution); the
        pixel-centre convention is preserved because K scales about the image corner."""
        K = self.K.copy()
        K[:2] *= factor
        return replace(self, K=K, width=round(self.width * factor), height=round(self.height * factor))


@dataclass
class Scene:
    """A posed image set, whatever format it came from (COLMAP, DTU, T&T, synthetic)."""

    root: Path
    """Dataset folder the scene was read from."""
    cameras: list[Camera]
    kind: SceneKind = "scene"
    """'object' (DTU-like, object in a unit sphere) or 'scene' (rooms, outdoor scenes)."""
    points: np.ndarray | None = None
    """Sparse 3D points (N,3), world coordinates (SfM points or a synthetic stand-in)."""
    point_colors: np.ndarray | None = None
    """uint8 RGB (N,3) of the sparse points."""
    point_views: list[np.ndarray] | None = None
    """For each sparse point, the indices into ``cameras`` that observe it."""
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    """4×4 map from these (normalised) coordinates to the dataset's original units, e.g.
    DTU's ``scale_mat``; identity when the scene was not normalised."""
    gt_mesh: Path | None = None
    """Ground-truth surface, when known (synthetic scenes, T&T ``Scene.ply``)."""
    extras: dict = field(default_factory=dict)
    """Format-specific files, e.g. T&T alignment and crop files."""

    @property
    def center(self) -> np.ndarray:
        """Mean camera centre."""
        return np.mean([c.center for c in self.cameras], axis=0)

    @property
    def radius(self) -> float:
        """1.1 × the largest distance of a camera centre from their mean (DESIGN §5)."""
        centers = np.array([c.center for c in self.cameras])
        return 1.1 * float(np.max(np.linalg.norm(centers - self.center, axis=1)))

    @property
    def object_radius(self) -> float:
        """Size of the 'normalised units' object-scene settings are given in: 1 when the
        scene is already normalised (DTU, synthetic objects), else the radius that holds
        95% of the :meth:`reliable_points` around their median."""
        if "object_radius" in self.extras:
            return float(self.extras["object_radius"])
        points = self.reliable_points()
        if points is not None and len(points) >= 10:
            d = np.linalg.norm(points - np.median(points, axis=0), axis=1)
            return float(np.quantile(d, 0.95))
        return self.radius / 3.0

    def reliable_points(self, views: int = 3, enough: int = 50) -> np.ndarray | None:
        """The sparse points seen in at least ``views`` images when there are ``enough`` of
        them, else all: SfM's two-view points are its least reliable (on the generated vase,
        triangulated: the 95 % radius of all points 2.7, of those in ≥ 3 views 1.5, of the
        object 1.5)."""
        return None if self.points is None else self.points[self.reliable(views, enough)]

    def reliable(self, views: int = 3, enough: int = 50) -> np.ndarray:
        """Which sparse points :meth:`reliable_points` keeps (a boolean mask)."""
        n = 0 if self.points is None else len(self.points)
        if self.point_views is None or views <= 2:  # SfM triangulates from two views at least
            return np.ones(n, bool)
        seen = np.array([len(v) >= views for v in self.point_views], bool)
        return seen if seen.sum() >= enough else np.ones(n, bool)

    def isolated(self, views: int = 3, quantile: float = 0.99) -> np.ndarray:
        """Which sparse points are outliers of the reconstruction (a boolean mask): seen in
        fewer than ``views`` images and farther from every :meth:`reliable_points` point
        than ``quantile`` of those lie from their nearest neighbour. On the generated object
        such points hang below the table's edge, where a black background lets the
        Gaussians grown from them stay (docs/results.md, "Floaters")."""
        from scipy.spatial import cKDTree

        reliable = self.reliable(views)
        if self.points is None or reliable.all() or reliable.sum() < 2:
            return np.zeros(0 if self.points is None else len(self.points), bool)
        tree = cKDTree(self.points[reliable])
        spacing = np.quantile(tree.query(self.points[reliable], k=2)[0][:, 1], quantile)
        out = np.zeros(len(self.points), bool)
        out[~reliable] = tree.query(self.points[~reliable])[0] > spacing
        return out

    def sparse_box(self, low: float = 5.0, high: float = 95.0) -> tuple[np.ndarray, np.ndarray] | None:
        """The box of the :meth:`reliable_points`' ``low``–``high`` percentiles per axis
        (robust to far background points and outliers); None without at least 10 points."""
        points = self.reliable_points()
        if points is None or len(points) < 10:
            return None
        lo, hi = np.percentile(points, [low, high], axis=0)
        return lo, hi

    def region(self, scale: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The region of interest, what the cameras look at: :meth:`sparse_box` scaled by
        ``scale`` about its centre; None without sparse points or when ``scale`` is 0 (no
        region)."""
        box = self.sparse_box()
        if box is None or not scale:
            return None
        centre, half = (box[0] + box[1]) / 2, (box[1] - box[0]) / 2 * scale
        half = np.maximum(half, 0.1 * half.max())  # points on one plane (a wall, a facade) span no depth
        return centre - half, centre + half

    def camera(self, view_id: str) -> Camera:
        for cam in self.cameras:
            if cam.view_id == view_id:
                return cam
        raise KeyError(view_id)


def similarity_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama): scale s, rotation R, translation t minimising
    Σ‖s R src_i + t − dst_i‖². Inputs are (N,3) with N ≥ 3 non-collinear points."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (xs**2).sum(axis=1).mean())
    t = mu_d - s * R @ mu_s
    return s, R, t
