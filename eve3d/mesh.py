"""Meshing stage (``eve3d mesh``): TSDF fusion of per-view depth maps and marching cubes.

Uses open3d's tensor ``VoxelBlockGrid`` (the legacy ``ScalableTSDFVolume`` returns empty
meshes in open3d 0.20). Its block count is preallocated, so it is sized from the blocks the
depth maps actually touch.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d import chunking
from eve3d.chunking import chunks
from eve3d.fileio import atomic_path
from eve3d.photos import read_view
from eve3d.maps import load_maps, map_camera
from eve3d.scene import Camera, Eve3dError, Scene
from eve3d.settings import MeshSettings

BLOCK_RESOLUTION = 8
MAX_BLOCKS = 2**31 // (BLOCK_RESOLUTION**3 * 16)
"""Blocks open3d (0.20, CPU) can extract a mesh from: its marching cubes keeps 4 int32 per
voxel and addresses them with 32-bit byte offsets, so past 262,144 blocks it crashes
(segmentation fault, measured: 262,144 extract, 262,200 do not)."""


def view_depths(scene: Scene, depth_dir: Path, min_confidence: float):
    """Yield (camera at the map's size, depth with low-confidence pixels zeroed) for every
    view, one map read at a time (its depth and confidence only: normals are not decompressed)."""
    for cam in scene.cameras:
        path = depth_dir / f"{cam.view_id}.npz"
        if not path.exists():
            raise Eve3dError(f"{path}: depth map missing for view {cam.view_id}")
        maps = load_maps(path, ("depth", "confidence"))
        depth = maps["depth"].astype(np.float32)
        small = map_camera(cam, depth.shape, path)  # fused at the map's size (priors: the pretrain's)
        if "confidence" in maps:
            depth = np.where(maps["confidence"] >= min_confidence, depth, 0).astype(np.float32)
        yield small, depth


def _row_bands(cam: Camera, multiple: int = 1) -> Iterator[slice]:
    """Bands of ``cam``'s image rows, each starting at a multiple of ``multiple``, of about a
    quarter of a chunk of pixels (:mod:`eve3d.chunking`): a band's back-projection is a few
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


def fused_depths(scene: Scene, depth_dir: Path, s: MeshSettings, desc: str = "", leave: bool = True):
    """:func:`view_depths`, only the depths within ``depth_max`` and the region of interest
    (a progress bar ``desc`` when given)."""
    region = scene.region(s.region)
    views = view_depths(scene, depth_dir, s.min_confidence)
    if desc:
        views = tqdm(views, total=len(scene.cameras), desc=desc, unit="view", leave=leave)
    for cam, depth in views:
        if s.depth_max:
            depth = np.where(depth <= s.depth_max, depth, 0)
        yield cam, in_region(cam, depth, region)


def _nothing_to_fuse(depth_dir: Path) -> Eve3dError:
    return Eve3dError(f"{depth_dir}: no valid depth in any view, nothing to fuse")


def scene_voxel(scene: Scene, depth_dir: Path, s: MeshSettings) -> float:
    """An open scene's voxel: the largest extent of the fused points (their 0.5–99.5 %
    per axis, within the region: a sky sets no size) / 2048 × ``coarsen``, from a sample of
    20–40 thousand points of each view (what this pass holds: about 1 MB a view)."""
    pts = []
    for cam, depth in fused_depths(scene, depth_dir, s, "TSDF voxel", leave=False):
        sample = _touched(cam, depth, stride=4)
        pts.append(sample[:: max(1, len(sample) // 20000)].copy())  # a view would keep all of `sample`
    if not sum(map(len, pts)):
        raise _nothing_to_fuse(depth_dir)
    # one coordinate of every sample at a time: a third of them copied, not all twice
    extent = [np.subtract(*np.percentile(np.concatenate([p[:, k] for p in pts]), [99.5, 0.5])) for k in range(3)]
    return float(np.max(extent)) / 2048 * s.coarsen


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


def _block_coords(grid, frame: tuple, s: MeshSettings, depth_max: float):
    """The blocks a view's depth (``frame``: :func:`_frame`) touches in ``grid``, or None
    when it touches none: open3d raises then (sparse or out-of-range depth), and the view
    adds nothing, as an empty one."""
    intrinsic, extrinsic, depth_img = frame
    try:
        return grid.compute_unique_block_coordinates(depth_img, intrinsic, extrinsic, 1.0, depth_max,
                                                     trunc_voxel_multiplier=s.trunc_factor)
    except RuntimeError as e:
        if "No block is touched" not in str(e):
            raise
        return None


def block_count(scene: Scene, depth_dir: Path, s: MeshSettings, voxel: float) -> int:
    """The blocks the fusion allocates, exactly: the union of the blocks each view touches
    (open3d's own test, ``compute_unique_block_coordinates``, gathered in a hash set),
    plus the most that one view touches (0 when no view touches one). open3d grows the
    grid's hash map (a copy of every block) whenever its size plus a view's blocks would
    pass its capacity; with this capacity it never does, and nothing is allocated that no
    view reaches."""
    import open3d.core as o3c

    probe, depth_max = _grid(voxel, 1), float(s.depth_max) if s.depth_max else 1e6
    touched = o3c.HashSet(1024, o3c.int32, (3,), o3c.Device("CPU:0"))
    most, valid = 0, False
    for cam, depth in fused_depths(scene, depth_dir, s, "TSDF blocks", leave=False):
        if not (depth > 0).any():
            continue
        valid = True
        coords = _block_coords(probe, _frame(cam, depth), s, depth_max)
        if coords is not None:
            touched.insert(coords)
            most = max(most, len(coords))
    if not valid:
        raise _nothing_to_fuse(depth_dir)
    if not touched.size():
        return 0
    if touched.size() > MAX_BLOCKS:  # refused before the fusion, not a crash after it
        raise Eve3dError(f"{depth_dir}: at voxel {voxel:.4g} the views touch {touched.size():,} blocks of "
                         f"{BLOCK_RESOLUTION}³ voxels; open3d extracts a mesh from at most {MAX_BLOCKS:,}. Use a voxel "
                         f"about {1.05 * np.sqrt(touched.size() / MAX_BLOCKS):.2g}× as large (mesh.coarsen, "
                         f"mesh.voxel) or a smaller region (mesh.region)")
    return touched.size() + most


def plan_grid(scene: Scene, depth_dir: Path, s: MeshSettings) -> tuple[float, int]:
    """Voxel size and the block count of the grid (:func:`block_count`). Each pass reads
    the depth maps one at a time."""
    voxel = s.voxel
    if voxel is None:
        voxel = 0.002 * scene.object_radius * s.coarsen if scene.kind == "object" else scene_voxel(scene, depth_dir, s)
    return voxel, block_count(scene, depth_dir, s, voxel)


def fuse(scene: Scene, depth_dir: Path, settings: MeshSettings | None = None):
    """TSDF-fuse the depth maps in ``depth_dir`` (``{view}.npz``) → open3d legacy mesh. The
    maps are read one at a time (one pass for the voxel of an open scene, one for the grid's
    size, one to fuse), so memory is the grid's and one view's."""
    import open3d as o3d
    import open3d.core as o3c

    s = settings or MeshSettings()
    voxel, blocks = plan_grid(scene, depth_dir, s)
    depth_max = float(s.depth_max) if s.depth_max else 1e6
    vbg = _grid(voxel, max(blocks, 1))
    fused = 0
    views = fused_depths(scene, depth_dir, s, f"TSDF (voxel {voxel:.4g}, {blocks} blocks)") if blocks else ()
    for cam, depth in views:
        if not (depth > 0).any():  # nothing of this view in the region (open3d refuses an empty view)
            continue
        frame = _frame(cam, depth)
        coords = _block_coords(vbg, frame, s, depth_max)
        if coords is None:
            continue
        intrinsic, extrinsic, depth_img = frame
        if cam.image_path is not None and cam.image_path.exists():
            rgb = read_view(cam).astype(np.float32) / 255.0
        else:
            rgb = np.full((cam.height, cam.width, 3), 0.7, np.float32)
        color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb)))
        vbg.integrate(coords, depth_img, color_img, intrinsic, extrinsic, 1.0, depth_max,
                      trunc_voxel_multiplier=s.trunc_factor)
        fused += 1
    mesh = o3d.geometry.TriangleMesh()  # open3d cannot extract from a grid that no view reached
    if fused:
        extracted = vbg.extract_triangle_mesh(weight_threshold=s.weight_threshold)
        del vbg  # the grid goes before the mesh is converted (each a few GB at the DESIGN voxel on a large scene)
        mesh = extracted.to_legacy()
        del extracted
    region = scene.region(s.region)
    if region is not None:  # the truncation band reaches a few voxels past the fused depths
        mesh = mesh.crop(o3d.geometry.AxisAlignedBoundingBox(*region))
    if len(mesh.triangles) == 0:
        why = (f"too few of the {fused} views fused agree on a depth for mesh.weight_threshold "
               f"{s.weight_threshold:g}, or it lies outside the region of interest (mesh.region)" if fused else
               "no view's depth reaches the grid (beyond mesh.depth_max, not finite, or too sparse)")
        raise Eve3dError(f"{depth_dir}: the depth maps fuse to no surface (an empty mesh at voxel {voxel:.4g}): {why}; "
                         f"no mesh written")
    keep_largest = s.largest_cluster if s.largest_cluster is not None else scene.kind == "object"
    if keep_largest:
        mesh = keep_large_clusters(mesh, s.min_cluster_fraction)
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


def keep_large_clusters(mesh, min_fraction: float):
    """Keep the largest connected set of triangles and those with at least ``min_fraction``
    of its triangles (drops floaters)."""
    labels, counts, _ = mesh.cluster_connected_triangles()
    labels, counts = np.asarray(labels), np.asarray(counts)
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


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray, like: Camera, size: int, name: str) -> Camera:
    """A camera at ``eye`` looking at ``target`` (``up`` up in the image), with ``like``'s
    field of view and aspect, its longest side ``size`` px."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    small = like.scaled(size / max(like.width, like.height))
    return replace(small, name=name, R=R, t=-R @ eye, image_path=None, mask_path=None)


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
    return views + [look_at(eye, centre, up, like, size, "overview")]


def shaded(mesh, cam: Camera) -> np.ndarray:
    """RGB uint8 of the mesh seen by ``cam``, ray-cast on the CPU: clay-coloured Lambert
    shading under a light above and to the left of the camera, white background."""
    from eve3d.raycast import MeshRaycaster

    hits = MeshRaycaster([mesh]).cast(cam)
    light = cam.R.T @ np.array([-0.4, -0.6, -1.0])
    light /= np.linalg.norm(light)
    lambert = np.clip(hits.normal @ light, 0, 1)
    shade = (0.25 + 0.75 * lambert)[..., None] * np.array([0.85, 0.80, 0.72])
    return np.where(hits.valid[..., None], shade * 255, 255).round().astype(np.uint8)


def write_mesh_views(mesh, scene: Scene, out_dir: Path, size: int = 640) -> list[Path]:
    """:func:`shaded` renders from :func:`view_cameras` as ``out_dir/{view}.png``."""
    from eve3d.fileio import write_image

    paths = []
    for cam in view_cameras(mesh, scene, size):
        paths.append(out_dir / f"{cam.view_id}.png")
        write_image(paths[-1], shaded(mesh, cam))
    return paths
