"""eve3d.synth: the generated scenes (photos, cameras, sparse points and GT mesh agree; the kinds)."""
import numpy as np

from eve3d.core.io import load_scene
from eve3d.core.io.colmap import read_colmap
from eve3d.core.raycast import MeshRaycaster
from eve3d.priors.matching import local_std


def test_synthetic_scene_is_consistent(object_scene):
    """The sparse points, SIFT matched between the photos and triangulated with the known
    poses, project where the GT depth says: photos, cameras and GT mesh agree. Measured:
    180 points in view 3, median relative depth difference 0.30 %, 95 % within 5 %."""
    caster = MeshRaycaster.from_file(object_scene.gt_mesh)
    cam = object_scene.cameras[3]
    seen = [i for i, v in enumerate(object_scene.point_views) if 3 in v]
    uv, z = cam.project(object_scene.points[seen])
    rel = np.abs(caster.cast_uv(cam, uv).depth - z) / z
    assert len(seen) > 100 and np.median(rel) < 0.01 and np.mean(rel < 0.05) > 0.85
    assert object_scene.kind == "object" and len(object_scene.cameras) == 32


def test_dark_room_is_the_inside_room_darker_and_flatter(tmp_path):
    """The hard case for stereo: the same capture as ``inside-room`` (same cameras), with
    walls and ceiling dark and of low contrast."""
    from eve3d.core.fileio import read_image
    from eve3d.synth import generate

    images = {}
    for kind in ("inside-room", "dark-room"):
        scene = generate(kind, tmp_path / kind, views=3, width=80, height=60)
        images[kind] = np.stack([read_image(p) for p in sorted((scene / "images").glob("*.png"))])
    bright, dark = images["inside-room"].astype(float), images["dark-room"].astype(float)
    walls = np.abs(bright - dark).max(-1) > 2  # the rest (floor, furniture) is unchanged
    assert 0.2 < walls.mean() < 0.9 and np.abs(bright - dark)[~walls].max() <= 2
    assert dark[walls].mean() < 0.4 * bright[walls].mean()

    def spread(im):
        return np.median(np.stack([local_std(v, 5) for v in im])[walls])

    assert spread(dark) < 0.4 * spread(bright)


def test_generated_scenes_start_from_points_sfm_triangulates(object_dataset):
    """A generated scene's sparse points are what a user's SfM gives with known poses
    (features matched and triangulated by pycolmap), not samples of the GT surface: most lie
    on the surface, some do not, every point is seen by two views or more and projects
    near its features, and the poses are the generator's, untouched."""
    import open3d as o3d

    scene = load_scene(object_dataset)
    gt = o3d.t.geometry.RaycastingScene()
    gt.add_triangles(o3d.t.io.read_triangle_mesh(str(object_dataset / "gt" / "mesh.ply")))
    distance = gt.compute_distance(o3d.core.Tensor(scene.points.astype(np.float32))).numpy()
    print(f"{len(scene.points)} points; distance to the GT surface: median {np.median(distance):.4f}, "
          f"within 1 cm {np.mean(distance < 0.01):.2f}, beyond 10 cm {np.mean(distance > 0.1):.2f}")
    assert len(scene.points) > 1000
    assert np.median(distance) < 0.01 and 0.5 < np.mean(distance < 0.01) < 0.95  # outliers and all
    assert all(len(v) >= 2 for v in scene.point_views)
    colmap = read_colmap(object_dataset / "sparse" / "0", object_dataset / "images")
    assert [c.center.round(9).tolist() for c in colmap.cameras] == [c.center.round(9).tolist() for c in scene.cameras]


def test_a_background_shows_where_no_surface_is_and_stays_empty(tmp_path):
    """The sky and the backdrop change only the pixels whose rays meet no surface: not black
    there (the sky plain, the backdrop textured), the same surface elsewhere, and the same
    ground truth, cameras and exact depth (those pixels stay empty)."""
    import cv2

    from eve3d.core.fileio import read_image
    from eve3d.synth import generate

    images, depth = {}, None
    for background in ("black", "sky", "backdrop"):
        out = generate("object", tmp_path / background, views=2, width=96, height=72, surface_samples=200,
                       background=background)
        scene = load_scene(out)
        images[background] = np.stack([read_image(c.image_path).astype(float) for c in scene.cameras])
        caster = MeshRaycaster.from_file(scene.gt_mesh)
        exact = np.stack([caster.cast(c).depth for c in scene.cameras])
        assert depth is None or np.array_equal(exact, depth)
        depth = exact
    empty = depth == 0
    # a pixel at a silhouette mixes surface and background in its 2×2 samples
    inside = np.stack([cv2.erode((~e).astype(np.uint8), np.ones((3, 3), np.uint8)) for e in empty]).astype(bool)
    outside = np.stack([cv2.erode(e.astype(np.uint8), np.ones((3, 3), np.uint8)) for e in empty]).astype(bool)
    assert 0.1 < outside.mean() and inside.mean() > 0.5
    assert images["black"][outside].max() == 0
    for background in ("sky", "backdrop"):
        assert np.array_equal(images[background][inside], images["black"][inside]), background
        assert images[background][outside].min() > 60, background  # lit, nowhere near black
    sky = np.stack([local_std(v, 5) for v in images["sky"]])[outside]
    backdrop = np.stack([local_std(v, 5) for v in images["backdrop"]])[outside]
    print(f"grey std over 5×5 on the background: sky {np.median(sky):.2f}, backdrop {np.median(backdrop):.2f}")
    assert np.median(sky) < 1.0 < 3.0 < np.median(backdrop)  # plain against textured


def test_a_generated_capture_is_read_as_a_users_colmap_folder(tmp_path):
    """``eve3d synth --capture``: images and a COLMAP text model, the GT mesh apart in gt/, and
    nothing that says it was generated: read as any user's COLMAP folder (kind ``scene``, no
    GT mesh until a config names it), with the generated scene's cameras."""
    from tests.helpers import run_cli

    r = run_cli("synth", "object", tmp_path / "capture", "--capture", "--config",
                '{"preset": null, "synthetic": {"views": 3, "width": 64, "height": 48, "surface_samples": 200, '
                '"background": "sky"}}')
    assert r.returncode == 0, r.stderr[-2000:]
    out = tmp_path / "capture"
    assert sorted(p.name for p in out.iterdir()) == ["gt", "images", "sparse"]
    assert {"cameras.txt", "images.txt", "points3D.txt"} <= {p.name for p in (out / "sparse" / "0").iterdir()}
    scene = load_scene(out)
    assert scene.extras["format"] == "colmap" and scene.kind == "scene" and scene.gt_mesh is None
    assert (out / "gt" / "mesh.ply").is_file() and len(scene.cameras) == 3 and len(scene.points) > 50
