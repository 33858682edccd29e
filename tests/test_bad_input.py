"""Bad input: a clear message naming the file and the problem, a non-zero exit, and no
artefact that looks complete."""
import shutil

import pytest

from eve3d.config import resolve_config
from eve3d.io.colmap import import_pycolmap
from eve3d.scene import Eve3dError
from tests.helpers import run_cli


@pytest.fixture
def dataset_copy(object_dataset, tmp_path):
    copy = tmp_path / "data"
    shutil.copytree(object_dataset, copy)
    return copy


def assert_fails(result, *fragments):
    assert result.returncode != 0
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr


def test_missing_image_folder(dataset_copy, tmp_path):
    shutil.rmtree(dataset_copy / "images")
    out = tmp_path / "priors"
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out),
                 str(dataset_copy / "images"), "image folder not found")
    assert not out.exists()
    assert_fails(run_cli("sfm", dataset_copy, tmp_path / "sfm"), "image folder not found")
    assert not (tmp_path / "sfm").exists()


def test_corrupt_image(dataset_copy, tmp_path):
    bad = dataset_copy / "images" / "007.png"
    bad.write_bytes(bad.read_bytes()[:200])  # truncated
    out = tmp_path / "priors"
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out), str(bad), "corrupt")
    assert not out.exists()


def test_model_names_a_missing_image(dataset_copy, tmp_path):
    (dataset_copy / "images" / "012.png").unlink()
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", tmp_path / "p"),
                 "images.bin", "'012.png'", "not in")


def test_unknown_camera_model(dataset_copy, tmp_path):
    pycolmap = import_pycolmap()
    model = dataset_copy / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    cam = rec.cameras[1]
    rec.cameras[1] = pycolmap.Camera.create_from_model_name(1, "EQUIRECTANGULAR", 100.0, cam.width, cam.height)
    for f in model.iterdir():
        f.unlink()
    rec.write_text(str(model))
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", tmp_path / "p"),
                 "cameras.txt", "EQUIRECTANGULAR", "cannot be undistorted")
    (model / "cameras.txt").write_text("1 FANCY_LENS 320 240 1 2 3\n")
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", tmp_path / "p"),
                 str(model), "cannot read COLMAP model")


def test_negative_voxel_in_config():
    with pytest.raises(Eve3dError) as e:
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object"}}}, "mesh": {"voxel": -0.01}}, "my.yaml")
    assert "my.yaml" in str(e.value) and "mesh.voxel" in str(e.value) and "-0.01" in str(e.value)


@pytest.mark.slow
def test_sfm_lists_images_it_could_not_register(tmp_path):
    """Six views of the object plus two frames of unrelated noise: SfM must refuse and name them."""
    import numpy as np
    from PIL import Image

    from eve3d.synth import generate

    data = generate("object", tmp_path / "data", views=8, width=640, height=480, arc=60, images_only=True)
    rng = np.random.default_rng(0)
    for name in ("003.png", "006.png"):
        Image.fromarray(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)).save(data / "images" / name)
    result = run_cli("sfm", data, tmp_path / "sfm", "--min-registered-fraction", "1.0")
    assert_fails(result, "left out", "003.png", "006.png")
    assert not (tmp_path / "sfm").exists()
