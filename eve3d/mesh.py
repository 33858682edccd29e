"""Meshing stage (``eve3d mesh``): TSDF fusion of per-view depth maps and marching cubes.

Uses open3d's tensor ``VoxelBlockGrid`` (the legacy ``ScalableTSDFVolume`` returns empty
meshes in open3d 0.20). Its block count is preallocated, so it is sized from the blocks the
depth maps actually touch. A large scene is fused and meshed a slab of blocks at a time:
open3d's marching cubes crashes past 262,144 blocks, and a slab bounds the memory.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.core import chunking
from eve3d.core.chunking import chunks
from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path
from eve3d.core.maps import FUSABLE_KEYS, fusable, load_maps, map_camera
from eve3d.core.photos import read_view
from eve3d.core.scene import Camera, Scene, look_at
from eve3d.core.settings import MeshSettings
from eve3d.core.timing import phase

BLOCK_RESOLUTION = 8
MAX_BLOCKS = 2**31 // (BLOCK_RESOLUTION**3 * 16)
"""Blocks open3d (0.20, CPU) can extract a mesh from: its marching cubes keeps 4 int32 per
voxel and addresses them with 32-bit byte offsets, so past 262,144 blocks it crashes
(segmentation fault, measured: 262,144 extract, 262,200 do not)."""
TILE_BLOCKS = MAX_BLOCKS // 2
"""Blocks of one grid at most: a scene that touches more is fused and meshed a slab at a
time. A block is about 10 KB of grid and 8 KB of marching-cubes buffers, so a grid of
131,072 blocks peaks at about 2.5 GB."""


def view_depths(scene: Scene, depth_dir: Path, min_confidence: float, max_incidence: float = 90.0):
    """Yield (camera at the map's size, depth zeroed where it is not fusable) for every
    view, one map read at a time (its depth and confidence; its normals only to leave out the
    pixels seen more obliquely than ``max_incidence`` degrees, when below 90)."""
    oblique = max_incidence < 90
    for cam in scene.cameras:
        path = depth_dir / f"{cam.view_id}.npz"
        if not path.exists():
            raise Eve3dError(f"{path}: depth map missing for view {cam.view_id}")
        maps = load_maps(path, FUSABLE_KEYS + (("normal",) if oblique else ()))
        depth = maps["depth"].astype(np.float32)
        small = map_camera(cam, depth.shape, path)  # fused at the map's size (priors: the pretrain's)
        keep = fusable(maps, min_confidence)
        if oblique and "normal" in maps:
            keep &= incidence(small, maps["normal"]) <= max_incidence
        depth = np.where(keep, depth, 0).astype(np.float32)
        yield small, depth


def incidence(cam: Camera, normal: np.ndarray) -> np.ndarray:
    """(H, W) degrees between each pixel's ray and its camera-space ``normal`` (H, W, 3);
    90 where the normal is missing."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float32) + 0.5
    rays = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(u)], -1)
    cos = np.abs((rays * normal).sum(-1)) / (np.linalg.norm(rays, axis=-1) * np.linalg.norm(normal, axis=-1) + 1e-12)
    return np.degrees(np.arccos(np.clip(cos, 0, 1)))


def _row_bands(cam: Camera, multiple: int = 1) -> Iterator[slice]:
    """Bands of ``cam``'s image rows, each starting at a multiple of ``multiple``, of about a
    quarter of a chunk of pixels (:mod:`eve3d.core.chunking`): a band's back-projection is a few
    MB, a 1920×1080 image's about 50 MB a float64 array, of which it makes several."""
    return chunks(cam.height, max(multiple, chunking.CHUNK // 4 // cam.width // multiple * multiple))


def in_region(cam: Camera, depth: np.ndarray, region: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """``depth`` with every pixel whose point lies outside ``region`` (lo, hi) zeroed
    (back-projected a band of rows at a time)."""
    if region is None:
        return depth
    inside = np.empty(depth.shape, dtype=bool)
    for rows in _row_bands(cam):
        points = cam.backproject(depth, rows)
        inside[rows] = np.all((points >= region[0]) & (points <= region[1]), axis=-1)
    return np.where(inside, depth, 0).astype(np.float32)


def _touched(cam: Camera, depth: np.ndarray, stride: int = 2) -> np.ndarray:
    """World points of every ``stride``-th valid pixel, in row-major order (back-projected
    a band of rows at a time)."""
    pts = []
    for rows in _row_bands(cam, stride):
        pts.append(cam.backproject(depth, rows)[::stride, ::stride][depth[rows][::stride, ::stride] > 0])
    return np.concatenate(pts)


def fused_depths(scene: Scene, depth_dir: Path, settings: MeshSettings, desc: str = "", leave: bool = True):
    """:func:`view_depths`, only the depths within ``depth_max`` and the region of interest
    (a progress bar ``desc`` when given)."""
    region = scene.region(settings.region)
    views = view_depths(scene, depth_dir, settings.min_confidence, settings.max_incidence)
    if desc:
        views = tqdm(views, total=len(scene.cameras), desc=desc, unit="view", leave=leave)
    for cam, depth in views:
        if settings.depth_max:
            depth = np.where(depth <= settings.depth_max, depth, 0)
        yield cam, in_region(cam, depth, region)


def _nothing_to_fuse(depth_dir: Path) -> Eve3dError:
    return Eve3dError(f"{depth_dir}: no valid depth in any view, nothing to fuse")


def scene_voxel(scene: Scene, depth_dir: Path, settings: MeshSettings) -> float:
    """An open scene's voxel: the largest extent of the fused points (their 0.5–99.5 %
    per axis, within the region: a sky sets no size) / 2048 × ``coarsen``, from a sample of
    20–40 thousand points of each view (what this pass holds: about 1 MB a view)."""
    pts = []
    for cam, depth in fused_depths(scene, depth_dir, settings, "TSDF voxel", leave=False):
        sample = _touched(cam, depth, stride=4)
        pts.append(sample[:: max(1, len(sample) // 20000)].copy())  # a view would keep all of `sample`
    if not sum(map(len, pts)):
        raise _nothing_to_fuse(depth_dir)
    # one coordinate of every sample at a time: a third of them copied, not all twice
    extent = [np.subtract(*np.percentile(np.concatenate([p[:, k] for p in pts]), [99.5, 0.5])) for k in range(3)]
    return float(np.max(extent)) / 2048 * settings.coarsen


def _grid(voxel: float, blocks: int):
    """An empty TSDF grid (tsdf, weight, colour) of ``blocks`` preallocated blocks of
    BLOCK_RESOLUTION³ voxels: about 10 KB a block."""
    import open3d as o3d
    import open3d.core as o3c

    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=BLOCK_RESOLUTION,
        block_count=blocks, device=o3c.Device("CPU:0"))


def _frame(cam: Camera, depth: np.ndarray):
    """open3d's intrinsics, extrinsics and depth image of a view."""
    import open3d as o3d
    import open3d.core as o3c

    return (o3c.Tensor(cam.K, o3c.float64), o3c.Tensor(cam.world_to_camera, o3c.float64),
            o3d.t.geometry.Image(o3c.Tensor(depth)))


def _block_coords(grid, frame: tuple, settings: MeshSettings, depth_max: float):
    """The blocks a view's depth (``frame``: :func:`_frame`) touches in ``grid``, or None
    when it touches none: open3d raises then (sparse or out-of-range depth), and the view
    adds nothing, as an empty one."""
    intrinsic, extrinsic, depth_img = frame
    try:
        return grid.compute_unique_block_coordinates(depth_img, intrinsic, extrinsic, 1.0, depth_max,
                                                     trunc_voxel_multiplier=settings.trunc_factor)
    except RuntimeError as e:
        if "No block is touched" not in str(e):
            raise
        return None


@dataclass
class GridPlan:
    """What the counting pass found: the blocks of BLOCK_RESOLUTION³ voxels the views touch
    (open3d's own test, ``compute_unique_block_coordinates``) and where each view reaches."""

    voxel: float
    blocks: np.ndarray
    """(N, 3) int32 block coordinates, every block some view touches."""
    most: int
    """The most blocks one view touches. open3d grows a grid's hash map (a copy of every
    block) whenever its size plus a view's blocks would pass its capacity: a grid of the
    blocks it will hold plus this many never grows."""
    reach: dict[str, np.ndarray]
    """Per view id, the (2, 3) lowest and highest block coordinates it touches (views that
    touch none are left out)."""


def count_blocks(scene: Scene, depth_dir: Path, settings: MeshSettings, voxel: float) -> GridPlan:
    """The blocks the views touch at ``voxel``, gathered a view at a time in a hash set."""
    import open3d.core as o3c

    probe, depth_max = _grid(voxel, 1), float(settings.depth_max) if settings.depth_max else 1e6
    touched = o3c.HashSet(1024, o3c.int32, (3,), o3c.Device("CPU:0"))
    most, valid, reach = 0, False, {}
    for cam, depth in fused_depths(scene, depth_dir, settings, "TSDF blocks", leave=False):
        if not (depth > 0).any():
            continue
        valid = True
        coords = _block_coords(probe, _frame(cam, depth), settings, depth_max)
        if coords is not None:
            touched.insert(coords)
            most = max(most, len(coords))
            c = coords.numpy()
            reach[cam.view_id] = np.stack([c.min(0), c.max(0)])
    if not valid:
        raise _nothing_to_fuse(depth_dir)
    blocks = touched.key_tensor()[touched.active_buf_indices().to(o3c.int64)].numpy()
    return GridPlan(voxel, blocks.reshape(-1, 3), most, reach)


def plan_grid(scene: Scene, depth_dir: Path, settings: MeshSettings) -> GridPlan:
    """The voxel (``mesh.voxel``, else the scene's at ``mesh.coarsen``) and the blocks the
    views touch at it. Each pass reads the depth maps one at a time."""
    voxel = settings.voxel
    if voxel is None:
        voxel = (0.002 * scene.object_radius * settings.coarsen if scene.kind == "object"
                 else scene_voxel(scene, depth_dir, settings))
    return count_blocks(scene, depth_dir, settings, voxel)


def slabs(plan: GridPlan, depth_dir: Path) -> tuple[int, list[tuple[int, int]]]:
    """The axis of the most block layers and consecutive ranges [a, b) of its layers, each
    of at most TILE_BLOCKS blocks with one layer more on either side (its grid's margin:
    marching cubes reads a cell's neighbours), covering every block; one range when the
    whole grid fits."""
    keys = plan.blocks
    if len(keys) <= TILE_BLOCKS:
        return 0, [(int(keys[:, 0].min()), int(keys[:, 0].max()) + 1)]
    axis = int(np.argmax(keys.max(0) - keys.min(0)))
    lo = int(keys[:, axis].min())
    layers = np.bincount(keys[:, axis] - lo)

    def held(a, b):  # layers a-1 … b, as offsets
        return int(layers[max(a - 1, 0):b + 1].sum())

    ranges, a = [], 0
    while a < len(layers):
        b = a + 1
        if held(a, b) > MAX_BLOCKS:  # refused before the fusion, not a crash after it
            raise Eve3dError(
                f"{depth_dir}: at voxel {plan.voxel:.4g} three layers of blocks of {BLOCK_RESOLUTION}³ voxels hold "
                f"{held(a, b):,} blocks; open3d extracts a mesh from at most {MAX_BLOCKS:,}. Use a larger voxel "
                f"(mesh.coarsen, mesh.voxel) or a smaller region (mesh.region)")
        while b < len(layers) and held(a, b + 1) <= TILE_BLOCKS:
            b += 1
        ranges.append((lo + a, lo + b))
        a = b
    return axis, ranges


def _welded(parts: list):
    """One open3d mesh of the slabs' meshes: a vertex position that two slabs share (their
    seam: the same cells give bit-identical vertices) made one vertex; any other vertex kept
    as it is (open3d itself makes several at one position where a TSDF value is exactly 0)."""
    import open3d as o3d

    arrays = {key: [np.asarray(getattr(m, key)) for m in parts] for key in ("vertices", "triangles")}
    vertices = np.concatenate(arrays["vertices"])
    sizes = [len(v) for v in arrays["vertices"]]
    slab = np.repeat(np.arange(len(parts)), sizes)
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    lowest, highest = np.full(len(first), len(parts)), np.full(len(first), -1)
    np.minimum.at(lowest, inverse, slab)
    np.maximum.at(highest, inverse, slab)
    shared = lowest[inverse] != highest[inverse]
    target = np.where(shared, first[inverse], np.arange(len(vertices)))
    offsets = np.cumsum([0] + sizes[:-1])
    triangles = np.concatenate([t + o for t, o in zip(arrays["triangles"], offsets)])
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                     o3d.utility.Vector3iVector(target[triangles]))
    for key in ("vertex_colors", "vertex_normals"):
        if all(len(getattr(m, key)) for m in parts):
            setattr(mesh, key, o3d.utility.Vector3dVector(np.concatenate([np.asarray(getattr(m, key)) for m in parts])))
    mesh.remove_unreferenced_vertices()
    return mesh


def _integrate(vbg, cam: Camera, depth: np.ndarray, settings: MeshSettings, depth_max: float, near=None) -> bool:
    """Fuse one view's depth and colour into ``vbg``, only into the blocks ``near`` keeps
    (a slab and its margin) when given; False when the view touches none."""
    import open3d as o3d
    import open3d.core as o3c

    if not (depth > 0).any():  # nothing of this view in the region (open3d refuses an empty view)
        return False
    frame = _frame(cam, depth)
    coords = _block_coords(vbg, frame, settings, depth_max)
    if coords is not None and near is not None:
        coords = coords[o3c.Tensor(near(coords.numpy()))]
    if coords is None or not len(coords):
        return False
    intrinsic, extrinsic, depth_img = frame
    if cam.image_path is not None and cam.image_path.exists():
        rgb = read_view(cam).astype(np.float32) / 255.0
    else:
        rgb = np.full((cam.height, cam.width, 3), 0.7, np.float32)
    color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb)))
    vbg.integrate(coords, depth_img, color_img, intrinsic, extrinsic, 1.0, depth_max,
                  trunc_voxel_multiplier=settings.trunc_factor)
    return True


def fuse(scene: Scene, depth_dir: Path, settings: MeshSettings | None = None):
    """TSDF-fuse the depth maps in ``depth_dir`` (``{view}.npz``) → open3d legacy mesh. The
    maps are read one at a time (one pass for the voxel of an open scene, one to count the
    blocks, one to fuse), so memory is the grid's and one view's. A scene of more than
    TILE_BLOCKS blocks is fused and meshed a slab at a time (:func:`slabs`; each slab reads
    the views that reach it): the same mesh, with a grid of at most TILE_BLOCKS blocks."""
    import open3d as o3d

    settings = settings or MeshSettings()
    plan = plan_grid(scene, depth_dir, settings)
    voxel, depth_max = plan.voxel, float(settings.depth_max) if settings.depth_max else 1e6
    axis, ranges = slabs(plan, depth_dir) if len(plan.blocks) else (0, [])
    fused_views, parts = set(), []
    for k, (a, b) in enumerate(ranges):
        def near(c):  # the slab and its margin
            return (c[..., axis] >= a - 1) & (c[..., axis] <= b)

        held = int(near(plan.blocks).sum())
        seen = [cam for cam in scene.cameras if cam.view_id in plan.reach and
                plan.reach[cam.view_id][0, axis] <= b and plan.reach[cam.view_id][1, axis] >= a - 1]
        vbg = _grid(voxel, held + min(plan.most, held))  # a view adds at most the slab's blocks
        desc = f"TSDF (voxel {voxel:.4g}, {held} blocks" + (f", slab {k + 1}/{len(ranges)})" if len(ranges) > 1 else ")")
        for cam, depth in fused_depths(replace(scene, cameras=seen), depth_dir, settings, desc, leave=len(ranges) == 1):
            if _integrate(vbg, cam, depth, settings, depth_max, near if len(ranges) > 1 else None):
                fused_views.add(cam.view_id)
        if not vbg.hashmap().size():  # open3d cannot extract from a grid that no view reached
            continue
        extracted = vbg.extract_triangle_mesh(weight_threshold=settings.weight_threshold)
        del vbg  # the grid goes before the mesh is converted (each a few GB at the DESIGN voxel on a large scene)
        piece = extracted.to_legacy()
        del extracted
        if len(ranges) > 1:  # each slab keeps the triangles whose centre lies in its own layers
            v, t = np.asarray(piece.vertices), np.asarray(piece.triangles)
            centre = v[t, axis].mean(1) / (voxel * BLOCK_RESOLUTION)
            keep = (centre >= a if k else True) & (centre < b if k < len(ranges) - 1 else True)
            piece.remove_triangles_by_mask(~keep)
            piece.remove_unreferenced_vertices()
        if len(piece.triangles):
            parts.append(piece)
    if not parts:
        mesh = o3d.geometry.TriangleMesh()
    else:
        mesh = parts[0] if len(parts) == 1 else _welded(parts)
        parts.clear()  # the slabs' meshes go before the mesh is reordered (a copy of it)
    fused = len(fused_views)
    region = scene.region(settings.region)
    if region is not None:  # the truncation band reaches a few voxels past the fused depths
        mesh = mesh.crop(o3d.geometry.AxisAlignedBoundingBox(*region))
    if len(mesh.triangles) == 0:
        why = (f"too few of the {fused} views fused agree on a depth for mesh.weight_threshold "
               f"{settings.weight_threshold:g}, or it lies outside the region of interest (mesh.region)" if fused else
               "no view's depth reaches the grid (beyond mesh.depth_max, not finite, or too sparse)")
        raise Eve3dError(f"{depth_dir}: the depth maps fuse to no surface (an empty mesh at voxel {voxel:.4g}): {why}; "
                         f"no mesh written")
    keep_largest = settings.largest_cluster if settings.largest_cluster is not None else scene.kind == "object"
    if keep_largest:
        mesh = keep_large_clusters(mesh, settings.min_cluster_fraction)
    return canonical_order(mesh)


def canonical_order(mesh):
    """The same open3d mesh with its vertices sorted by position and its triangles by their
    vertex indices (each rotated to start at its smallest, so orientation is kept).
    open3d's extraction order varies from run to run (threads fill its block hash map), and
    the evaluation samples a mesh in triangle order, so two fusions of the same depth maps
    scored up to 0.4 % apart and were never byte-identical."""
    import open3d as o3d

    v = np.asarray(mesh.vertices)
    order = np.lexsort(v.T[::-1])
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    tri = rank[np.asarray(mesh.triangles)]
    tri = np.take_along_axis(tri, (tri.argmin(1)[:, None] + np.arange(3)) % 3, axis=1)
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v[order]),
                                    o3d.utility.Vector3iVector(tri[np.lexsort(tri.T[::-1])]))
    if mesh.has_vertex_normals():
        out.vertex_normals = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_normals)[order])
    if mesh.has_vertex_colors():
        out.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_colors)[order])
    return out


def triangle_clusters(triangles: np.ndarray, vertex_count: int) -> np.ndarray:
    """The connected set of each triangle, triangles joined through a shared edge (open3d's
    ``cluster_connected_triangles``, which took 4 GB for a mesh of 11 million triangles;
    this holds the edges' keys and their order)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    t = np.asarray(triangles, dtype=np.int64)
    keys = np.concatenate([np.minimum(t[:, i], t[:, j]) * vertex_count + np.maximum(t[:, i], t[:, j])
                           for i, j in ((0, 1), (1, 2), (2, 0))])  # edge k of triangle n at k·N + n
    order = np.argsort(keys, kind="stable")
    same = np.flatnonzero(keys[order[1:]] == keys[order[:-1]])  # consecutive copies of an edge
    del keys
    a, b = order[same] % len(t), order[same + 1] % len(t)
    del order, same
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(len(t), len(t)))
    return connected_components(graph, directed=False)[1]


def keep_large_clusters(mesh, min_fraction: float):
    """Keep the largest connected set of triangles and those with at least ``min_fraction``
    of its triangles (drops floaters)."""
    labels = triangle_clusters(np.asarray(mesh.triangles), len(mesh.vertices))
    counts = np.bincount(labels)
    mesh.remove_triangles_by_mask(counts[labels] < min_fraction * counts.max())
    mesh.remove_unreferenced_vertices()
    return mesh


MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb")


def check_mesh_path(path: Path) -> None:
    """Refuse an output name that names no mesh format (before the fusion, not after)."""
    if Path(path).suffix.lower() not in MESH_SUFFIXES:
        raise Eve3dError(f"{path}: not a mesh file name; give one ending in {', '.join(MESH_SUFFIXES)}")


def write_mesh(mesh, path: Path) -> None:
    """Write a mesh atomically, in the format its suffix names (binary PLY for ``.ply``)."""
    import open3d as o3d

    check_mesh_path(path)
    with atomic_path(path) as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise Eve3dError(f"{path}: could not write mesh")


def extent_report(mesh, scene: Scene) -> dict:
    """The mesh's size against the sparse points' 5–95 % box: triangles, both extents per
    axis, and the largest ratio of the two (None without sparse points)."""
    v = np.asarray(mesh.vertices)
    extent = v.max(0) - v.min(0) if len(v) else np.zeros(3)
    box = scene.sparse_box()
    sparse = None if box is None else box[1] - box[0]
    ratio = None if sparse is None else float(np.max(extent / np.maximum(sparse, 1e-12)))
    return {"triangles": len(mesh.triangles), "extent": extent.round(4).tolist(),
            "sparse_extent": None if sparse is None else sparse.round(4).tolist(), "extent_ratio": ratio}


def view_from(eye: np.ndarray, target: np.ndarray, up: np.ndarray, like: Camera, size: int, name: str) -> Camera:
    """A camera at ``eye`` looking at ``target`` (``up`` up in the image), with ``like``'s
    field of view and aspect, its longest side ``size`` px."""
    R, t = look_at(eye, target, up)
    small = like.scaled(size / max(like.width, like.height))
    return replace(small, name=name, R=R, t=t, image_path=None, mask_path=None)


def view_cameras(mesh, scene: Scene, size: int = 640) -> list[Camera]:
    """Where the mesh is shown from: three training viewpoints spread over the capture and
    one overview from 35° above the cameras' side, framing the sparse points' 5–95 % box
    (the mesh's own box where there are no sparse points)."""
    picks = [scene.cameras[i] for i in sorted({round(f * (len(scene.cameras) - 1)) for f in (0, 0.5, 1)})]
    views = [c.scaled(size / max(c.width, c.height)) for c in picks]
    box = scene.sparse_box()
    if box is None:
        aabb = mesh.get_axis_aligned_bounding_box()
        box = np.asarray(aabb.get_min_bound()), np.asarray(aabb.get_max_bound())
    centre, diagonal = (box[0] + box[1]) / 2, float(np.linalg.norm(box[1] - box[0]))
    up = -np.mean([c.R[1] for c in scene.cameras], axis=0)  # image y points down
    up /= np.linalg.norm(up)
    back = scene.center - centre
    back = back - up * (back @ up)
    back = back / np.linalg.norm(back) if np.linalg.norm(back) > 1e-9 else -scene.cameras[0].R[2]
    like = scene.cameras[0]
    distance = 0.5 * diagonal / np.tan(np.arctan(min(like.width, like.height) / 2 / like.fx))
    eye = centre + distance * (back * np.cos(np.radians(35)) + up * np.sin(np.radians(35)))
    return views + [view_from(eye, centre, up, like, size, "overview")]


def shaded(mesh, cam: Camera) -> np.ndarray:
    """RGB uint8 of the mesh seen by ``cam``, ray-cast on the CPU: clay-coloured Lambert
    shading under a light above and to the left of the camera, white background."""
    from eve3d.core.raycast import MeshRaycaster

    hits = MeshRaycaster([mesh]).cast(cam)
    light = cam.R.T @ np.array([-0.4, -0.6, -1.0])
    light /= np.linalg.norm(light)
    lambert = np.clip(hits.normal @ light, 0, 1)
    shade = (0.25 + 0.75 * lambert)[..., None] * np.array([0.85, 0.80, 0.72])
    return np.where(hits.valid[..., None], shade * 255, 255).round().astype(np.uint8)


def write_mesh_views(mesh, scene: Scene, out_dir: Path, size: int = 640) -> list[Path]:
    """:func:`shaded` renders from :func:`view_cameras` as ``out_dir/{view}.png``."""
    from eve3d.core.fileio import write_image

    paths = []
    for cam in view_cameras(mesh, scene, size):
        paths.append(out_dir / f"{cam.view_id}.png")
        write_image(paths[-1], shaded(mesh, cam))
    return paths


def run_mesh(settings: MeshSettings, *, scene: Path, depth: Path, out: Path, kind: str | None = None) -> None:
    """The ``mesh`` stage: fuse the maps in ``depth`` over ``scene``'s cameras into ``out``,
    with shaded views of it beside (``kind`` overrides the scene's kind)."""
    from eve3d.core.io import load_scene
    from eve3d.core.layout import MESH_VIEWS_DIR

    out = Path(out)
    check_mesh_path(out)
    with phase("read scene"):
        loaded = load_scene(scene, check_images=False)
    if kind:
        loaded.kind = kind
    with phase("fuse"):
        mesh = fuse(loaded, Path(depth), settings)
    with phase("write"):
        write_mesh(mesh, out)
    report = extent_report(mesh, loaded)
    print(f"wrote {out}: {len(mesh.vertices)} vertices, {report['triangles']} triangles, extent {report['extent']}"
          + (f", {report['extent_ratio']:.2f}× the sparse points' 5–95 % box {report['sparse_extent']}"
             if report["extent_ratio"] is not None else ""))
    with phase("mesh views"):
        views = write_mesh_views(mesh, loaded, out.with_name(MESH_VIEWS_DIR))
    print(f"wrote {len(views)} shaded views to {views[0].parent}")
