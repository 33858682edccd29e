"""eve3d.mesh: depth maps fused into a TSDF and its mesh (the grid's blocks, the region, the mesh's order and clusters)."""
import json

import numpy as np
import pytest

from eve3d.core.io import load_scene
from eve3d.core.maps import load_maps
from eve3d.synth import generate
from tests.helpers import run_cli


@pytest.mark.slow
@pytest.mark.parametrize("which", ["object", "room"])
def test_oracle_tsdf_mesh_scores_high(which, request, tmp_path):
    """The exact depth of the built-in scenes, fused at the cpu preset's coarse voxel,
    scores F ≥ 0.98 under the synthetic protocol."""
    dataset = request.getfixturevalue(f"{which}_dataset")  # each case makes only its own scene
    priors, mesh, metrics = tmp_path / "priors", tmp_path / "mesh.ply", tmp_path / "metrics.json"
    r = run_cli("stereo-depth", "--backend", "oracle", "--scene", dataset, "--out", priors)
    assert r.returncode == 0, r.stderr
    maps = load_maps(priors / "000.npz")
    assert maps["depth"].dtype == np.float32 and (priors / "000.depth.png").exists()
    r = run_cli("mesh", "--scene", dataset, "--depth", priors, "--out", mesh, "--coarsen", "5")
    assert r.returncode == 0, r.stderr
    if which == "object":  # a second fusion of the same maps writes the same bytes
        r = run_cli("mesh", "--scene", dataset, "--depth", priors, "--out", tmp_path / "again.ply", "--coarsen", "5")
        assert r.returncode == 0, r.stderr
        assert (tmp_path / "again.ply").read_bytes() == mesh.read_bytes()
    r = run_cli("evaluate", "--mesh", mesh, "--gt", dataset / "gt/mesh.ply", "--scene", dataset, "--out", metrics)
    assert r.returncode == 0, r.stderr
    assert "tau = " in r.stdout
    m = json.loads(metrics.read_text())
    assert m["record"] == "evaluation" and m["fscore"] >= 0.98, m
    assert m["chamfer"] < m["tau"] / 5


def test_canonical_order_ignores_the_order_a_mesh_comes_in():
    """Two orderings of one mesh (vertices and triangles shuffled, as open3d's threaded
    extraction returns them) come out identical, with every triangle's orientation kept."""
    import open3d as o3d

    from eve3d.mesh import canonical_order

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 10)
    sphere.compute_vertex_normals()
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(sphere.vertices))
    triangles = np.argsort(perm)[np.asarray(sphere.triangles)][rng.permutation(len(sphere.triangles))]
    shuffled = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(sphere.vertices)[perm]),
                                         o3d.utility.Vector3iVector(triangles))
    shuffled.vertex_normals = o3d.utility.Vector3dVector(np.asarray(sphere.vertex_normals)[perm])
    a, b = canonical_order(sphere), canonical_order(shuffled)
    for key in ("vertices", "triangles", "vertex_normals"):
        assert np.array_equal(np.asarray(getattr(a, key)), np.asarray(getattr(b, key))), key
    a.compute_triangle_normals()
    sphere.compute_triangle_normals()

    def outward(m):
        centres = np.asarray(m.vertices)[np.asarray(m.triangles)].mean(1)
        return np.einsum("ij,ij->i", np.asarray(m.triangle_normals), centres)

    assert (outward(a) > 0).all() and (outward(sphere) > 0).all()


@pytest.mark.parametrize("kind", ["object", "room"])
def test_fusion_allocates_exactly_the_blocks_it_fuses_a_slab_at_a_time(kind, tmp_path, monkeypatch):
    """The grid is sized, reading a view at a time, to the blocks the views touch plus
    one view's worth, so open3d never grows it; the mesh is the one a grid of 8 times as
    many blocks gives (the size only holds blocks); and fused a slab of about 300 blocks at
    a time (open3d extracts from at most 262,144), it is the same mesh vertex for vertex."""
    from dataclasses import replace

    from eve3d import mesh as meshing
    from eve3d.core.io import load_scene
    from eve3d.core.settings import MeshSettings
    from eve3d.priors.oracle import priors_from_mesh

    scene = load_scene(generate(kind, tmp_path / kind, views=8, width=96, height=72))
    priors_from_mesh(scene, tmp_path / "depth", preview=False)
    made, make, count = [], meshing._grid, meshing.count_blocks

    def recorded(voxel, blocks):
        made.append((blocks, make(voxel, blocks)))
        return made[-1][1]

    monkeypatch.setattr(meshing, "_grid", recorded)
    settings = MeshSettings(coarsen=2)
    exact = meshing.fuse(scene, tmp_path / "depth", settings)
    blocks, grid = made[-1]
    assert grid.hashmap().capacity() == blocks and 0 < grid.hashmap().size() < blocks  # it never grew
    monkeypatch.setattr(meshing, "count_blocks", lambda *args: replace(count(*args), most=8 * blocks))
    generous = meshing.fuse(scene, tmp_path / "depth", settings)
    assert made[-1][1].hashmap().size() == grid.hashmap().size()
    monkeypatch.setattr(meshing, "count_blocks", count)
    monkeypatch.setattr(meshing, "TILE_BLOCKS", 300)
    made.clear()
    tiled = meshing.fuse(scene, tmp_path / "depth", settings)
    slabs = made[1:]  # (the first: the probe that counts)
    # a slab is 300 blocks at most unless one layer of blocks (a wall across the axis) has more
    assert len(slabs) > 10 and max(g.hashmap().size() for _, g in slabs) < grid.hashmap().size() / 3
    assert all(g.hashmap().capacity() == n for n, g in slabs)  # none grew
    for key in ("vertices", "triangles", "vertex_colors", "vertex_normals"):
        for other in (generous, tiled):
            assert np.array_equal(np.asarray(getattr(exact, key)), np.asarray(getattr(other, key))), key


def test_fusion_past_what_open3d_extracts_is_refused_before_fusing(tiny_dataset, tmp_path, monkeypatch):
    """Where even a slab of one layer of blocks is more than open3d's mesh extraction
    handles (it crashes past 262,144 blocks), the fusion stops with an error that names
    the remedy, before any view is fused."""
    from eve3d import mesh as meshing
    from eve3d.core.errors import Eve3dError
    from eve3d.core.io import load_scene
    from eve3d.core.settings import MeshSettings
    from eve3d.priors.oracle import priors_from_mesh

    scene = load_scene(tiny_dataset)
    priors_from_mesh(scene, tmp_path / "depth", preview=False)
    made, make = [], meshing._grid
    monkeypatch.setattr(meshing, "_grid", lambda voxel, blocks: made.append(blocks) or make(voxel, blocks))
    monkeypatch.setattr(meshing, "MAX_BLOCKS", 10)
    monkeypatch.setattr(meshing, "TILE_BLOCKS", 5)
    with pytest.raises(Eve3dError, match=r"open3d extracts a mesh from at most 10\. Use a larger voxel"):
        meshing.fuse(scene, tmp_path / "depth", MeshSettings(coarsen=5))
    assert made == [1]  # the probe that counts the blocks, no grid to fuse into


def test_triangle_clusters_are_open3ds():
    """The clusters that drop floaters join triangles through shared edges, as open3d's
    ``cluster_connected_triangles`` does: the same cluster sizes per triangle on a sphere with
    floaters, two triangles touching only at a vertex (separate) and an edge that three
    triangles share (one cluster)."""
    import open3d as o3d

    from eve3d.mesh import triangle_clusters

    parts = [o3d.geometry.TriangleMesh.create_sphere(1.0, 20)]
    parts += [o3d.geometry.TriangleMesh.create_sphere(0.05, 4).translate((2 + k, 0, 0)) for k in range(3)]
    v = [np.asarray(p.vertices) for p in parts]
    t = [np.asarray(p.triangles) for p in parts]
    v.append(np.array([[5, 0, 0], [6, 0, 0], [5, 1, 0], [4, -1, 0], [4, 0, 1], [5, 0, 1], [6, 1, 1]], float))
    t.append(np.array([[0, 1, 2], [0, 3, 4], [0, 1, 5], [0, 1, 6]]))  # a bow tie at vertex 0; edge 0-1 thrice
    offsets = np.cumsum([0] + [len(x) for x in v[:-1]])
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.concatenate(v)),
                                     o3d.utility.Vector3iVector(np.concatenate([x + o for x, o in zip(t, offsets)])))
    labels, counts, _ = mesh.cluster_connected_triangles()
    ours = triangle_clusters(np.asarray(mesh.triangles), len(mesh.vertices))
    assert np.array_equal(np.asarray(counts)[np.asarray(labels)], np.bincount(ours)[ours])
    assert len(np.unique(ours)) == len(np.asarray(counts)) == 6


def test_a_far_background_does_not_become_a_wall(tmp_path):
    """Every pixel that misses the object sees a 'sky' 60 units away, as a trained model
    renders one: fused without a region the sky is a wall far out; within the region of
    interest (the sparse points' box, doubled) the mesh is the object's size."""
    from eve3d.core.maps import save_maps
    from eve3d.core.raycast import MeshRaycaster
    from eve3d.core.settings import MeshSettings
    from eve3d.mesh import extent_report, fuse

    scene = load_scene(generate("object", tmp_path / "data", views=12, width=160, height=120))
    caster = MeshRaycaster.from_file(scene.gt_mesh)
    for cam in scene.cameras:
        depth = caster.cast(cam).depth.astype(np.float32)
        save_maps(tmp_path / "depth" / f"{cam.view_id}.npz", preview=False, depth=np.where(depth > 0, depth, 60.0))
    scene.kind = "scene"  # an open scene: no largest-cluster filter to hide the wall
    walled = extent_report(fuse(scene, tmp_path / "depth", MeshSettings(coarsen=8, region=0)), scene)
    cropped = extent_report(fuse(scene, tmp_path / "depth", MeshSettings(coarsen=8)), scene)
    print(walled, cropped, sep="\n")
    assert walled["extent_ratio"] > 10
    assert cropped["extent_ratio"] <= 2.0 and max(cropped["extent"]) < 3.5  # the object is 3 × 3 × 0.85


def test_pixels_seen_more_obliquely_than_max_incidence_are_not_fused(tmp_path):
    """A wall facing the camera: at the image centre its ray meets it head on, 45° where
    (u − cx)/fx = 1; with ``mesh.max_incidence`` 40 the pixels beyond that are left out, the
    depths within it fused as they are."""
    from eve3d.core.maps import save_maps
    from eve3d.core.scene import Camera, Scene
    from eve3d.mesh import incidence, view_depths

    cam = Camera("v.png", 40, 20, np.array([[10.0, 0, 20], [0, 10, 10], [0, 0, 1]]), np.eye(3), np.zeros(3))
    normal = np.broadcast_to(np.float32([0, 0, -1]), (20, 40, 3))
    angle = incidence(cam, normal)
    assert angle[10, 20] == pytest.approx(np.degrees(np.arctan(np.hypot(0.05, 0.05))), abs=1e-3)
    assert angle[10, 29] == pytest.approx(np.degrees(np.arctan(np.hypot(0.95, 0.05))), abs=1e-3)
    save_maps(tmp_path / "v.npz", preview=False, depth=np.full((20, 40), 2.0), confidence=np.ones((20, 40)),
              normal=normal)
    scene = Scene(None, [cam])
    (_, every), = view_depths(scene, tmp_path, 0.5)
    (_, kept), = view_depths(scene, tmp_path, 0.5, max_incidence=40)
    assert (every == 2).all()
    assert np.array_equal(kept > 0, angle <= 40) and 0.2 < (kept > 0).mean() < 0.9 and (kept[kept > 0] == 2).all()
