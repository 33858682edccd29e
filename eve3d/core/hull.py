"""The measured scene: the convex hull of what SfM triangulated, and the rays that miss it.

A ray that never enters the hull passes no measured surface: what its pixel shows lies
beyond the scene (a sky, a far background), which the environment at infinity explains
(``eve3d.gaussians.environment``). Inside a room nothing lies beyond: the cameras stand in
what they measure, and SfM may not see the ceiling that closes it (:func:`looks_out`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eve3d.core.scene import Camera, Scene


@dataclass
class Hull:
    """A convex region of the world (:func:`measured_hull`)."""

    equations: np.ndarray
    """(F, 4) its facets' half-spaces n·x + b ≤ 0 (n outward, unit)."""
    vertices: np.ndarray
    """(V, 3) its corners."""

    def missed(self, cam: Camera) -> np.ndarray:
        """(H, W) bool: the pixels of ``cam`` whose ray (through the pixel centre) never
        enters the region. From outside, with every corner ahead of the camera, the region
        projects to the convex polygon of its corners' projections, and a pixel outside it
        misses: a few edges a pixel instead of every facet (:func:`misses`, the general case,
        20× slower on a 512 px photo)."""
        centre = cam.center
        if np.all(self.equations[:, :3] @ centre + self.equations[:, 3] <= 0):
            return np.zeros((cam.height, cam.width), bool)  # from inside, every ray meets it
        uv, z = cam.project(self.vertices)
        if np.any(z <= 1e-9 * np.abs(z).max()):
            return misses(self.equations, centre, cam.pixel_rays())
        from scipy.spatial import ConvexHull

        polygon = uv[ConvexHull(uv).vertices]  # counter-clockwise
        edge = np.roll(polygon, -1, axis=0) - polygon
        v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64) + 0.5
        inside = np.ones((cam.height, cam.width), bool)
        for (x0, y0), (dx, dy) in zip(polygon, edge):
            inside &= dx * (v - y0) - dy * (u - x0) >= 0
        return ~inside


def misses(hull: np.ndarray, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Which rays from ``origin`` (3,) along ``directions`` (..., 3) never enter the convex
    region of half-spaces ``hull`` (F, 4) (:attr:`Hull.equations`): a ray enters where it
    lies inside every half-space at some t ≥ 0 (each facet bounds t from one side)."""
    normal, offset = hull[:, :3], hull[:, 3]
    start = normal @ origin + offset  # (F,): > 0 where the origin is outside that facet
    speed = directions @ normal.T  # (..., F)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -start / speed
    lower = np.where(speed < 0, t, 0.0).max(axis=-1, initial=0.0)
    upper = np.where(speed > 0, t, np.inf).min(axis=-1, initial=np.inf)
    never = ((speed == 0) & (start > 0)).any(axis=-1)
    return never | (lower > upper)


def looks_out(scene: Scene) -> bool:
    """Whether the cameras look out from within the scene, as in a room seen from inside:
    their optical axes meet (least squares) nearer to them than half the median distance of
    the scene's reliable points from their centre. Around an object, or facing a facade,
    they meet about as far off as the points lie (measured: 0.96–1.32 of it on the generated
    object, vase and plane and on monstree; −0.27–0.01 on the rooms)."""
    points = scene.reliable_points()
    if points is None or len(points) < 10:
        return False
    centres = np.array([c.center for c in scene.cameras])
    axes = np.array([c.R[2] for c in scene.cameras])
    project = np.eye(3) - axes[:, :, None] * axes[:, None, :]  # onto each axis' normal plane
    A = project.sum(axis=0)
    if np.linalg.eigvalsh(A)[0] < 0.01 * len(centres):  # parallel axes never meet
        return False
    meet = np.linalg.solve(A, np.einsum("nij,nj->i", project, centres))
    ahead = np.median(np.einsum("ni,ni->n", meet - centres, axes))
    return bool(ahead < 0.5 * np.median(np.linalg.norm(points - centres.mean(axis=0), axis=1)))


def measured_hull(scene: Scene, margin: float, two_view: bool = False) -> Hull | None:
    """The measured scene: the convex hull of the scene's reliable points (seen in three
    views or more) inside ``region(2)``, so that far outliers do not stretch it, grown by
    ``margin`` of its size about their centroid. None (nothing lies beyond) when the cameras
    look out from within the scene (:func:`looks_out`), or without enough points to span a
    volume. With ``two_view``, the two-view points beside the reliable ones too (all but
    :meth:`~eve3d.core.scene.Scene.isolated`): where SfM saw a surface less often, such as a
    floor's far rim before a textured background."""
    from scipy.spatial import ConvexHull, QhullError

    points, region = scene.reliable_points(), scene.region(2.0)
    if two_view and points is not None:
        points = scene.points[~scene.isolated()]
    if points is None or region is None or looks_out(scene):
        return None
    points = points[np.all((points >= region[0]) & (points <= region[1]), axis=1)]
    if len(points) < 10:
        return None
    centre = points.mean(axis=0)
    try:
        hull = ConvexHull(centre + (1 + margin) * (points - centre))
    except QhullError:  # the points lie on a plane or a line
        return None
    return Hull(hull.equations, hull.points[hull.vertices])
