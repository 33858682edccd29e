"""Meshing stage (``eve3d mesh``): TSDF fusion of per-view depth maps and marching cubes.

Uses open3d's tensor ``VoxelBlockGrid`` (the legacy ``ScalableTSDFVolume`` returns empty
meshes in open3d 0.20). Its block count is preallocated, so it is sized from the blocks the
depth maps actually touch.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eve3d.fileio import atomic_path
from eve3d.photos import read_view
from eve3d.maps import load_maps, map_camera
from eve3d.scene import Camera, Eve3dError, Scene
from eve3d.settings import MeshSettings

BLOCK_RESOLUTION = 8


def view_depths(scene: Scene, depth_dir: Path, min_confidence: float):
    """Yield (camera at the map's size, depth with low-confidence pixels zeroed) for every view."""
    for cam in scene.cameras:
        path = depth_dir / f"{cam.view_id}.npz"
        if not path.exists():
            raise Eve3dError(f"{path}: depth map missing for view {cam.view_id}")
        maps = load_maps(path)
        depth = maps["depth"].astype(np.float32)
        small = map_camera(cam, depth.shape, path)  # fused at the map's size (priors: the pretrain's)
        if "confidence" in maps:
            depth = np.where(maps["confidence"] >= min_confidence, depth, 0).astype(np.float32)
        yield small, depth


def in_region(cam: Camera, depth: np.ndarray, region: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """``depth`` with every pixel whose point lies outside ``region`` (lo, hi) zeroed."""
    if region is None:
        return depth
    points = cam.backproject(depth)
    inside = np.all((points >= region[0]) & (points <= region[1]), axis=-1)
    return np.where(inside, depth, 0).astype(np.float32)


def _touched(cam: Camera, depth: np.ndarray, stride: int = 2) -> np.ndarray:
    """World points of every ``stride``-th valid pixel."""
    d = depth[::stride, ::stride]
    pts = cam.backproject(depth)[::stride, ::stride]
    return pts[d > 0]


def fused_depths(scene: Scene, depth_dir: Path, s: MeshSettings):
    """:func:`view_depths`, only the depths within ``depth_max`` and the region of interest."""
    region = scene.region(s.region)
    for cam, depth in view_depths(scene, depth_dir, s.min_confidence):
        if s.depth_max:
            depth = np.where(depth <= s.depth_max, depth, 0)
        yield cam, in_region(cam, depth, region)


def plan_grid(scene: Scene, depth_dir: Path, s: MeshSettings) -> tuple[float, int]:
    """Voxel size and a block count that covers every block the depth maps touch."""
    pts = []
    for cam, depth in fused_depths(scene, depth_dir, s):
        sample = _touched(cam, depth, stride=4)
        pts.append(sample[:: max(1, len(sample) // 20000)])
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if not len(pts):
        raise Eve3dError(f"{depth_dir}: no valid depth in any view, nothing to fuse")
    voxel = s.voxel
    if voxel is None:
        if scene.kind == "object":
            voxel = 0.002 * scene.object_radius * s.coarsen
        else:
            lo, hi = np.percentile(pts, [0.5, 99.5], axis=0)  # within the region: a sky sets no size
            voxel = float(np.max(hi - lo)) / 2048 * s.coarsen
    block = voxel * BLOCK_RESOLUTION
    keys = np.unique(np.floor(pts / block).astype(np.int64), axis=0)
    # The truncation band reaches trunc_factor voxels off the surface: dilate by one block
    # (more when the band is wider than a block) and add headroom for the sparser sample.
    reach = int(np.ceil(s.trunc_factor / BLOCK_RESOLUTION)) + 1
    offsets = np.stack(np.meshgrid(*[np.arange(-reach, reach + 1)] * 3), -1).reshape(-1, 3)
    dilated = np.unique((keys[:, None] + offsets[None]).reshape(-1, 3), axis=0)
    return voxel, int(len(dilated) * 1.5) + 1000


def fuse(scene: Scene, depth_dir: Path, settings: MeshSettings | None = None):
    """TSDF-fuse the depth maps in ``depth_dir`` (``{view}.npz``) → open3d legacy mesh."""
    import open3d as o3d
    import open3d.core as o3c

    s = settings or MeshSettings()
    voxel, blocks = plan_grid(scene, depth_dir, s)
    depth_max = float(s.depth_max) if s.depth_max else 1e6
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=BLOCK_RESOLUTION,
        block_count=blocks, device=o3c.Device("CPU:0"))
    fused = 0
    for cam, depth in tqdm(fused_depths(scene, depth_dir, s), total=len(scene.cameras),
                           desc=f"TSDF (voxel {voxel:.4g})", unit="view"):
        if not (depth > 0).any():  # nothing of this view in the region (open3d refuses an empty view)
            continue
        intrinsic = o3c.Tensor(cam.K, o3c.float64)
        extrinsic = o3c.Tensor(cam.world_to_camera, o3c.float64)
        depth_img = o3d.t.geometry.Image(o3c.Tensor(depth))
        if cam.image_path is not None and cam.image_path.exists():
            rgb = read_view(cam).astype(np.float32) / 255.0
        else:
            rgb = np.full((cam.height, cam.width, 3), 0.7, np.float32)
        color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb)))
        try:
            coords = vbg.compute_unique_block_coordinates(depth_img, intrinsic, extrinsic, 1.0, depth_max,
                                                          trunc_voxel_multiplier=s.trunc_factor)
        except RuntimeError as e:  # open3d aborts on a view none of whose sampled depths touch a block
            if "No block is touched" not in str(e):
                raise
            continue  # (sparse or out-of-range depth): it adds nothing, as an empty view
        vbg.integrate(coords, depth_img, color_img, intrinsic, extrinsic, 1.0, depth_max,
                      trunc_voxel_multiplier=s.trunc_factor)
        fused += 1
    mesh = o3d.geometry.TriangleMesh()  # open3d cannot extract from a grid that no view reached
    if fused:
        mesh = vbg.extract_triangle_mesh(weight_threshold=s.weight_threshold).to_legacy()
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
