"""Bad input: a clear message naming the file and the problem, a non-zero exit, and no
artefact that looks complete; an earlier run's artefact at the output path is left as it was.
docs/faults.md lists each fault with its message and the test here (or elsewhere) that backs it."""
import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from eve3d.config import resolve_config
from eve3d.core.errors import Eve3dError
from eve3d.core.io.colmap import import_pycolmap
from tests.helpers import TINY_START, run_cli

EARLIER = b"an earlier run's artefact"


@pytest.fixture
def dataset_copy(object_dataset, tmp_path):
    copy = tmp_path / "data"
    shutil.copytree(object_dataset, copy)
    return copy


def earlier_artefact(path: Path):
    """An earlier run's artefact at ``path`` (a file when ``path`` has a suffix, else a folder
    holding one); returns a check that it, and everything beside it, are as they were: not
    overwritten, and no temporary file or folder left."""
    file = path if path.suffix else path / "000.npz"
    file.parent.mkdir(parents=True, exist_ok=True)
    file.write_bytes(EARLIER)
    before = sorted(path.parent.rglob("*"))

    def intact():
        assert file.read_bytes() == EARLIER
        assert sorted(path.parent.rglob("*")) == before

    return intact


def assert_fails(result, *fragments):
    assert result.returncode != 0
    assert "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr


def fails(capsys, *args, expect: tuple[str, ...]) -> str:
    """``eve3d ARGS`` run in this process (cheaper than a fresh one, the same ``main``): exit 2,
    the last line of stderr ``eve3d COMMAND: error: ...`` holding each of ``expect``, no traceback."""
    from eve3d.cli import main

    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    line = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err, err
    assert line.startswith(f"eve3d {args[0]}: error: "), err
    for fragment in expect:
        assert fragment in line, line
    return line


def test_missing_image_folder(dataset_copy, tmp_path):
    shutil.rmtree(dataset_copy / "images")
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out),
                 str(dataset_copy / "images"), "image folder not found")
    assert_fails(run_cli("sfm", dataset_copy, tmp_path / "results" / "sfm"), "image folder not found")
    intact()


def test_corrupt_image(dataset_copy, tmp_path):
    bad = dataset_copy / "images" / "007.png"
    bad.write_bytes(bad.read_bytes()[:200])  # truncated
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out), str(bad), "corrupt")
    intact()


def test_image_of_the_wrong_size(dataset_copy, tmp_path, capsys):
    from PIL import Image

    bad = dataset_copy / "images" / "007.png"
    Image.open(bad).resize((300, 240)).save(bad)
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    fails(capsys, "stereo-depth", "--scene", dataset_copy, "--out", out,
          expect=(f"{bad}: image is 300×240 but its camera says 320×240",))
    intact()


def test_model_names_a_missing_image(dataset_copy, tmp_path):
    (dataset_copy / "images" / "012.png").unlink()
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out),
                 "images.bin", "'012.png'", "not in")
    intact()


def test_unknown_camera_model(dataset_copy, tmp_path):
    pycolmap = import_pycolmap()
    model = dataset_copy / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    cam = rec.cameras[1]
    rec.cameras[1] = pycolmap.Camera.create_from_model_name(1, "EQUIRECTANGULAR", 100.0, cam.width, cam.height)
    for f in model.iterdir():
        f.unlink()
    rec.write_text(str(model))
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out),
                 "cameras.txt", "EQUIRECTANGULAR", "cannot be undistorted")
    (model / "cameras.txt").write_text("1 FANCY_LENS 320 240 1 2 3\n")
    assert_fails(run_cli("stereo-depth", "--scene", dataset_copy, "--out", out),
                 str(model), "cannot read COLMAP model")
    intact()


def test_malformed_colmap_binary(dataset_copy, tmp_path, capsys):
    """Cut or garbage binary files: pycolmap read past their end without a check (a cut
    points3D.bin asked for gigabytes, a garbage frames.bin looped, a cut cameras.bin gave a
    camera of zeros and a singular-matrix traceback)."""
    model = dataset_copy / "sparse" / "0"
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    garbage = b"# a text file saved as .bin\n" * 40
    for name, broken, expect in [
            ("images.bin", lambda b: b[:len(b) // 2], "of the 32 images it declares runs past the end of the file"),
            ("cameras.bin", lambda b: b[:32], "camera 1 of the 1 camera it declares runs past the end of the file "
                                              "(32 bytes): truncated, or not a COLMAP cameras.bin"),
            ("cameras.bin", lambda b: b[:12] + (99).to_bytes(4, "little") + b[16:],
             "camera 1 of 1: camera model id 99, which COLMAP does not define"),
            ("points3D.bin", lambda b: garbage, "more than its 1120 bytes can hold: truncated, or not a COLMAP"),
            ("frames.bin", lambda b: garbage, "more than its 1120 bytes can hold")]:
        path = model / name
        good = path.read_bytes()
        path.write_bytes(broken(good))
        fails(capsys, "stereo-depth", "--scene", dataset_copy, "--backend", "oracle", "--out", out,
              expect=(f"{path}: ", expect))
        path.write_bytes(good)
    intact()


def test_truncated_images_txt(dataset_copy, tmp_path, capsys):
    """A text model cut after its first image. Without the check pycolmap read it as ONE
    view and training went on without a word (no point track names a later image here)."""
    pycolmap = import_pycolmap()
    model = dataset_copy / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    for f in model.iterdir():
        f.unlink()
    rec.write_text(str(model))
    for name in ("frames.txt", "rigs.txt"):  # a model as COLMAP before 3.12 wrote it
        (model / name).unlink()
    (model / "points3D.txt").write_text("# 3D point list\n")
    images = model / "images.txt"
    lines = images.read_text().splitlines(keepends=True)
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    args = ("stereo-depth", "--scene", dataset_copy, "--backend", "oracle", "--out", out)
    images.write_text("".join(lines[:6]))  # the header's 4 comment lines, the first image's 2
    fails(capsys, *args, expect=(f"{images}: its header declares 32 images, the file holds 1: truncated?",))
    images.write_text("".join(lines[:7]))  # the second image's pose line without its POINTS2D line
    fails(capsys, *args, expect=(f"{images}: line 7: image '001.png' has no POINTS2D line after it",))
    images.write_text("".join(lines[4:6]) + lines[6][:40])  # no header; cut inside a pose line
    fails(capsys, *args, expect=(f"{images}: line 3: an image line has 10 fields",))
    images.write_text(lines[4] + " ".join(lines[5].split()[:4]))  # cut inside the first POINTS2D line
    fails(capsys, *args, expect=(f"{images}: line 2: the POINTS2D line ends inside an (X, Y, POINT3D_ID) triple",))
    intact()


def test_negative_voxel_in_config():
    with pytest.raises(Eve3dError) as e:
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object"}}}, "mesh": {"voxel": -0.01}}, "my.yaml")
    assert "my.yaml" in str(e.value) and "mesh.voxel" in str(e.value) and "-0.01" in str(e.value)


def test_negative_iterations(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "results" / "pretrain"
    intact = earlier_artefact(out / "point_cloud.ply")
    args = ("pretrain", "--scene", tiny_dataset, "--out", out)
    expected = "iterations: expected an integer ≥ 0, got -5"
    fails(capsys, *args, "--set", "pretrain.iterations=-5", expect=(f"pretrain (train + pretrain sections).{expected}",))
    fails(capsys, *args, "--iterations", "-5", expect=("pretrain (train + pretrain sections).iterations (--iterations): "
                                                       "expected an integer ≥ 0, got -5",))
    fails(capsys, *args, "--config", '{"pretrain": {"iterations": -5}}', expect=(expected,))
    # the preset's pretrain.iterations shadows train.iterations: -5 there was never read, and passed
    fails(capsys, *args, "--set", "train.iterations=-5", expect=(f"train.{expected}",))
    intact()


def test_training_resolution_zero_or_too_small(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "results" / "pretrain"
    intact = earlier_artefact(out / "point_cloud.ply")
    args = ("pretrain", "--scene", tiny_dataset, "--out", out)
    fails(capsys, *args, "--set", "pretrain.resolution=0",
          expect=("pretrain (train + pretrain sections).resolution: expected a number > 0, got 0",))
    # > 0 but a 0 px image: it was OpenCV's "(-215:Assertion failed) inv_scale_x > 0 in function 'resize'"
    fails(capsys, *args, "--resolution", "0.001",
          expect=("pretrain.resolution 0.001 (max_side 512): view 000.png (64×48) would be trained at 0×0 px; the "
                  "training size needs at least 8 px a side",))
    intact()


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast")  # planning the grid for 1e30 depths
def test_depth_maps_that_fuse_to_no_surface(tiny_dataset, tmp_path, capsys):
    from eve3d.core.io import load_scene
    from eve3d.core.maps import save_maps

    scene = load_scene(tiny_dataset)
    depth_dir = tmp_path / "depth"
    out = tmp_path / "results" / "mesh.ply"
    intact = earlier_artefact(out)
    args = ("mesh", "--scene", tiny_dataset, "--depth", depth_dir, "--out", out)

    def depth_maps(depth_of):
        for cam in scene.cameras:
            depth = np.full((cam.height, cam.width), depth_of(cam), np.float32)
            save_maps(depth_dir / f"{cam.view_id}.npz", preview=False, depth=depth, confidence=np.ones_like(depth))

    depth_maps(lambda cam: 0.0)
    fails(capsys, *args, expect=(f"{depth_dir}: no valid depth in any view, nothing to fuse",))
    depth_maps(lambda cam: 1e30)  # beyond any depth: open3d's "No block is touched" RuntimeError
    fails(capsys, *args, "--set", "mesh.region=0",
          expect=(f"{depth_dir}: the depth maps fuse to no surface", "no view's depth reaches the grid"))
    centre = scene.points.mean(axis=0)
    depth_maps(lambda cam: float(np.linalg.norm(cam.center - centre)))  # a plane through the centre per view
    fails(capsys, *args, "--set", "mesh.weight_threshold=100",
          expect=(f"{depth_dir}: the depth maps fuse to no surface (an empty mesh at voxel ",
                  "too few of the 8 views fused agree on a depth for mesh.weight_threshold 100", "no mesh written"))
    intact()


def test_malformed_onnx_model(tiny_dataset, tmp_path, capsys):
    junk = tmp_path / "stereo.onnx"
    junk.write_bytes(b"not a model")
    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)
    args = ("stereo-depth", "--scene", tiny_dataset, "--backend", "onnx", "--stereo", tmp_path / "stereo", "--out", out)
    fails(capsys, *args, "--set", f"stereo.onnx.model={junk}", expect=(f"{junk}: not a loadable ONNX model (",))
    fails(capsys, *args, "--set", f"stereo.onnx.model={tmp_path / 'none.onnx'}",
          expect=(f"{tmp_path / 'none.onnx'}: ONNX stereo model not found (stereo.onnx.model)",))
    hitnet = ("stereo-depth", "--scene", tiny_dataset, "--backend", "hitnet", "--stereo", tmp_path / "stereo", "--out", out)
    fails(capsys, *hitnet, expect=("--backend hitnet needs the model file: set stereo.hitnet.model", "stereodemo"))
    fails(capsys, *hitnet, "--set", f"stereo.hitnet.model={junk}",
          expect=(f"{junk}: not a loadable ONNX model (", "expected HITNet: one input 'input' float32 [1, 2, H, W]"))
    intact()


def test_ground_truth_of_the_wrong_kind(tiny_dataset, tmp_path, capsys):
    import open3d as o3d

    from eve3d.core.io import load_scene
    from eve3d.tools.standin import dtu_scale_mat, write_dtu_layout, write_log

    mesh = tiny_dataset / "gt" / "mesh.ply"
    out = tmp_path / "results" / "metrics.json"
    intact = earlier_artefact(out)
    cloud, text = tmp_path / "gt_points.ply", tmp_path / "gt.ply"
    o3d.io.write_point_cloud(str(cloud), o3d.geometry.PointCloud(o3d.io.read_triangle_mesh(str(mesh)).vertices))
    text.write_text("a mesh, honestly\n")
    args = ("evaluate", "--mesh", mesh, "--out", out)
    points = len(o3d.io.read_point_cloud(str(cloud)).points)
    fails(capsys, *args, "--scene", tiny_dataset, "--gt", cloud,
          expect=(f"{cloud}: a point cloud ({points} points, no triangles), not a triangle mesh",))
    fails(capsys, *args, "--scene", tiny_dataset, "--gt", text,
          expect=(f"{text}: not a triangle mesh that open3d reads (.ply, .obj, .off, .stl, .glb), or an empty one",))
    fails(capsys, "stereo-depth", "--scene", tiny_dataset, "--backend", "oracle", "--gt-mesh", cloud,
          "--out", tmp_path / "results" / "oracle", expect=(f"{cloud}: a point cloud",))
    # DTU: an ObsMask that is not a MATLAB file
    dtu = tmp_path / "scan1"
    write_dtu_layout(load_scene(tiny_dataset), dtu, dtu_scale_mat())
    fails(capsys, *args, "--scene", dtu, "--protocol", "dtu", "--gt", cloud, "--obs-mask", text, "--plane", text,
          expect=(f"{text}: not a DTU ObsMask / BB / Res file (",))
    # T&T: a trajectory .log that is binary garbage, or whose matrices have rows of 3
    tnt = tmp_path / "Barn"
    shutil.copytree(tiny_dataset, tnt, ignore=shutil.ignore_patterns("gt", "eve3d_scene.json"))
    shutil.copy(cloud, tnt / "Barn.ply")
    (tnt / "Barn.json").write_text("{}")
    np.savetxt(tnt / "Barn_trans.txt", np.eye(4))
    log = tnt / "Barn_COLMAP_SfM.log"
    log.write_bytes(bytes(range(256)) * 4)
    fails(capsys, *args, "--scene", tnt, "--tau", "0.01", expect=(f"{log}: not a text file",))
    write_log(log, [np.eye(4)[:, :3]] * 8)
    fails(capsys, *args, "--scene", tnt, "--tau", "0.01",
          expect=(f"{log}: line 2: expected a row of 4 numbers (camera 0's 4×4 matrix), got 3 values",))
    intact()


def test_disk_full_while_writing(tiny_dataset, tmp_path, capsys, monkeypatch):
    """The disk fills up half-way through writing a depth map (a mock of numpy's writer):
    the message names the artefact and says the disk is full; the earlier one is intact."""
    from eve3d.core.fileio import DiskFull, atomic_path

    out = tmp_path / "results" / "priors"
    intact = earlier_artefact(out)

    def disk_full(file, **arrays):
        file.write(b"half a depth map")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez", disk_full)
    fails(capsys, "stereo-depth", "--scene", tiny_dataset, "--backend", "oracle", "--out", out, "--no-preview",
          expect=(f"{out}: cannot write it, the disk is full (No space left on device); the earlier one is kept as it "
                  "was",))
    intact()
    metrics = tmp_path / "results" / "metrics.json"  # one file through atomic_path: the same, for the file
    intact = earlier_artefact(metrics)
    with pytest.raises(DiskFull, match=f"^{metrics}: cannot write it, the disk is full"):
        with atomic_path(metrics) as tmp:
            tmp.write_text('{"half": ')
            raise OSError(errno.EDQUOT, os.strerror(errno.EDQUOT))
    intact()


@pytest.mark.slow
def test_sfm_lists_images_it_could_not_register(tmp_path):
    """Six views of the object plus two frames of unrelated noise: SfM must refuse and name them."""
    from PIL import Image

    from eve3d.synth import generate

    # the sparse points are hidden under gt/ and unused: exact samples spare SIFT on the known poses
    data = generate("object", tmp_path / "data", views=8, width=640, height=480, arc=60, images_only=True,
                    surface_samples=TINY_START)
    rng = np.random.default_rng(0)
    for name in ("003.png", "006.png"):
        Image.fromarray(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)).save(data / "images" / name)
    out = tmp_path / "results" / "sfm"
    intact = earlier_artefact(out)
    result = run_cli("sfm", data, out, "--min-registered-fraction", "1.0")
    assert_fails(result, "left out", "003.png", "006.png")
    intact()
