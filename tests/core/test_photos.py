"""Photos as users bring them: EXIF-rotated phone photos, files that are not photos, photos
of two sizes, the image pyramid, and a folder of photos with nothing else through the
workflow."""
import json
import math
import shutil

import numpy as np
import pytest
from PIL import Image

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import read_image
from eve3d.core.io import load_scene
from eve3d.core.layout import HELD_OUT_DIR, MESH_VIEWS_DIR, PRETRAIN, Layout
from eve3d.core.photos import read_upright, read_view, scan_photos
from eve3d.core.settings import RenderSettings
from eve3d.synth import generate
from tests.helpers import run_cli, snakemake, write_config

ORIENTATION = 274
"""The EXIF tag of the orientation; 6 ("upper-right", a phone held upright) asks a viewer to
rotate the stored pixels 90° clockwise."""


def save_sideways(upright: np.ndarray, path, quality: int = 95) -> None:
    """Store ``upright`` as a phone does: pixels turned 90° counter-clockwise, tag 6."""
    exif = Image.Exif()
    exif[ORIENTATION] = 6
    Image.fromarray(np.ascontiguousarray(np.rot90(upright))).save(path, exif=exif, quality=quality)


def test_one_orientation_rule(tmp_path):
    """Stages read the pixels as stored (as COLMAP does); the import applies the tag."""
    import cv2

    rng = np.random.default_rng(0)
    upright = cv2.resize(rng.integers(0, 255, (12, 16, 3), dtype=np.uint8), (64, 48), interpolation=cv2.INTER_CUBIC)
    save_sideways(upright, tmp_path / "a.png")  # lossless, so pixels compare exactly
    assert read_image(tmp_path / "a.png").shape == (64, 48, 3)
    assert np.array_equal(read_upright(tmp_path / "a.png"), upright)
    save_sideways(upright, tmp_path / "b.jpg")  # as a phone writes it
    assert read_image(tmp_path / "b.jpg").shape == (64, 48, 3)
    grey = lambda im: im.astype(float).mean(-1)  # noqa: E731  (JPEG keeps the luma, not the chroma)
    assert np.abs(grey(read_upright(tmp_path / "b.jpg")) - grey(upright)).mean() < 5  # measured 3.2
    assert np.abs(grey(read_upright(tmp_path / "b.jpg")) - grey(upright[::-1, ::-1])).mean() > 20


def test_read_view_reads_the_smallest_pyramid_level_that_is_large_enough(tmp_path):
    from eve3d.core.photos import write_pyramid
    from eve3d.core.scene import Camera

    rng = np.random.default_rng(1)
    images = tmp_path / "images"
    images.mkdir()
    Image.fromarray(rng.integers(0, 255, (300, 400, 3), dtype=np.uint8)).save(images / "v.png")
    write_pyramid(images)
    assert Image.open(tmp_path / "images_2/v.png").size == (200, 150)
    assert Image.open(tmp_path / "images_4/v.png").size == (100, 75)
    assert not (tmp_path / "images_8").exists()  # 37 px would be below the 64 px floor
    cam = Camera("v.png", 400, 300, np.array([[300, 0, 200], [0, 300, 150], [0, 0, 1]]), np.eye(3), np.zeros(3),
                 images / "v.png")
    import cv2

    # 110 px wide: from images_2 (images_4 is too small); 90 px: from images_4
    for side, level in ((110, "images_2"), (90, "images_4")):
        small = RenderSettings(max_side=side).sized(cam)
        assert small.width == side and small.height == round(side * 0.75)
        expect = cv2.resize(read_image(tmp_path / level / "v.png"), (small.width, small.height),
                            interpolation=cv2.INTER_AREA)
        assert np.array_equal(read_view(small), expect)
    rotated = Camera("v.png", 300, 400, cam.K, np.eye(3), np.zeros(3), images / "v.png")
    with pytest.raises(Eve3dError, match="image is 400×300, its camera says 300×400"):
        read_view(rotated)


def test_training_size_is_capped_by_the_longest_side():
    from eve3d.core.scene import Camera

    cam = Camera("v.png", 4032, 3024, np.eye(3), np.eye(3), np.zeros(3))
    assert RenderSettings(max_side=512).scale(cam) == pytest.approx(512 / 4032)
    assert RenderSettings(resolution=0.1, max_side=512).scale(cam) == pytest.approx(0.1)
    assert RenderSettings(resolution=0.75, max_side=0).scale(cam) == 0.75


def test_a_folder_with_a_note_an_empty_jpeg_and_a_duplicate_name(tmp_path, capsys):
    rng = np.random.default_rng(2)
    folder = tmp_path / "images"
    folder.mkdir()
    for name in ("a.jpg", "b.JPG"):
        Image.fromarray(rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)).save(folder / name)
    (folder / "notes.txt").write_text("shot at noon")
    (folder / "empty.jpg").write_bytes(b"")
    (folder / ".DS_Store").write_bytes(b"\0")
    assert [p.name for p in scan_photos(folder)] == ["a.jpg", "b.JPG"]
    err = capsys.readouterr().err
    assert f"{folder / 'notes.txt'}: not an image" in err and f"{folder / 'empty.jpg'}: unreadable image (empty file)" in err
    assert ".DS_Store" not in err
    shutil.copy(folder / "a.jpg", folder / "a.png")
    with pytest.raises(Eve3dError, match="a.png: same name as a.jpg"):
        scan_photos(folder)
    for p in folder.iterdir():
        p.unlink()
    (folder / "empty.jpg").write_bytes(b"")
    with pytest.raises(Eve3dError, match="no readable images"):
        scan_photos(folder)


def camera_centres(scene) -> dict[str, np.ndarray]:
    return {c.view_id: c.center for c in scene.cameras}


@pytest.mark.slow
def test_exif_rotated_photos_give_the_poses_and_images_of_upright_ones(object_photos, object_photos_sfm, tmp_path):
    """The same 16 views stored upright and stored sideways with the EXIF tag register with
    the same poses and give the same training images. Stored losslessly (PNG with the tag),
    the import makes the two sets the same pixels, so single-threaded SfM (bit-reproducible)
    must give the same model to rounding; a JPEG set re-encodes differently, and a phone's
    JPEGs are exercised by ``eve3d bench real``."""
    (tmp_path / "sideways" / "images").mkdir(parents=True)
    for png in sorted((object_photos / "images").glob("*.png")):
        save_sideways(read_image(png), tmp_path / "sideways" / "images" / png.name)
    r = run_cli("sfm", tmp_path / "sideways", tmp_path / "sideways-sfm")
    assert r.returncode == 0, r.stderr[-2000:]
    assert Image.open(tmp_path / "sideways/images/000.png").size == (360, 480)  # stored sideways
    up, side = load_scene(object_photos_sfm), load_scene(tmp_path / "sideways-sfm")
    assert [c.view_id for c in side.cameras] == [c.view_id for c in up.cameras] and len(up.cameras) == 16
    for cu, cs in zip(up.cameras, side.cameras):
        assert (cs.width, cs.height) == (cu.width, cu.height) and cs.width > cs.height  # upright
        assert np.allclose(cs.K, cu.K) and np.allclose(cs.R, cu.R, atol=1e-9) and np.allclose(cs.t, cu.t, atol=1e-9)
    # the training images (each at the training size, from the pyramid) are the same pixels
    settings = RenderSettings(resolution=0.5)
    for cu, cs in zip(up.cameras, side.cameras):
        assert np.array_equal(read_view(settings.sized(cu)), read_view(settings.sized(cs)))


@pytest.mark.slow
def test_sfm_skips_bad_files_and_gives_each_photo_size_a_camera(object_photos, tmp_path):
    """A note, a zero-byte JPEG and photos of two sizes: skipped with a warning naming each
    file, and a camera per size, never a traceback."""
    data = shutil.copytree(object_photos, tmp_path / "data")
    for png in list((data / "images").glob("*.png"))[::3]:  # every third photo from a camera with fewer pixels
        Image.open(png).resize((400, 300), Image.LANCZOS).save(png)
    (data / "images" / "notes.txt").write_text("tripod, f/8")
    (data / "images" / "IMG_0000.JPG").write_bytes(b"")
    r = run_cli("sfm", data, tmp_path / "sfm")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "notes.txt: not an image" in r.stderr and "IMG_0000.JPG: unreadable image (empty file)" in r.stderr
    assert "photos of 2 sizes" in r.stderr and "Traceback" not in r.stderr
    scene = load_scene(tmp_path / "sfm")
    assert len(scene.cameras) == 16
    sizes = {(c.width, c.height) for c in scene.cameras}
    assert len(sizes) == 2 and max(sizes)[0] > 440 and min(sizes)[0] < 410, sizes  # ~480×360 and ~400×300


@pytest.mark.slow
def test_photos_and_their_path_run_to_meshes_and_held_out_scores(object_photos, tmp_path):
    """An images-only scene with no other key: SfM, the default nvs protocol, meshes of every
    trained method with their shaded views, held-out views side by side with the photos."""
    data = shutil.copytree(object_photos, tmp_path / "mine")
    short = {"refine_start": 5, "refine_every": 5, "refine_stop": 25, "reset_every": 0}
    # pgsr left out: eve3d is pgsr with the priors and an opacity loss; pgsr's runs end to end
    # are tests/workflow/test_workflow.py's and tests/test_pipeline.py's
    cfg = write_config(tmp_path, methods=["oracle", "stereo-tsdf", "eve3d"],
                       scenes={"mine": {"path": str(data)}}, train={"max_side": 240},  # trained at 240×180
                       pretrain={"iterations": 80, "reinit_at": [], "simplify_at": [60], "densify": short},
                       joint={"iterations": 40, "dn_from": 20, "mv_from": 20, "prior_from": 5, "joint_from": 20,
                              "init_prior_points": 3000, "densify": short})
    r = snakemake("-c2", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    layout = Layout(tmp_path / "results")
    scene = load_scene(layout.sfm("mine"))
    held = [c.view_id for i, c in enumerate(scene.cameras) if i % 8 == 0]
    m = json.loads(layout.metrics("mine", "eve3d").read_text())
    assert m["protocol"] == "nvs" and m["views"] == 2 and math.isfinite(m["psnr"]) and m["psnr"] > 10
    assert layout.mesh("mine", "eve3d").is_file()
    views = sorted(p.name for p in (layout.method("mine", "eve3d") / MESH_VIEWS_DIR).glob("*.png"))
    assert len(views) == 4 and "overview.png" in views
    shaded = read_image(layout.method("mine", "eve3d") / MESH_VIEWS_DIR / "overview.png")
    assert (shaded < 250).any(axis=-1).mean() > 0.02  # the mesh covers part of the picture
    pairs = sorted(p.stem for p in (layout.method("mine", "eve3d") / HELD_OUT_DIR).glob("*.png"))
    assert pairs == held
    assert not layout.method("mine", "oracle").exists() and not layout.method("mine", "stereo-tsdf").exists()
    assert json.loads(layout.train_metrics("mine", PRETRAIN).read_text())["held_out"]["views"] == 2
    assert (layout.sfm("mine") / "images_2").is_dir()


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
