"""The report's pages: the scene sheets' error maps."""
import numpy as np

from eve3d.evaluate.common import write_error_maps
from eve3d.report import ERROR_MAP_BACKGROUND, ERROR_MAP_PIXELS, _error_map


def test_error_map_is_seen_from_above_with_y_up(tmp_path):
    """A white floor of 2 × 1 under a dark roof over its top-left corner: each pixel shows
    its highest point, so the corner is dark; the longest side spans ERROR_MAP_PIXELS; +y
    is up, as on a plot; a pixel without a point shows the background."""
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform((0, 0), (2, 1), (100_000, 2)), np.zeros(100_000)]
    roof = np.c_[rng.uniform((0, 0.75), (0.5, 1), (60_000, 2)), np.ones(60_000)]  # 34 a pixel
    points, top = np.r_[floor, roof], 1.0
    distances = np.r_[np.zeros(len(floor)), np.full(len(roof), top)]
    write_error_maps(tmp_path, points, distances, points, distances, top)
    image = _error_map(tmp_path / "precision.ply")
    height, width, _ = image.shape
    assert width == ERROR_MAP_PIXELS and abs(height - ERROR_MAP_PIXELS // 2) <= 1
    shown = (image != ERROR_MAP_BACKGROUND).any(-1)
    assert 0.7 < shown.mean() < 1  # 3.5 floor points a pixel leave a few empty
    corner = image[: height // 4 - 2, : width // 4 - 2][shown[: height // 4 - 2, : width // 4 - 2]]
    rest = image[height // 4 + 2:][shown[height // 4 + 2:]]
    assert len(corner) > 100 and np.all(corner == corner[0]) and corner[0].max() < 0.1  # the roof hides the floor
    assert len(rest) > 1000 and np.all(rest == 1)  # below it, the white floor


def _cells(page: str, table_id: str) -> list[dict]:
    """The rows of table ``table_id`` of ``page``: header → (text, bold)."""
    from html.parser import HTMLParser

    class Parser(HTMLParser):
        def __init__(self):
            super().__init__()
            self.inside, self.header, self.rows, self.cell, self.bold = False, [], [], None, False

        def handle_starttag(self, tag, attrs):
            if tag == "table":
                self.inside = dict(attrs).get("id") == table_id
            elif self.inside and tag == "tr":
                self.rows.append([])
            elif self.inside and tag in ("td", "th"):
                self.cell, self.bold = "", False
            elif self.inside and tag == "b":
                self.bold = True

        def handle_endtag(self, tag):
            if self.inside and tag in ("td", "th"):
                self.rows[-1].append((self.cell, self.bold))
                self.cell = None
            elif tag == "table":
                self.inside = False

        def handle_data(self, data):
            if self.cell is not None:
                self.cell += data

    parser = Parser()
    parser.feed(page)
    header = [text for text, _ in parser.rows[0]]
    return [dict(zip(header, row)) for row in parser.rows[1:]]


def test_summary_page_shows_units_and_marks_the_best_of_each_scene():
    """DTU distances in mm as they are, T&T's metres in mm; the best of a scene's methods is
    bold in each ranked column (the oracle, a ceiling, is not ranked; a tie marks both), and
    the means mark the best among methods scored on every scene."""
    from eve3d.report import summary_page

    dtu = [{"scene": s, "method": m, "protocol": "dtu", "unit": "mm", "chamfer": str(c), "accuracy": str(a)}
           for s, m, c, a in (("scan24", "pgsr", 0.612, 0.5), ("scan24", "eve3d", 0.5449, 0.5),
                              ("scan24", "oracle", 0.1, 0.1), ("scan37", "pgsr", 0.8, 0.7),
                              ("scan37", "eve3d", 0.9, 0.6))]
    tnt = [{"scene": "Barn", "method": m, "protocol": "tnt", "unit": "m", "tau": "0.01", "fscore": str(f)}
           for m, f in (("pgsr", 0.51234), ("eve3d", 0.58))]
    failed = [{"scene": "scan37", "method": "stereo-tsdf", "failed": "stereo: out of memory", "log": "x.log"}]
    page = summary_page(dtu + tnt + failed, [{"source": "published", "method": "pgsr", "chamfer": 0.52}], "t")

    rows = _cells(page, "summary-dtu")
    assert "Chamfer (mm)" in rows[0] and "accuracy (mm)" in rows[0]
    chamfer = {(r["scene"][0], r["method"][0]): r["Chamfer (mm)"] for r in rows}
    assert chamfer[("scan24", "eve3d")] == ("0.545", True) and chamfer[("scan24", "pgsr")] == ("0.612", False)
    assert chamfer[("scan24", "oracle")] == ("0.1", False)  # lower, but not ranked
    assert chamfer[("scan37", "pgsr")] == ("0.8", True)
    accuracy = {(r["scene"][0], r["method"][0]): r["accuracy (mm)"][1] for r in rows}
    assert accuracy[("scan24", "eve3d")] and accuracy[("scan24", "pgsr")]  # a tie
    means = {(r["source"][0], r["method"][0]): r for r in _cells(page, "means-dtu")}
    mine = "this run (mean)"
    assert means[(mine, "eve3d")]["Chamfer (mm)"] == ("0.722", False)
    assert means[(mine, "pgsr")]["Chamfer (mm)"] == ("0.706", True) and means[(mine, "pgsr")]["scenes"][0] == "2"
    assert means[("published", "pgsr")]["Chamfer (mm)"] == ("0.52", False)

    barn = {r["method"][0]: r for r in _cells(page, "summary-tnt")}
    assert barn["pgsr"]["τ (mm)"] == ("10", False) and barn["pgsr"]["F-score"] == ("0.512", False)
    assert barn["eve3d"]["F-score"] == ("0.580", True)
    assert "means-tnt" in page and "Chamfer" not in str(_cells(page, "means-tnt")[0])  # T&T's table has no Chamfer
    assert _cells(page, "summary-failed")[0]["failed"][0] == "stereo: out of memory"


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
