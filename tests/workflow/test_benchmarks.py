"""Benchmarks as users download them: miniature DTU, T&T and Mip-NeRF 360 folders in the
released layouts (generated scenes with their ground-truth files), each benchmark config
resolved on them and run end to end, and the checks that stop misplaced files first."""
import csv
import json
import shutil

import numpy as np
import pytest
import yaml

from eve3d.config import REPO, resolve_config
from eve3d.core.errors import Eve3dError
from eve3d.core.io import load_scene
from eve3d.core.layout import EVALUATION, RECORD, TRAINING, Layout
from eve3d.synth import generate
from eve3d.core.datasets import BENCHMARKS
from eve3d.tools.standin import standin, write_log, write_standin
from tests.helpers import TINY_START, WORKFLOW_CORES, folder_report, open_report, run_cli, snakemake

BENCHMARK_SCENES = {
    "dtu": ["scan24", "scan37", "scan40", "scan55", "scan63", "scan65", "scan69", "scan83", "scan97", "scan105",
            "scan106", "scan110", "scan114", "scan118", "scan122"],
    "tnt": ["Barn", "Caterpillar", "Courthouse", "Ignatius", "Meetingroom", "Truck"],
    "mipnerf360": ["bicycle", "flowers", "garden", "stump", "treehill", "room", "counter", "kitchen", "bonsai"],
}
MINIATURE = {name: standin(name)[1] for name in BENCHMARKS}
"""The scene of each benchmark that the miniature download holds."""
SHORT = {"refine_start": 5, "refine_every": 5, "refine_stop": 25, "reset_every": 0}
TINY = {"preset": "cpu", "mesh": {"coarsen": 8},
        "pretrain": {"iterations": 60, "reinit_at": [], "simplify_at": [40], "densify": SHORT},
        "joint": {"iterations": 30, "dn_from": 15, "mv_from": 15, "prior_from": 5, "joint_from": 15,
                  "init_prior_points": 3000, "densify": SHORT}}
"""A tiny schedule over a benchmark config (the cpu preset, a few dozen iterations)."""


@pytest.fixture(scope="module")
def object_views(tmp_path_factory):
    """The object scene, 12 views of 128×96: what the miniature downloads are made of."""
    return load_scene(generate("object", tmp_path_factory.mktemp("gen") / "object", views=12, width=128, height=96,
                               surface_samples=TINY_START))


@pytest.fixture(scope="module")
def downloads(object_views, tmp_path_factory):
    """benchmark → the root of its miniature download."""
    roots = {}
    for name in MINIATURE:
        roots[name] = tmp_path_factory.mktemp(name)
        write_standin(name, object_views, roots[name])
    return roots


def benchmark_config(name, root, results, **overrides):
    """config/benchmarks/{name}.yaml with only the miniature's scene, ``root`` and ``overrides``."""
    config = yaml.safe_load((REPO / "config" / "benchmarks" / f"{name}.yaml").read_text())
    config["scenes"] = {MINIATURE[name]: config["scenes"][MINIATURE[name]]}
    config.update(root=str(root), results=str(results), **overrides)
    return config


def test_benchmark_configs_list_the_benchmarks_scenes():
    for name, scenes in BENCHMARK_SCENES.items():
        config = yaml.safe_load((REPO / "config" / "benchmarks" / f"{name}.yaml").read_text())
        assert config["benchmark"] == name and config["root"] is None
        assert sorted(config["scenes"]) == sorted(scenes)
    with pytest.raises(Eve3dError, match=r"dtu.yaml: root: set the folder .* --config root="):
        resolve_config(yaml.safe_load((REPO / "config/benchmarks/dtu.yaml").read_text()), "dtu.yaml")


def test_a_stand_in_download_and_only_some_scenes_of_a_config(tmp_path):
    """`eve3d bench standin` writes one scan as the download lays it out; `only` picks the
    scans a user has, and without it the first missing one is named."""
    r = run_cli("bench", "standin", "dtu", tmp_path / "DTU", "--views", "6", "--width", "96", "--height", "72")
    assert r.returncode == 0 and "only=[scan24]" in r.stdout, r.stderr
    config = yaml.safe_load((REPO / "config/benchmarks/dtu.yaml").read_text())
    config.update(root=str(tmp_path / "DTU"))
    assert list(resolve_config({**config, "only": ["scan24"]})["scenes"]) == ["scan24"]
    with pytest.raises(Eve3dError, match=rf"scenes.scan37 \(dtu benchmark\): {tmp_path}/DTU/scan37: not found"):
        resolve_config(config)
    with pytest.raises(Eve3dError, match=r"only: unknown scene\(s\) scan1 \(scenes: scan24, scan37"):
        resolve_config({**config, "only": ["scan1"]})


def test_benchmark_configs_resolve_on_the_released_layouts(downloads, tmp_path):
    from eve3d.config import scene_protocol, scene_sections

    dtu = resolve_config(benchmark_config("dtu", downloads["dtu"], tmp_path))
    scan = dtu["scenes"]["scan24"]
    assert scan["path"] == str(downloads["dtu"] / "scan24")
    assert scan["dtu"] == {"stl": str(downloads["dtu"] / "Points/stl/stl024_total.ply"),
                           "obs_mask": str(downloads["dtu"] / "ObsMask/ObsMask24_10.mat"),
                           "plane": str(downloads["dtu"] / "ObsMask/Plane24.mat")}
    assert scene_protocol("scan24", scan).name == "dtu"
    tnt = resolve_config(benchmark_config("tnt", downloads["tnt"], tmp_path))
    assert scene_protocol("Barn", tnt["scenes"]["Barn"]).name == "tnt"
    assert tnt["joint"]["exposure"] is True and tnt["evaluate"]["tnt_points"] == "vertices"
    mip = resolve_config(benchmark_config("mipnerf360", downloads["mipnerf360"], tmp_path))
    assert scene_protocol("room", mip["scenes"]["room"]).name == "nvs"
    assert scene_sections(mip, "room")["train"]["resolution"] == 0.5   # indoor: images_2


def test_the_2dgs_dtu_layout_reads_cropped_photos_and_full_size_masks(downloads, object_views):
    """The photos are described by the COLMAP model (cropped), the masks by cameras.npz."""
    scene = load_scene(downloads["dtu"] / "scan24")
    assert scene.extras["format"] == "dtu" and (scene.cameras[0].width, scene.cameras[0].height) == (120, 88)
    masks = scene.extras["mask_cameras"]
    assert (masks[0].width, masks[0].height) == (128, 96) and masks[0].mask_path.is_file()
    for cam, mask_cam, truth in zip(scene.cameras, masks, object_views.cameras):
        assert np.allclose(cam.center, truth.center, atol=1e-6) and np.allclose(mask_cam.K, truth.K, atol=1e-6)
        assert np.allclose(cam.K[:2, 2], truth.K[:2, 2] - 4)


def test_the_released_mipnerf360_pyramid_is_read(downloads, tmp_path):
    """A view trained at 1/2 size is read from the release's images_2 (same file name), not
    decoded at full size and resized."""
    import cv2

    from eve3d.core.photos import read_view

    root = tmp_path / "360"
    shutil.copytree(downloads["mipnerf360"], root)
    cam = load_scene(root / "room").cameras[0]
    assert cam.name == "DSC00000.JPG" and (cam.width, cam.height) == (128, 96)
    cv2.imwrite(str(root / "room/images_2/DSC00000.JPG"), np.full((48, 64, 3), (30, 60, 90), np.uint8))
    assert np.abs(read_view(cam.scaled(0.5)).astype(int) - (90, 60, 30)).max() <= 2   # RGB of the marked level


def test_a_misplaced_obsmask_is_named(downloads, tmp_path):
    root = tmp_path / "DTU"
    shutil.copytree(downloads["dtu"], root)
    (root / "ObsMask" / "ObsMask24_10.mat").rename(root / "ObsMask24_10.mat")
    with pytest.raises(Eve3dError, match=rf"scenes.scan24 \(dtu benchmark\): {root}/ObsMask/ObsMask24_10.mat: not "
                                         rf"found .*; found {root}/ObsMask24_10.mat: move it there"):
        resolve_config(benchmark_config("dtu", root, tmp_path))
    (root / "ObsMask24_10.mat").unlink()
    shutil.rmtree(root / "Points")
    with pytest.raises(Eve3dError, match=rf"{root}/Points/stl/stl024_total.ply: not found \(DTU's official"):
        resolve_config(benchmark_config("dtu", root, tmp_path))


def test_a_stl_in_another_frame_stops_the_check(downloads, tmp_path):
    """The STL of another scan (here: this one moved by 40 mm, 40 % of the object's size)
    does not fall on the object."""
    import open3d as o3d

    root = tmp_path / "DTU"
    shutil.copytree(downloads["dtu"], root)
    scan, files = root / "scan24", {"gt": root / "Points/stl/stl024_total.ply",
                                    "obs-mask": root / "ObsMask/ObsMask24_10.mat", "plane": root / "ObsMask/Plane24.mat"}
    args = ["evaluate", "--check", "--scene", scan, "--protocol", "dtu", "--out", tmp_path / "check.json"]
    for flag, path in files.items():
        args += [f"--{flag}", path]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "check.json").read_text())["stl_points_in_masks"] > 0.95   # measured 1.0
    cloud = o3d.io.read_point_cloud(str(files["gt"])).translate([40.0, 0, 0])
    o3d.io.write_point_cloud(str(files["gt"]), cloud)
    r = run_cli(*args)
    assert r.returncode == 2 and f"{files['gt']}: does not line up with {scan}" in r.stderr, r.stderr
    r = run_cli(*args, "--set", "evaluate.ground_truth_check=warn")   # a user who knows better goes on
    assert r.returncode == 0 and f"warning: {files['gt']}: does not line up" in r.stderr
    assert "does not line up" in json.loads((tmp_path / "check.json").read_text())["warning"]


@pytest.mark.parametrize("mistake", ["swapped", "training log"])
def test_a_wrong_trajectory_stops_before_training(downloads, object_views, tmp_path, mistake):
    """Two cameras of the log swapped; or the log overwritten by a 'training' one, the same
    cameras in the scene's own frame (where the official transform does not apply)."""
    from eve3d.core.io.tnt import read_log_trajectory

    root = tmp_path / "TNT"
    shutil.copytree(downloads["tnt"], root)
    log = root / "Barn" / "Barn_COLMAP_SfM.log"
    poses = read_log_trajectory(log)
    if mistake == "swapped":
        poses[2], poses[9] = poses[9], poses[2]
        expected = f"{log}: its cameras are not the scene's images in their order"
    else:
        for pose, cam in zip(poses, object_views.cameras):
            pose[:3, :3], pose[:3, 3] = cam.R.T, cam.center   # camera-to-world in the scene's own frame
        expected = f"{root}/Barn/Barn_trans.txt: the scene's SfM points, aligned by {log} and this transform, do not lie"
    write_log(log, poses)
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump(benchmark_config("tnt", root, tmp_path / "results", **TINY)))
    r = snakemake(WORKFLOW_CORES, "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0 and expected in r.stdout + r.stderr, (r.stdout + r.stderr)[-3000:]
    assert not (tmp_path / "results" / "Barn" / "pretrain").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name", list(MINIATURE))
def test_each_benchmark_runs_end_to_end(downloads, tmp_path, name):
    """The benchmark's config, only the tiny schedule and the miniature's scene changed:
    every method but pgsr to its score in summary.csv. (eve3d is pgsr with the priors and an
    opacity loss; pgsr's runs end to end are tests/workflow/test_workflow.py's.)"""
    config = benchmark_config(name, downloads[name], tmp_path / "results", **TINY)
    config["methods"] = [m for m in config["methods"] if m != "pgsr"]
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump(config))
    r = snakemake(WORKFLOW_CORES, "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    layout, scene = Layout(tmp_path / "results"), MINIATURE[name]
    rows = list(csv.DictReader(open(layout.summary())))
    trained = [m for m in config["methods"] if m != "stereo-tsdf" or name != "mipnerf360"]
    assert sorted((row["scene"], row["method"]) for row in rows) == sorted((scene, m) for m in trained)
    for row in rows:
        metrics = json.loads(layout.metrics(scene, row["method"]).read_text())
        assert metrics["versions"]["eve3d"] and metrics["evaluator"].startswith("eve3d.evaluate.")
        if name == "dtu":
            assert row["protocol"] == "dtu" and 0 < float(row["chamfer"]) < 20
        elif name == "tnt":
            assert row["protocol"] == "tnt" and row["points"] == "vertices" and 0 <= float(row["fscore"]) <= 1
            assert metrics["tau"] == 0.01   # the toolbox's τ of Barn
        else:
            assert row["protocol"] == "nvs" and float(row["psnr"]) > 10 and row["depth_signed_error"] == ""
            # every 8th view held out (views 0 and 8 of 12); the protocol renders the saved
            # model, and agrees with the trainer's own held-out score
            training = json.loads(layout.train_metrics(scene, row["method"]).read_text())
            assert metrics[RECORD] == EVALUATION and training[RECORD] == TRAINING
            assert training["settings"]["holdout"] == 8 and metrics["views"] == 2
            assert metrics["psnr"] == pytest.approx(training["held_out"]["psnr"], abs=1e-3)
            assert float(row["psnr"]) == pytest.approx(metrics["psnr"])
        assert layout.mesh(scene, row["method"]).is_file()
    if name in ("dtu", "tnt"):
        check = json.loads(layout.ground_truth_check(scene).read_text())
        assert check["protocol"] == name
    # the report: Snakemake gathers the pages into a folder report, which a browser shows whole
    archive = tmp_path / "report.zip"
    r = snakemake("-c1", "--configfile", str(cfg), "--replace-workflow-config", "--report", str(archive))
    assert r.returncode == 0, r.stderr[-3000:]
    report = folder_report(archive)
    seen = open_report(report, tmp_path / "report.png")
    assert sorted((row["scene"], row["method"]) for row in seen["rows"]) == sorted((scene, m) for m in trained)
    sheets = [p for p in seen["images"] if "/report/scenes/" in p]
    assert len(sheets) == len(trained) and any(p.endswith("charts/runtimes.png") for p in seen["images"])
    assert seen["broken"] == [] and seen["problems"] == []
    assert list(seen["views3d"]) == [str(layout.report_pages() / "scenes3d" / f"{scene}.html")]
    assert seen["views3d"][str(layout.report_pages() / "scenes3d" / f"{scene}.html")] > 0.02  # not blank
    page3d = (layout.report_pages() / "scenes3d" / f"{scene}.html").read_text()
    assert '"name":"cameras"' in page3d and ('"name":"GT"' in page3d) == (name != "mipnerf360")
    if name == "tnt":  # the single file, and the browser check sees an image that does not decode
        chart = layout.report_pages() / "charts" / "fscore.png"
        chart.write_bytes(chart.read_bytes()[:200])
        r = snakemake("-c1", "--configfile", str(cfg), "--replace-workflow-config", "--report", str(tmp_path / "b.html"))
        assert r.returncode == 0, r.stderr[-3000:]
        single = open_report(tmp_path / "b.html", views3d=False)
        assert single["broken"] == [str(chart)] and single["problems"] == []
