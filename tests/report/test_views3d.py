"""eve3d.report.views3d: the 3D views (reduced surfaces, error points, frusta) and their page in a browser."""
import numpy as np

from eve3d.evaluate.common import write_error_maps


def _ring(count: int, radius: float, height: float) -> list:
    """Cameras on a ring round the origin, above it, looking at it (z up)."""
    from eve3d.core.scene import Camera
    from eve3d.mesh import view_from

    like = Camera("like", 160, 120, np.array([[150.0, 0, 80], [0, 150, 60], [0, 0, 1]]), np.eye(3), np.zeros(3))
    angles = 2 * np.pi * np.arange(count) / count
    return [view_from(np.array([radius * np.cos(a), radius * np.sin(a), height]), np.zeros(3), np.array([0, 0, 1.0]),
                    like, 160, f"view{k}") for k, a in enumerate(angles)]


def test_reduced_surface_keeps_the_shape_within_its_budget(tmp_path):
    """A unit sphere of 159,200 triangles kept in ≤ 5,000: every vertex stays within 2 % of the
    radius and the area within 3 %; a point cloud keeps a uniform subset."""
    import open3d as o3d

    from eve3d.report.views3d import reduced_surface

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution=200)
    o3d.io.write_triangle_mesh(str(tmp_path / "sphere.ply"), sphere)
    kept = reduced_surface(tmp_path / "sphere.ply", triangles=5000)
    assert kept.original == len(sphere.triangles) > 70_000 and 2000 < kept.kept <= 5000
    assert np.abs(np.linalg.norm(kept.vertices, axis=1) - 1).max() < 0.02
    area = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(kept.vertices.astype(float)),
                                     o3d.utility.Vector3iVector(kept.faces)).get_surface_area()
    assert abs(area / sphere.get_surface_area() - 1) < 0.03
    assert kept.note("pgsr") == f"pgsr: {kept.kept:,} of 159,200 triangles"
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).normal(size=(9000, 3))))
    o3d.io.write_point_cloud(str(tmp_path / "gt.ply"), cloud)
    points = reduced_surface(tmp_path / "gt.ply", points=1000)
    assert points.faces is None and points.kept == 1000 and points.original == 9000
    assert np.isin(points.vertices[:, 0], np.asarray(cloud.points, np.float32)[:, 0]).all()


def test_error_points_read_their_distance_back_from_the_colours(tmp_path):
    """The 3D view colours each error point by the distance its map's colour stands for:
    read back to within one of the colour table's 256 steps."""
    from eve3d.report.views3d import error_points

    rng = np.random.default_rng(1)
    points = np.c_[np.arange(5000.0), rng.uniform(size=(5000, 2))]  # x: the point's index
    distances, top = rng.uniform(0, 4, 5000), 3.0
    write_error_maps(tmp_path, points, distances, points, distances, top)
    shown, fraction = error_points(tmp_path / "precision.ply", count=2000)
    assert shown.kept == 2000 and shown.original == 5000
    index = shown.vertices[:, 0].astype(int)
    assert len(set(index)) == 2000
    assert np.abs(fraction * top - np.minimum(distances[index], top)).max() <= top / 256


def test_frusta_reach_the_image_corners():
    """Each pyramid's apex is its camera's centre and its base corners project to the
    image's corners, ``size`` in front of it."""
    from eve3d.report.views3d import frusta

    cameras = _ring(3, 2.0, 1.0)
    lines = frusta(cameras, 0.1).reshape(len(cameras), 4, 4, 3)  # camera, side, (apex, a, b, break)
    for cam, sides in zip(cameras, lines):
        assert np.allclose(sides[:, 0], cam.center, atol=1e-6) and np.isnan(sides[:, 3]).all()
        x = (sides[:, 1] @ cam.R.T) + cam.t
        assert np.allclose(x[:, 2], 0.1, atol=1e-5)
        uv = (x @ cam.K.T)[:, :2] / x[:, 2:]
        assert np.allclose(uv, [[0, 0], [160, 0], [160, 120], [0, 120]], atol=1e-3)


def test_a_scene_in_3d_renders_in_the_browser_offline(tmp_path):
    """Two methods' meshes (a sphere, and one 3 % too big), their error maps, the GT and the
    cameras: the page loads in headless Chromium with no console error and no request
    leaving the machine; its 3D view is not blank; the second method's button shows the other
    mesh; the title says how far each mesh was reduced."""
    import json
    import re

    import open3d as o3d
    from playwright.sync_api import sync_playwright

    from eve3d.core.layout import Layout
    from eve3d.report.views3d import BACKGROUND, scene_view
    from tests.helpers import CHROMIUM, VIEW3D_BACKGROUND, nonbackground

    layout = Layout(tmp_path / "results")
    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution=60)
    sphere.compute_vertex_normals()
    gt = tmp_path / "gt.ply"
    o3d.io.write_triangle_mesh(str(gt), sphere)
    gt_points = np.random.default_rng(0).normal(size=(4000, 3))
    gt_points /= np.linalg.norm(gt_points, axis=1, keepdims=True)  # on the GT sphere
    for method, scale in (("pgsr", 1.03), ("eve3d", 1.0)):
        layout.method("ball", method).mkdir(parents=True)
        mesh = o3d.geometry.TriangleMesh(sphere).scale(scale, center=np.zeros(3))
        o3d.io.write_triangle_mesh(str(layout.mesh("ball", method)), mesh)
        error = abs(scale - 1) * np.ones(len(gt_points))
        maps = write_error_maps(layout.method("ball", method), gt_points * scale, error, gt_points, error, 0.09)
        layout.metrics("ball", method).write_text(json.dumps(maps))
    page = tmp_path / "ball.html"
    assert scene_view(layout, "ball", ["eve3d", "pgsr"], ("×10⁻³", 1e3), gt, _ring(8, 4.0, 2.0), page)
    assert re.search(r"eve3d: [\d,]+ triangles", page.read_text())  # fewer than the budget: none left out

    assert tuple(int(v) for v in re.findall(r"\d+", BACKGROUND)) == VIEW3D_BACKGROUND
    problems = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        tab = browser.new_page(viewport={"width": 1000, "height": 800})
        tab.on("console", lambda m: m.type == "error" and problems.append(m.text))
        tab.on("pageerror", lambda e: problems.append(str(e)))
        tab.on("request", lambda r: not r.url.startswith(("file:", "data:", "blob:")) and problems.append(r.url))
        tab.goto(page.as_uri())
        view = tab.locator(".gl-container canvas").first
        view.wait_for()
        tab.wait_for_timeout(1000)
        first = view.screenshot()
        tab.get_by_text("pgsr", exact=True).click()
        tab.wait_for_timeout(1000)
        second = view.screenshot()
        browser.close()
    assert problems == []
    assert nonbackground(first, VIEW3D_BACKGROUND) > 0.05 and nonbackground(second, VIEW3D_BACKGROUND) > 0.05
    assert first != second


def test_error_points_scored_in_the_gt_frame_come_back_to_the_scene(tmp_path, monkeypatch):
    """T&T scores in its GT's frame (metrics.json's ``transformation``: ours → GT, a similarity):
    the 3D view carries that method's error points and the GT back onto its mesh."""
    import json

    import open3d as o3d

    import eve3d.report.views3d as views3d
    from eve3d.core.layout import Layout

    layout = Layout(tmp_path / "results")
    ours = np.random.default_rng(0).normal(size=(3000, 3))
    ours /= np.linalg.norm(ours, axis=1, keepdims=True)  # on our mesh, the unit sphere
    angle, scale = 0.7, 2.5
    to_gt = np.eye(4)
    to_gt[:3, :3] = scale * np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    to_gt[:3, 3] = [10.0, -4.0, 3.0]
    in_gt = ours @ to_gt[:3, :3].T + to_gt[:3, 3]
    layout.method("barn", "eve3d").mkdir(parents=True)
    o3d.io.write_triangle_mesh(str(layout.mesh("barn", "eve3d")), o3d.geometry.TriangleMesh.create_sphere(1.0))
    errors = np.full(len(ours), 0.01)
    maps = write_error_maps(layout.method("barn", "eve3d"), in_gt, errors, in_gt, errors, 0.03)
    layout.metrics("barn", "eve3d").write_text(json.dumps({**maps, "transformation": to_gt.tolist()}))
    gt = tmp_path / "gt.ply"
    o3d.io.write_point_cloud(str(gt), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(in_gt)))
    figures = []
    monkeypatch.setattr(views3d, "write_scene_view", lambda fig, out: figures.append(fig))
    assert views3d.scene_view(layout, "barn", ["eve3d"], ("mm", 1e3), gt, [], tmp_path / "barn.html")
    points = [trace for trace in figures[0].data if trace.type == "scatter3d"]
    assert sorted(trace.name for trace in points) == ["GT", "eve3d precision errors", "eve3d recall errors"]
    for trace in points:  # on the unit sphere again
        radius = np.linalg.norm(np.c_[trace.x, trace.y, trace.z], axis=1)
        assert np.abs(radius - 1).max() < 1e-4, trace.name
