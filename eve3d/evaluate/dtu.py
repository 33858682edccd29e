"""The ``dtu`` protocol: DTUeval-python's semantics, in DTU mm.

Cull the mesh by the object masks dilated by a disk of 24 px (2DGS's ``cull_scan``), undo
``scale_mat``, sample the triangles on a 0.2 mm barycentric grid and thin greedily to
0.2 mm, keep the points inside the bounding box and the ``ObsMask``; accuracy over those
against the STL points, completeness of the STL points above the ground plane; distances
≥ 20 mm are left out of both means; Chamfer = mean(accuracy, completeness). ``precision.ply``
and ``recall.ply`` beside ``metrics.json`` colour the points scored by their distance.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.core import chunking
from eve3d.core.chunking import chunks
from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_mesh
from eve3d.core.scene import Camera, Scene
from eve3d.evaluate.common import nearest_distances, write_error_maps
from eve3d.evaluate.protocol import EvalInputs, Protocol

MASK_DILATION = 24
"""Radius (px) of the disk the object masks are dilated by before culling."""
ERROR_MAP_MM = 10.0
"""precision.ply / recall.ply colour distances from white (0) to black (10 mm and beyond),
DTUeval-python's visualisation threshold."""
CHECK_POINTS = 20_000
"""STL points the ground-truth check projects into the masks."""
MIN_IN_MASK = 0.8
"""The check's bound: in the median view, at least this share of the STL points above the
ground plane that fall in the image fall on the object's mask, dilated by
:data:`MASK_DILATION` px per 1600 px of width (DTU's photos). On a miniature scan (128×96)
the right STL scored 1.0, the same STL moved by 10 % of the object's size 0.82, by 40 %
0.47 (another scan's STL, or cameras of another frame, lie further off still)."""


def mask_cameras(scene: Scene) -> list[Camera]:
    """The cameras the object masks were drawn for (``io.dtu``), each with its mask."""
    cameras = scene.extras.get("mask_cameras", scene.cameras)
    if any(cam.mask_path is None for cam in cameras):
        raise Eve3dError(f"{scene.root}: the DTU protocol needs object masks (mask/) for every view")
    return cameras


def on_mask(cam: Camera, points: np.ndarray, dilation: int = MASK_DILATION) -> tuple[np.ndarray, np.ndarray]:
    """Which ``points`` fall in ``cam``'s image (in front of it), and of those which fall on
    a pixel of its object mask dilated by a disk of ``dilation`` px (projected a chunk of
    points at a time)."""
    import cv2
    from skimage.morphology import disk

    from eve3d.core.fileio import read_mask

    mask = cv2.dilate(read_mask(cam.mask_path).astype(np.uint8), disk(dilation).astype(np.uint8)) > 0
    inside, hit = np.zeros(len(points), dtype=bool), []
    for part in chunks(len(points)):
        uv, z = cam.project(points[part])
        inside[part] = cam.in_image(uv, z)
        px = np.floor(uv[inside[part]]).astype(np.int64)  # the pixel a point falls in (centres at +0.5)
        hit.append(mask[px[:, 1], px[:, 0]])
    return inside, np.concatenate(hit) if hit else np.zeros(0, dtype=bool)


def cull_by_masks(mesh, scene: Scene, dilation: int = MASK_DILATION):
    """Drop the vertices that fall, in some image, on a pixel outside its object mask
    dilated by a disk of ``dilation`` px (vertices behind a camera or outside its image are
    not judged by it); a face stays only if all its vertices stay."""
    v = np.asarray(mesh.vertices)
    keep = np.ones(len(v), dtype=bool)
    for cam in mask_cameras(scene):
        inside, hit = on_mask(cam, v, dilation)
        ok = np.ones(len(v), dtype=bool)
        ok[inside] = hit
        keep &= ok
    tri = np.asarray(mesh.triangles)
    mesh.remove_triangles_by_mask(~keep[tri].all(axis=1))
    mesh.remove_unreferenced_vertices()
    return mesh


def read_ground_truth(inputs: EvalInputs) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, float], np.ndarray]:
    """The STL points, the ObsMask (mask, bounding box, resolution) and the ground plane,
    with an error naming the file that cannot be read."""
    import open3d as o3d
    from scipy.io import loadmat

    def mat(path, keys):
        try:
            data = loadmat(path)
            return [data[k] for k in keys]
        except Exception as e:  # scipy raises several kinds for a file that is not a .mat
            raise Eve3dError(f"{path}: not a DTU {' / '.join(keys)} file ({type(e).__name__}: {e})") from None

    obs_mask, bb, res = mat(inputs.obs_mask, ("ObsMask", "BB", "Res"))
    (plane,) = mat(inputs.plane, ("P",))
    stl = np.asarray(o3d.io.read_point_cloud(str(inputs.gt)).points)
    if not len(stl):
        raise Eve3dError(f"{inputs.gt}: empty or unreadable ground-truth point cloud")
    return stl, (obs_mask, bb.astype(np.float32), float(np.squeeze(res))), plane.reshape(4)


def above_plane(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Which points lie above the ground plane P (P·[x, 1] > 0): the object, not the table
    (a chunk of homogeneous points at a time)."""
    above = np.empty(len(points), dtype=bool)
    for part in chunks(len(points)):
        above[part] = np.concatenate([points[part], np.ones((part.stop - part.start, 1))], 1) @ plane > 0
    return above


def check_alignment(inputs: EvalInputs) -> dict:
    """Before any training: the STL points above the ground plane, moved into the scan's
    normalised frame, fall on the object in its photos (module constants); an error names
    the STL file otherwise."""
    scene = inputs.scene
    stl, _, plane = read_ground_truth(inputs)
    stl = stl[above_plane(stl, plane)]  # the object: the table around it is not in the masks
    if len(stl) < 100:
        raise Eve3dError(f"{inputs.gt}: {len(stl)} points lie above the ground plane of {inputs.plane}: are they "
                         f"the same scan's files?")
    stl = stl[np.random.default_rng(0).choice(len(stl), min(CHECK_POINTS, len(stl)), replace=False)]
    inverse = np.linalg.inv(scene.to_world)
    points = stl @ inverse[:3, :3].T + inverse[:3, 3]
    shares = []
    for cam in mask_cameras(scene):
        inside, hit = on_mask(cam, points, round(MASK_DILATION * cam.width / 1600))
        shares.append(float(hit.mean()) if inside.sum() >= 100 else 0.0)
    share = float(np.median(shares))
    if share < MIN_IN_MASK:
        raise Eve3dError(f"{inputs.gt}: does not line up with {scene.root}: in the median view {share:.0%} of its "
                         f"points fall on the object's mask (at least {MIN_IN_MASK:.0%} expected). Is it the STL "
                         f"of this scan, and cameras.npz the scan's own (its scale_mat maps to DTU mm)?")
    return {"stl_points_in_masks": share}


def dtu_sample_mesh(vertices: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """DTUeval-python's deterministic triangle sampling: a grid of barycentric points per
    triangle with step ``density`` (plus the vertices)."""
    tri = vertices[triangles]
    v1, v2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    l1, l2 = np.linalg.norm(v1, axis=-1), np.linalg.norm(v2, axis=-1)
    area2 = np.linalg.norm(np.cross(v1, v2), axis=-1)
    ok = area2 > 0
    tri, v1, v2, l1, l2, area2 = tri[ok], v1[ok], v2[ok], l1[ok], l2[ok], area2[ok]
    thr = density * np.sqrt(l1 * l2 / area2)
    n1, n2 = np.floor(l1 / thr), np.floor(l2 / thr)
    out = [vertices]
    for (a, b), group in _group_by_counts(n1, n2):
        c = np.mgrid[: a + 1, : b + 1].reshape(2, -1).astype(np.float64) + 0.5
        c[0] /= max(a, 1e-7)
        c[1] /= max(b, 1e-7)
        c = c[:, c[0] + c[1] < 1]
        if c.shape[1]:
            pts = v1[group, None] * c[0][None, :, None] + v2[group, None] * c[1][None, :, None] + tri[group, 0, None]
            out.append(pts.reshape(-1, 3))
    return np.concatenate(out)


def _group_by_counts(n1: np.ndarray, n2: np.ndarray):
    """Triangles grouped by their (n1, n2) sample counts, so each group samples in one go
    (each group's indices in increasing order; one sort, not one pass per group)."""
    keys = np.stack([n1, n2], 1).astype(np.int64)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(len(uniq) + 1))
    for k, (a, b) in enumerate(uniq):
        yield (int(a), int(b)), order[bounds[k]:bounds[k + 1]]


def radius_thin(points: np.ndarray, radius: float, rng: np.random.Generator) -> np.ndarray:
    """DTUeval-python's greedy thinning: in random order, keep a point and drop every other
    point within ``radius`` of it (neighbours looked up a chunk of points at a time)."""
    points = points[rng.permutation(len(points))]
    from scipy.spatial import cKDTree  # here: every command imports the protocols, only scoring needs scipy

    tree = cKDTree(points)
    keep = np.ones(len(points), dtype=bool)
    for part in chunks(len(points), max(1, chunking.CHUNK // 5)):  # Python lists: ~300 bytes a point
        for i, nbrs in enumerate(tree.query_ball_point(points[part], r=radius, workers=-1), start=part.start):
            if keep[i]:
                keep[nbrs] = False
                keep[i] = True
    return points[keep]


def evaluate_dtu(inputs: EvalInputs, patch: float = 60.0) -> dict:
    """The protocol of the module docstring; distances in mm."""
    settings, scene = inputs.settings, inputs.scene
    rng = np.random.default_rng(0)
    stl, (obs_mask, bb, res), plane = read_ground_truth(inputs)
    mesh = cull_by_masks(read_mesh(inputs.reconstruction), scene)
    if len(mesh.triangles) == 0:
        raise Eve3dError(f"{inputs.reconstruction}: nothing of the mesh lies inside the object masks")
    mesh.transform(scene.to_world)
    # the samples before thinning are held only while they are thinned
    data = radius_thin(dtu_sample_mesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), settings.dtu_density),
                       settings.dtu_density, rng)
    del mesh
    inbound = np.all((data >= bb[:1] - patch) & (data < bb[1:] + patch * 2), axis=1)
    data_in = data[inbound]
    del data
    grid = np.around((data_in - bb[:1]) / res).astype(np.int32)
    grid_ok = np.all((grid >= 0) & (grid < np.array(obs_mask.shape)), axis=1)
    in_obs = obs_mask[grid[grid_ok, 0], grid[grid_ok, 1], grid[grid_ok, 2]].astype(bool)
    data_in_obs = data_in[grid_ok][in_obs]
    # Distances at or beyond max_dist are left out of the means, so the search stops there.
    d2s = nearest_distances(data_in_obs, stl, settings.dtu_max_dist)
    stl_above = stl[above_plane(stl, plane)]
    del stl
    s2d = nearest_distances(stl_above, data_in, settings.dtu_max_dist)
    near_d2s, near_s2d = d2s[d2s < settings.dtu_max_dist], s2d[s2d < settings.dtu_max_dist]
    if not len(near_d2s) or not len(near_s2d):
        raise Eve3dError(f"{inputs.reconstruction}: no point of the mesh inside the ObsMask lies within "
                         f"{settings.dtu_max_dist:g} mm of {inputs.gt}: is the mesh in the scan's normalised frame?")
    maps = write_error_maps(Path(inputs.out).parent, data_in_obs, d2s, stl_above, s2d, ERROR_MAP_MM)
    acc, comp = float(near_d2s.mean()), float(near_s2d.mean())
    return {"accuracy": acc, "completeness": comp, "chamfer": (acc + comp) / 2,
            "n_recon": int(len(data_in_obs)), "n_gt": int(len(stl_above)), **maps}


PROTOCOL = Protocol("dtu", "DTUeval-python: mask culling, 0.2 mm sampling, ObsMask crop, Chamfer in mm",
                    "mesh", evaluate_dtu, {"gt": "dtu.stl", "obs_mask": "dtu.obs_mask", "plane": "dtu.plane"},
                    formats=("dtu",), default_of=("dtu",), unit="mm", check=check_alignment)
