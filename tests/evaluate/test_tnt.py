"""eve3d.evaluate.tnt: the Tanks and Temples protocol (scores, the alignment of known frames, input errors)."""

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import write_image
from eve3d.core.io import load_scene
from eve3d.core.io.colmap import write_colmap
from eve3d.core.scene import Camera, Scene, look_at
from eve3d.core.settings import EvalSettings
from eve3d.core.surface import sample_surface
from eve3d.evaluate import EvalInputs
from eve3d.evaluate.tnt import TAU, align_trajectory, evaluate_tnt, log_centres, read_crop, score
from eve3d.tools.standin import similarity, write_crop, write_log


def inside_polygon(xy, polygon):
    """Even-odd rule: a ray from each point towards +x crosses the polygon's edges an odd
    number of times exactly when the point is inside."""
    poly = np.asarray(polygon, dtype=np.float64)
    inside = np.zeros(len(xy), dtype=bool)
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, axis=0)):
        straddles = (y0 > xy[:, 1]) != (y1 > xy[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = x0 + (xy[:, 1] - y0) * (x1 - x0) / (y1 - y0)
        inside ^= straddles & (xy[:, 0] < x_cross)
    return inside


def brute_nearest(query, reference, chunk=2000):
    """Exact nearest distances, all pairs: the nearest by |q|² - 2 q·r + |r|², its
    distance then recomputed from the difference."""
    out = np.empty(len(query))
    r2 = (reference**2).sum(1)
    for i in range(0, len(query), chunk):
        q = query[i:i + chunk]
        nearest = np.argmin(r2[None, :] - 2 * q @ reference.T, axis=1)
        out[i:i + chunk] = np.linalg.norm(q - reference[nearest], axis=1)
    return out


def height(x, y):
    return 0.1 * np.sin(2 * x) * np.cos(3 * y) + 0.05 * x


def jittered_grid(rng, x_range, y_range, spacing, jitter):
    """Grid points whose neighbours differ by more than spacing - 2·jitter in x or y, so
    no two share a voxel smaller than that (voxel down-sampling leaves them as they are)."""
    x, y = np.meshgrid(np.arange(*x_range, spacing), np.arange(*y_range, spacing), indexing="ij")
    xy = np.stack([x.ravel(), y.ravel()], axis=1)
    return xy + rng.uniform(-jitter, jitter, xy.shape)


def test_score_matches_brute_force(tmp_path):
    import open3d as o3d

    tau, rng = 0.01, np.random.default_rng(1)
    gt_xy = jittered_grid(rng, (0.0, 1.2), (0.0, 1.2), tau, 0.1 * tau)
    gt = np.column_stack([gt_xy, height(*gt_xy.T)])
    # Ours: part of the surface (some of it outside the crop), on another grid, noisy in z.
    xy = jittered_grid(rng, (0.3, 1.4), (0.1, 1.0), 1.1 * tau, 0.1 * tau) + 0.37 * tau
    recon = np.column_stack([xy, height(*xy.T) + 0.3 * tau + rng.normal(0, 0.8 * tau, len(xy))])
    # Floaters above the surface, some above the crop's axis_max; a coarse grid keeps them apart.
    cells = jittered_grid(rng, (0.0, 1.2), (0.0, 1.2), 5 * tau, tau)
    floaters = np.column_stack([cells, rng.uniform(0.25, 0.55, len(cells))])[rng.random(len(cells)) < 0.05]
    recon = np.vstack([recon, floaters])
    polygon = [(0.05, 0.02), (1.13, 0.07), (1.17, 1.1), (0.6, 0.7), (0.03, 1.15)]   # with a notch
    write_crop(tmp_path / "crop.json", polygon, -0.5, 0.4)

    s = score(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(recon)),
              o3d.geometry.PointCloud(o3d.utility.Vector3dVector(gt)), np.eye(4),
              read_crop(tmp_path / "crop.json"), tau)

    def crop(p):
        return p[inside_polygon(p[:, :2], polygon) & (p[:, 2] >= -0.5) & (p[:, 2] <= 0.4)]

    r_in, g_in = crop(recon), crop(gt)
    d1, d2 = brute_nearest(r_in, g_in), brute_nearest(g_in, r_in)
    precision, recall = np.mean(d1 < tau), np.mean(d2 < tau)
    assert (len(s.recon.points), len(s.gt.points)) == (len(r_in), len(g_in))  # down-sampling kept every point
    assert len(r_in) < len(recon) - 1000 and len(g_in) < len(gt)                # and the crop cut some
    assert s.precision == pytest.approx(precision, abs=1e-3)
    assert s.recall == pytest.approx(recall, abs=1e-3)
    assert 0.2 < s.precision < 0.95 and 0.2 < s.recall < 0.95
    # The distances themselves: equal up to the 5τ search bound, beyond it inf.
    for ours, ref in ((s.recon_distances, d1), (s.gt_distances, d2)):
        assert np.allclose(np.sort(ours[np.isfinite(ours)]), np.sort(ref[ref < 5 * tau]))
        assert np.sum(np.isinf(ours)) == np.sum(ref >= 5 * tau)
    assert np.isinf(s.recon_distances).any()   # the floaters


def test_empty_side_scores_zero(tmp_path):
    import open3d as o3d

    write_crop(tmp_path / "crop.json", [(0, 0), (1, 0), (1, 1), (0, 1)], 0, 1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((500, 3))))
    away = np.eye(4)
    away[:3, 3] = 5.0                                        # ours moved out of the crop
    s = score(cloud, cloud, away, read_crop(tmp_path / "crop.json"), 0.05)
    assert (s.precision, s.recall, len(s.recon.points)) == (0.0, 0.0, 0)
    assert score(cloud, cloud, np.eye(4), read_crop(tmp_path / "crop.json"), 0.05)[:2] == (1.0, 1.0)


def apply(m, points):
    return points @ m[:3, :3].T + m[:3, 3]


G = similarity(2.0, [0.3, -1.0, 0.5], 0.7, [1.0, -2.0, 0.5])
"""COLMAP frame → GT frame (``{Scene}_trans.txt``)."""
S = similarity(1.05, [1.0, 0.4, -0.2], 0.4, [0.3, 0.2, -0.1])
"""GT frame → our reconstruction's frame."""
CAMERA_NOISE = 0.004
"""Our camera centres are off by this (GT units, 1.3τ): the ICP has to finish the alignment."""


def gt_mesh_parts():
    """A few boxes and a sphere (no symmetry), about 0.4 units across, in the GT frame."""
    import open3d as o3d

    box, sphere = o3d.geometry.TriangleMesh.create_box, o3d.geometry.TriangleMesh.create_sphere
    return [box(0.25, 0.16, 0.12).translate((-0.12, -0.08, 0.0)),
            box(0.08, 0.1, 0.22).translate((0.05, 0.03, 0.0)),
            sphere(0.06, resolution=20).translate((-0.08, 0.02, 0.18)),
            box(0.06, 0.05, 0.04).translate((0.14, -0.12, 0.0))]


def noisy_reconstruction(rng, noise=0.001, floaters=150):
    """The GT shapes, finely triangulated, each vertex moved along its normal by
    N(0, noise) (5% by 4× that), plus small floater triangles in the crop volume, as an MVS
    mesh has. Returns the mesh (GT frame) and the true (noise-free) positions of its vertices.

    A clean copy of the GT would not do: the toolbox's ICP stops as soon as the number of
    points within the threshold repeats, which with no points near the threshold is after
    the first iteration of each stage."""
    import open3d as o3d

    parts = gt_mesh_parts()
    mesh = o3d.geometry.TriangleMesh()
    for part, levels in zip(parts, (5, 5, 2, 4)):
        mesh += part.subdivide_midpoint(levels)
    mesh.remove_duplicated_vertices()
    mesh.compute_vertex_normals()
    v_true = np.asarray(mesh.vertices).copy()
    offset = rng.normal(0, noise, (len(v_true), 1)) * np.where(rng.random((len(v_true), 1)) < 0.05, 4, 1)
    mesh.vertices = o3d.utility.Vector3dVector(v_true + np.asarray(mesh.vertex_normals) * offset)
    corners = rng.uniform((-0.28, -0.28, -0.04), (0.28, 0.28, 0.38), (floaters, 1, 3))
    corners = corners + rng.normal(0, 0.002, (floaters, 3, 3))
    mesh += o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(corners.reshape(-1, 3)),
                                      o3d.utility.Vector3iVector(np.arange(3 * floaters).reshape(-1, 3)))
    return mesh, v_true


def write_tnt_layout(root, name="Ignatius", n_log=20, gt_points=250_000):
    """A T&T dataset folder (GT frame, COLMAP frame via G) with our cameras and mesh (frame
    S); returns the mesh path and the true positions of its surface vertices in the GT frame
    and in ours."""
    import open3d as o3d

    rng = np.random.default_rng(0)
    (root / "images").mkdir(parents=True)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 20))
    centres = np.column_stack([1.0 * np.cos(angles), 1.0 * np.sin(angles), rng.uniform(0.3, 0.6, 20)])
    target = np.array([0.0, 0.0, 0.1])
    K = [[8.0, 0, 4.0], [0, 8.0, 3.0], [0, 0, 1]]
    cameras, log = [], []
    for i, c in enumerate(centres):
        rot = look_at(c, target, np.array([0.0, 0.0, 1.0]))[0].T   # camera-to-world, GT frame
        c_ours = apply(S, c[None])[0] + rng.normal(0, CAMERA_NOISE * 1.05, 3)
        r_ours = S[:3, :3] @ rot / 1.05
        cameras.append(Camera(f"{i:03d}.png", 8, 6, K, r_ours.T, -r_ours.T @ c_ours))
        write_image(root / "images" / f"{i:03d}.png", np.full((6, 8, 3), 40 * (i % 6), np.uint8))
        pose = np.eye(4)
        pose[:3, :3] = np.linalg.inv(G[:3, :3] / 2.0) @ rot
        pose[:3, 3] = apply(np.linalg.inv(G), c[None])[0]
        log.append(pose)
    write_colmap(Scene(root=root, cameras=cameras), root / "sparse" / "0")
    write_log(root / f"{name}_COLMAP_SfM.log", log[:n_log])
    np.savetxt(root / f"{name}_trans.txt", G)

    mesh = sum(gt_mesh_parts()[1:], gt_mesh_parts()[0])
    v, tri = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    gt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sample_surface(v, tri, gt_points, rng)))
    o3d.io.write_point_cloud(str(root / f"{name}.ply"), gt)
    write_crop(root / f"{name}.json", [(-0.3, -0.3), (0.35, -0.25), (0.3, 0.3), (-0.25, 0.35)], -0.05, 0.4)
    ours, v_gt = noisy_reconstruction(rng)
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), ours.transform(S))
    return root / "mesh.ply", v_gt, apply(S, v_gt)


@pytest.fixture(scope="module")
def tnt_layout(tmp_path_factory):
    root = tmp_path_factory.mktemp("tnt") / "Ignatius"
    mesh_path, v_gt, v_ours = write_tnt_layout(root)
    return root, mesh_path, v_gt, v_ours


def test_alignment_recovers_the_frame(tnt_layout, tmp_path):
    import open3d as o3d

    root, mesh_path, v_gt, v_ours = tnt_layout
    scene = load_scene(root)
    tau = TAU["Ignatius"]
    # RANSAC on the camera centres alone lands within a few τ.
    rough = align_trajectory([c.center for c in scene.cameras], log_centres(scene.extras["gt_trajectory"]),
                             scene.extras["alignment"])
    rough_error = np.linalg.norm(apply(rough, v_ours) - v_gt, axis=1).max()
    assert rough_error < 5 * tau

    # ICP finishes it. With the toolbox's stopping rule (see noisy_reconstruction) how far it
    # gets depends on the start: over 16 camera-noise draws the largest vertex error had a
    # median of 0.06τ (0.2τ at worst, from a 10τ start); this draw ends at 0.04τ. Those
    # figures were measured with the vertices and area samples (the `sampled` points), so
    # this test scores those: vertices only end this draw at 0.21τ (fewer points to fit).
    m = evaluate_tnt(EvalInputs(scene=scene, reconstruction=mesh_path, out=tmp_path / "metrics.json",
                                settings=EvalSettings(tnt_points="sampled")))
    error = np.linalg.norm(apply(np.array(m["transformation"]), v_ours) - v_gt, axis=1).max()
    assert error < tau / 10 and error < rough_error / 3, (error, rough_error)
    assert (m["tau"], m["tau_rule"]) == (tau, "T&T toolbox table (Ignatius)")
    assert m["precision"] > 0.95 and m["recall"] > 0.95
    assert m["fscore"] == pytest.approx(2 * m["precision"] * m["recall"] / (m["precision"] + m["recall"]))
    assert CAMERA_NOISE < m["alignment_rmse"] < 4 * CAMERA_NOISE   # camera residuals after RANSAC, GT units
    for name, count in (("precision", m["n_recon"]), ("recall", m["n_gt"])):
        pcd = o3d.io.read_point_cloud(str(tmp_path / f"{name}.ply"))
        assert len(pcd.points) == count > 10_000 and pcd.has_colors()
        colours = np.asarray(pcd.colors)
        assert colours.min() >= 0 and colours.max() <= 1
        assert np.mean((colours[:, 0] == 1) & (colours[:, 1] > 0.75)) > 0.9   # mostly yellow-white: d < τ
    assert not list(tmp_path.glob(".*"))   # no temporary files left


@pytest.mark.slow
def test_official_mode_scores_the_vertices_of_a_coarse_mesh(tnt_layout, tmp_path):
    """By default a mesh is scored as the toolbox scores it: its PLY read as a point cloud,
    i.e. its vertices. On a mesh whose vertices lie about τ apart that misses GT points
    between them (lower recall); the `sampled` mode adds area samples and differs."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    root, mesh_path, _, _ = tnt_layout
    scene, tau = load_scene(root), TAU["Ignatius"]
    fine = o3d.io.read_triangle_mesh(str(mesh_path))
    coarse = fine.simplify_vertex_clustering(voxel_size=0.75 * tau * 1.05)   # our frame is 1.05× the GT's
    corners = np.asarray(coarse.vertices)[np.asarray(coarse.triangles)]
    spacing = np.median(np.linalg.norm(corners[:, 0] - corners[:, 1], axis=1)) / 1.05
    assert 0.7 * tau < spacing < 1.5 * tau
    path = tmp_path / "coarse.ply"
    o3d.io.write_triangle_mesh(str(path), coarse)

    official = evaluate_tnt(EvalInputs(scene=scene, reconstruction=path, out=tmp_path / "metrics.json"))
    assert official["points"] == "vertices"
    # The toolbox's own reading, aligned by the transform the evaluation found: crop, τ/2 voxels.
    toolbox = o3d.io.read_point_cloud(str(path)).transform(np.array(official["transformation"]))
    toolbox = read_crop(root / "Ignatius.json").crop_point_cloud(toolbox).voxel_down_sample(tau / 2)
    gt = o3d.io.read_point_cloud(str(root / "Ignatius.ply"))
    gt = read_crop(root / "Ignatius.json").crop_point_cloud(gt).voxel_down_sample(tau / 2)
    ours, theirs = np.asarray(toolbox.points), np.asarray(gt.points)
    assert official["n_recon"] == len(ours)
    # exact nearest distances by scipy's k-d tree (the evaluation uses open3d's)

    def nearest(query, reference):
        return cKDTree(reference).query(query)[0]

    assert official["precision"] == pytest.approx(np.mean(nearest(ours, theirs) < tau), abs=1e-9)
    assert official["recall"] == pytest.approx(np.mean(nearest(theirs, ours) < tau), abs=1e-9)

    sampled = evaluate_tnt(EvalInputs(scene=scene, reconstruction=path, out=tmp_path / "metrics.json",
                                      settings=EvalSettings(tnt_points="sampled")))
    assert sampled["points"] == "sampled" and sampled["n_recon"] > 3 * official["n_recon"]
    # measured: recall 0.79 (vertices) against 0.999 (sampled), F 0.87 against 0.98
    assert sampled["recall"] > official["recall"] + 0.05 and sampled["fscore"] > official["fscore"] + 0.02


def test_log_with_other_cameras_is_refused(tmp_path):
    mesh_path = write_tnt_layout(tmp_path / "t", n_log=19, gt_points=1000)[0]
    with pytest.raises(Eve3dError, match=r"Ignatius_COLMAP_SfM\.log.*19 cameras.*20"):
        evaluate_tnt(EvalInputs(scene=load_scene(tmp_path / "t"), reconstruction=mesh_path, out=tmp_path / "m.json"))


def test_unknown_scene_needs_tau(tmp_path):
    mesh_path = write_tnt_layout(tmp_path / "t", name="Playground", gt_points=1000)[0]
    scene = load_scene(tmp_path / "t")
    with pytest.raises(Eve3dError, match=r"'Playground'.*Barn.*Ignatius.*Truck.*evaluate\.tau"):
        evaluate_tnt(EvalInputs(scene=scene, reconstruction=mesh_path, out=tmp_path / "m.json"))
    m = evaluate_tnt(EvalInputs(scene=scene, reconstruction=mesh_path, out=tmp_path / "m.json",
                                settings=EvalSettings(tau=0.02, samples=20_000)))
    assert (m["tau"], m["tau_rule"]) == (0.02, "given (evaluate.tau)")


@pytest.mark.parametrize("text", [None, "{not json", '{"class_name": "PointCloud"}',
                                  '{"class_name": "SelectionPolygonVolume", "orthogonal_axis": "Z", '
                                  '"axis_min": 0, "axis_max": 1, "bounding_polygon": [], '
                                  '"version_major": 1, "version_minor": 0}'])
def test_bad_crop_file(tmp_path, text):
    path = tmp_path / "Barn.json"
    if text is not None:
        path.write_text(text)
    with pytest.raises(Eve3dError, match="Barn.json"):
        read_crop(path)
