"""The Snakemake workflow: config validation, dry runs (local and SLURM), a tiny real run."""
import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
import pytest
from PIL import Image

from eve3d.core.fileio import read_image
from eve3d.core.io import load_scene
from eve3d.core.io.colmap import write_colmap
from eve3d.core.layout import EVALUATION, HELD_OUT_DIR, MESH_VIEWS_DIR, PRETRAIN, RECORD, TRAINING, Layout
from eve3d.core.methods import REGISTRY
from eve3d.synth import generate
from eve3d.tools.profile import log_jobs, read_run
from eve3d.tools.standin import dtu_scale_mat, write_dtu_layout
from tests.helpers import REPO, SNAKEFILE, WORKFLOW_CORES, run_cli, snakemake, write_config

# -- what each rule writes ---------------------------------------------------------------------

def assert_synth_input(root, views: int, width: int, height: int) -> None:
    """synth: ``images/`` (and ``masks/``) with one PNG per view at the requested size, a
    COLMAP model in ``sparse/0`` that loads with the views' cameras and sparse points, and
    the GT mesh ``gt/mesh.ply`` with faces."""
    images = sorted((root / "images").glob("*.png"))
    assert len(images) == views and len(list((root / "masks").glob("*.png"))) == views
    assert all(Image.open(f).size == (width, height) for f in images)
    assert (root / "sparse/0").is_dir()
    scene = load_scene(root)
    assert [c.name for c in scene.cameras] == [f.name for f in images]
    assert all((c.width, c.height) == (width, height) for c in scene.cameras)
    assert len(scene.points) > 0 and np.isfinite(scene.points).all()
    assert_mesh(root / "gt/mesh.ply")


def assert_mesh(path):
    """A triangle mesh that trimesh loads, with faces and finite vertices."""
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    assert len(mesh.faces) > 0 and len(mesh.vertices) > 0, path
    assert np.isfinite(mesh.vertices).all(), path
    return mesh


def assert_maps(folder, scene, previews: bool = True, scale: float = 1.0) -> None:
    """Per-view maps (``{view}.npz``) for every camera of ``scene``: depth and confidence of
    the camera's shape (at ``scale``), normals (H, W, 3), all finite; depth ≥ 0, confidence in [0, 1],
    some confident pixels, with a positive depth on every confident pixel; the PNG preview
    of the depth beside each (``previews``)."""
    from eve3d.core.maps import load_maps

    assert sorted(f.stem for f in folder.glob("*.npz")) == sorted(c.view_id for c in scene.cameras), folder
    for cam in (c.scaled(scale) if scale != 1 else c for c in scene.cameras):
        m = load_maps(folder / f"{cam.view_id}.npz")
        assert {"depth", "confidence", "normal"} <= set(m), (folder, cam.view_id, set(m))
        depth, conf, normal = m["depth"], m["confidence"], m["normal"]
        assert depth.shape == conf.shape == (cam.height, cam.width) and normal.shape == (cam.height, cam.width, 3)
        assert np.isfinite(depth).all() and np.isfinite(conf).all() and np.isfinite(normal).all()
        assert depth.min() >= 0 and 0 <= conf.min() and conf.max() <= 1
        assert (conf >= 0.5).any() and (depth[conf >= 0.5] > 0).all(), (folder, cam.view_id)
        assert np.linalg.norm(normal, axis=-1).max() <= 1 + 1e-4
        if previews:
            assert (folder / f"{cam.view_id}.depth.png").is_file(), (folder, cam.view_id)


def assert_gaussians(path, count: int) -> None:
    """A Gaussian model PLY that loads, with ``count`` Gaussians (as its metrics say), finite."""
    from eve3d.gaussians.model import GaussianModel

    model = GaussianModel.load_ply(path)
    assert len(model) == count > 0, path
    assert all(np.isfinite(v.detach().numpy()).all() for v in model.params.values()), path


def assert_mesh_metrics(path, scene: str, method: str) -> dict:
    """evaluate (synthetic protocol): metrics.json names the scene and method, with a finite
    F-score, precision and recall in [0, 1] and finite, non-negative distances."""
    m = json.loads(path.read_text())
    assert m["protocol"] == "synthetic" and m["scene"] == scene and m["method"] == method
    for key in ("fscore", "precision", "recall"):
        assert math.isfinite(m[key]) and 0 <= m[key] <= 1, (path, key, m[key])
    for key in ("accuracy", "completeness", "chamfer", "tau"):
        assert math.isfinite(m[key]) and m[key] >= 0, (path, key, m[key])
    assert m["tau"] > 0 and m["chamfer"] == pytest.approx((m["accuracy"] + m["completeness"]) / 2)
    return m


def test_default_config_dry_run_lists_every_stage(tmp_path):
    r = snakemake("-n", "--config", f"results={tmp_path}")
    assert r.returncode == 0, r.stderr
    for rule in ("synth", "stereo_depth", "stereo_render", "pretrain", "joint", "mesh", "evaluate", "summary"):
        assert rule in r.stdout + r.stderr


def training_job_configs(dry_run: str) -> dict[tuple[str, str], dict]:
    """(stage, scene) → the resolved sections a training job of ``snakemake -n -p`` reads
    (its ``--config``): ``pretrain`` and each joint stage, named ``joint METHOD``."""
    import shlex

    configs = {}
    for line in dry_run.splitlines():
        if " -m eve3d pretrain " in line or " -m eve3d joint " in line:
            args = shlex.split(line[line.index("python -m eve3d"):])
            stage = args[3] if args[3] == "pretrain" else f"joint {args[args.index('--method') + 1]}"
            scene = Path(args[args.index("--out") + 1]).parent.name  # results/{scene}/{stage or method}
            configs[stage, scene] = json.loads(args[args.index("--config") + 1])
    return configs


@pytest.mark.parametrize("replace", [True, False])
def test_a_capture_config_from_the_default_and_the_demo_train_at_the_preset(tmp_path, replace):
    """config/config.yaml with its scenes swapped for a folder of photos plans the training at
    the cpu preset as it is, with or without ``--replace-workflow-config`` (without it, it is
    merged over config/config.yaml); so does make demo's config/demo.yaml, two training jobs
    side by side."""
    from eve3d.config import resolve_config

    photos = tmp_path / "capture" / "images"
    photos.mkdir(parents=True)
    for i in range(3):
        Image.fromarray(np.full((48, 64, 3), 40 * i, np.uint8)).save(photos / f"{i}.jpg")
    config = yaml.safe_load((REPO / "config/config.yaml").read_text())
    config.update(results=str(tmp_path / "results"), scenes={"mine": {"path": str(photos.parent)}})
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump(config))
    r = snakemake("-n", "-p", "-c2", "--configfile", str(tmp_path / "mine.yaml"),
                  *(["--replace-workflow-config"] if replace else []))
    assert r.returncode == 0, r.stderr[-3000:]
    jobs = training_job_configs(r.stdout + r.stderr)
    preset = resolve_config({"preset": "cpu", "scenes": {"mine": {"path": str(photos.parent)}}})
    assert {stage for stage, scene in jobs if scene == "mine"} == {"pretrain", "joint eve3d"}  # photos: eve3d alone
    for (stage, scene), job in jobs.items():
        section = stage.split()[0]
        if scene == "mine":
            # the protocol adds its own keys (nvs holds views out)
            assert {k: job[section][k] for k in preset[section]} == preset[section], stage
            assert job["train"] == preset["train"], stage
    threads = {job.title: job.threads for job in log_jobs((r.stdout + r.stderr).splitlines())}
    assert threads["joint mine eve3d"] == 2  # every core: one training job at a time

    r = snakemake("-n", "-p", "-c2", "--configfile", str(REPO / "config/demo.yaml"), "--config",
                  f"results={tmp_path / 'demo'}")
    assert r.returncode == 0, r.stderr[-3000:]
    jobs = training_job_configs(r.stdout + r.stderr)
    object_preset = resolve_config({"preset": "cpu", "scenes": {"o": {"synthetic": {"kind": "object"}}}})
    for (stage, scene), job in jobs.items():  # the preset's schedule, views and Gaussians
        section = stage.split()[0]
        assert {k: job[section][k] for k in object_preset[section]} == object_preset[section], stage
    threads = {job.title: job.threads for job in log_jobs((r.stdout + r.stderr).splitlines())}
    assert threads["joint synthetic-object pgsr"] == threads["joint synthetic-object eve3d"] == 1  # side by side


@pytest.mark.parametrize("cores, training_jobs", [(2, 1), (4, 1), (2, 2), (4, 2)])
def test_training_and_network_jobs_take_their_share_of_the_cores(tmp_path, cores, training_jobs):
    """The pretrain takes every core (it starts first); a joint stage's job and a stereo
    network's take the cores over ``training_jobs``: every core by default, one each on 2
    cores in the demo, where pgsr trains beside the chain pretrain → stereo → eve3d."""
    cfg = write_config(tmp_path, methods=["stereo-tsdf", "pgsr", "eve3d"], stereo={"backend": "hitnet"},
                       scenes={"s": {"synthetic": {"kind": "object"}}}, training_jobs=training_jobs)
    r = snakemake("-n", f"-c{cores}", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    jobs = {job.title: job for job in log_jobs((r.stdout + r.stderr).splitlines())}
    threads = {title: job.threads for title, job in jobs.items()}
    shared = ("joint s pgsr", "joint s eve3d", "stereo-depth s hitnet")
    assert threads["pretrain s"] == cores
    assert {t: threads[t] for t in shared} == dict.fromkeys(shared, cores // training_jobs), threads
    assert threads["stereo-render s"] == 1 and threads["mesh s eve3d"] == 1
    # the longest chain first, and the trained methods' meshes and scores before the others'
    assert jobs["pretrain s"].priority > jobs["stereo-render s"].priority > jobs["joint s eve3d"].priority > 0
    assert [jobs[f"{rule} s {m}"].priority for rule in ("mesh", "evaluate") for m in ("pgsr", "eve3d")] == [1] * 4
    assert [jobs[f"{rule} s stereo-tsdf"].priority for rule in ("mesh", "evaluate")] == [0, 0]


def test_slurm_profile_dry_runs_without_slurm(tmp_path):
    r = snakemake("-n", "--profile", str(REPO / "profiles/slurm"), "--config", f"results={tmp_path}")
    assert r.returncode == 0, r.stderr[-3000:]


def test_bad_config_value_is_named(tmp_path):
    cfg = write_config(tmp_path, mesh={"voxel": -0.5})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    assert "mesh.voxel" in r.stdout + r.stderr and "-0.5" in r.stdout + r.stderr


def test_bad_stereo_check_is_named_before_any_job(tmp_path):
    cfg = write_config(tmp_path, stereo={"mv_views": 5, "mv_neighbours": 4})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0 and "stereo.mv_views" in r.stdout + r.stderr


def test_bad_training_key_is_named_before_any_job(tmp_path):
    cfg = write_config(tmp_path, joint={"scale_wieght": 1.0})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    assert "scale_wieght" in r.stdout + r.stderr and "scale_weight" in r.stdout + r.stderr


@pytest.mark.slow
def test_tiny_training_run(tmp_path):
    """pretrain, stereo priors, stereo-tsdf, 3dgs, pgsr and eve3d through the workflow on a
    tiny scene with very short schedules. (The nvs protocol's run is the Mip-NeRF 360
    miniature's, tests/workflow/test_benchmarks.py.)"""
    short = {"refine_start": 5, "refine_every": 5, "refine_stop": 25, "reset_every": 0}
    tiny = {"kind": "object", "views": 12, "width": 160, "height": 120}
    cfg = write_config(tmp_path, methods=["stereo-tsdf", "3dgs", "pgsr", "eve3d"],
                       scenes={"tiny": {"synthetic": tiny}},
                       pretrain={"iterations": 80, "reinit_at": [], "simplify_at": [60], "densify": short},
                       joint={"iterations": 40, "dn_from": 20, "mv_from": 20, "prior_from": 5, "joint_from": 20,
                              "init_prior_points": 3000, "densify": short})
    results = tmp_path / "results"
    layout = Layout(results)
    r = snakemake(WORKFLOW_CORES, "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    run_log = re.search(r"Complete log\(s\): (\S+)", r.stderr).group(1)
    rows = list(csv.DictReader(open(layout.summary())))
    assert [(row["scene"], row["method"]) for row in rows] == [
        ("tiny", "3dgs"), ("tiny", "eve3d"), ("tiny", "pgsr"), ("tiny", "stereo-tsdf")]
    # the table printed once (by the workflow's onsuccess, after every job), as the summary wrote it
    table = (layout.logs() / "summary.log").read_text()
    assert "fscore" in table and (r.stdout + r.stderr).count(table.splitlines()[0]) == 1 and table in r.stdout
    assert all(0 < float(row["fscore"]) <= 1 for row in rows)
    # the depth each mesh fused, against the exact depth (a GT mesh gives it)
    assert all(abs(float(row["depth_signed_error"])) < 0.05 and 0 < float(row["depth_error"]) < 0.1 for row in rows)
    assert (results / "tiny/eve3d/priors/000.npz").exists() and (results / "tiny/eve3d/priors/000.compare.png").exists()
    evaluated = json.loads(layout.metrics("tiny", "3dgs").read_text())
    trained = json.loads(layout.train_metrics("tiny", "3dgs").read_text())
    pretrained = json.loads(layout.train_metrics("tiny", PRETRAIN).read_text())
    # metrics.json holds an evaluation, train_metrics.json a training stage's record, and each says so
    assert evaluated[RECORD] == EVALUATION and trained[RECORD] == TRAINING and pretrained[RECORD] == TRAINING
    assert not (layout.pretrain("tiny") / "metrics.json").exists()
    r = run_cli("evaluate", "--scene", results / "tiny/input", "--model", results / "tiny/3dgs/point_cloud.ply",
                "--protocol", "nvs", "--out", tmp_path / "nvs.json")
    assert r.returncode == 2 and "trained with holdout 0" in r.stderr and "joint.holdout: 8" in r.stderr
    views = list(csv.DictReader(open(results / "summary_views.csv")))
    assert views[0]["stage"] == "pretrain" and int(views[0]["views"]) == 2
    assert float(views[0]["psnr"]) > 15
    assert (results / "tiny/stereo/right/000.png").exists() and (results / "tiny/priors/sgbm/000.npz").exists()
    tone = json.loads(layout.tone_curve("tiny").read_text())  # the photos are matched through it
    assert len(tone) == 256 and json.loads((results / "tiny/stereo/pairs.json").read_text())["tone_curve"] == tone
    for method in ("3dgs", "pgsr", "eve3d"):
        assert (results / f"tiny/{method}/depth/000.npz").exists()
        assert (results / f"tiny/{method}/previews/000.depth.png").exists()
    assert not list(results.glob("tiny/*/checkpoint.pt"))  # removed once a stage's outputs exist
    # What every rule wrote, and that it is well-formed.
    assert_synth_input(results / "tiny/input", 12, 160, 120)  # synth
    scene = load_scene(results / "tiny/input")
    assert pretrained["iterations"] == 80 and math.isfinite(pretrained["train"]["psnr"])  # pretrain
    assert_gaussians(results / "tiny/pretrain/point_cloud.ply", pretrained["gaussians"])
    assert all(isinstance(v, int) and 0 <= v <= 255 for v in tone) and tone == sorted(tone)
    pairs = json.loads((results / "tiny/stereo/pairs.json").read_text())  # stereo_render
    assert sorted(pairs["views"]) == sorted(c.view_id for c in scene.cameras)
    for cam in scene.cameras:
        pair = pairs["views"][cam.view_id]
        assert pair["baseline"] > 0 and 0 <= pair["min_disparity"] < pair["max_disparity"] and pair["margin"] >= 0
        # the right view extends ``margin`` columns to the left of the photo's frame
        # at the size the pretrain trained at (the preset's 3/4)
        small = cam.scaled(pair["scale"])
        assert pair["scale"] == 0.75 and (small.width, small.height) == (120, 90)
        assert Image.open(results / f"tiny/stereo/right/{cam.view_id}.png").size == (small.width + pair["margin"],
                                                                                    small.height)
    assert_maps(results / "tiny/priors/sgbm", scene, scale=0.75)  # stereo_depth, at the pretrain's size
    assert_maps(results / "tiny/priors/oracle", scene)
    for method in ("3dgs", "pgsr", "eve3d"):  # joint
        out = results / "tiny" / method
        trained = json.loads((out / "train_metrics.json").read_text())
        assert trained["method"] == method and math.isfinite(trained["train"]["psnr"])
        assert_gaussians(out / "point_cloud.ply", trained["gaussians"])
        assert_maps(out / "depth", scene)
    assert_maps(results / "tiny/eve3d/priors", scene)  # eve3d's final D̂
    assert all((results / f"tiny/eve3d/priors/{c.view_id}.compare.png").is_file() for c in scene.cameras)
    summary = {(row["scene"], row["method"]): row for row in csv.DictReader(open(results / "summary.csv"))}
    for method in ("3dgs", "eve3d", "pgsr", "stereo-tsdf"):  # mesh, evaluate; summary = the metrics
        assert_mesh(results / f"tiny/{method}/mesh.ply")
        m = assert_mesh_metrics(results / f"tiny/{method}/metrics.json", "tiny", method)
        assert float(summary["tiny", method]["fscore"]) == pytest.approx(m["fscore"])
    assert_profile(run_log)
    # a release that changes a registered method's settings reruns that method's jobs only
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text("from eve3d.core.methods import REGISTRY\n"
                                           "REGISTRY['pgsr'].settings['geo_weight'] = 0.5\n")
    path = os.pathsep.join(filter(None, (str(site), os.environ.get("PYTHONPATH"))))
    r = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "-n", "--configfile", str(cfg),
                        "--replace-workflow-config"], capture_output=True, text=True, cwd=REPO,
                       env={**os.environ, "PYTHONPATH": path})
    assert r.returncode == 0, r.stderr[-3000:]
    jobs = r.stdout.split("rule ")[1:]  # one job a block, its rule's name first
    assert {re.search(r"method=([\w-]+)", job).group(1) for job in jobs if job.startswith("joint:")} == {"pgsr"}
    assert "Params have changed" in r.stdout


def assert_profile(log: str) -> None:
    """``eve3d profile`` of a real run: every stage's job printed its phases, which add up to
    its wall time within Snakemake's one-second stamps, and the training jobs' steps are there."""
    run = read_run(Path(log))
    stages = [j for j in run.jobs if j.rule not in ("summary", "report_pages", "check_ground_truth")]
    assert stages and all(j.phases for j in stages), [j.title for j in stages if not j.phases]
    for job in stages:  # each figure printed to 0.1 s: the sum of n of them is off by up to n × 0.05
        shown = [v for k, v in job.phases.items() if k != "total"]
        assert sum(shown) == pytest.approx(job.phases["total"], abs=0.05 * (len(shown) + 1) + 1e-9)
        assert job.phases["total"] <= job.wall + 1.5 and job.phases["start-up"] > 0
    assert all(j.phases["steps"] > 0 for j in stages if j.rule in ("pretrain", "joint"))


@pytest.mark.slow
def test_tiny_run_with_a_failed_scene_then_rerun_one_stage(tmp_path):
    """The oracle on the tiny scene beside a scene whose SfM fails (photos of noise): with
    --keep-going the tiny scene finishes, and the summary and the report list the failed one
    with its first error line and log. Rerun without it, no failure is listed; --forcerun
    then reruns one stage and what depends on it, nothing upstream."""
    import cv2

    photos = tmp_path / "noise" / "images"
    photos.mkdir(parents=True)
    for i in range(4):
        cv2.imwrite(str(photos / f"{i:03d}.png"), np.random.default_rng(i).integers(0, 255, (48, 64, 3), np.uint8))
    scenes = yaml.safe_load(write_config(tmp_path).read_text())["scenes"]
    cfg = write_config(tmp_path, scenes={**scenes, "noise": {"path": str(tmp_path / "noise"), "methods": ["pgsr"]}})
    r = snakemake(WORKFLOW_CORES, "--keep-going", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    results = tmp_path / "results"
    layout = Layout(results)
    rows = {(row["scene"], row["method"]): row for row in csv.DictReader(open(layout.summary()))}
    assert set(rows) == {("tiny", "oracle"), ("noise", "pgsr")}
    failed = rows["noise", "pgsr"]
    assert failed["failed"] == (f"sfm: eve3d sfm: error: {photos}: SfM could not register any image pair "
                                "(too little texture or overlap?)")
    assert failed["log"] == str(layout.log("noise", "sfm")) and failed["fscore"] == ""
    assert f"failed: noise pgsr: sfm: eve3d sfm: error: {photos}" in r.stderr
    page = (layout.report_pages() / "summary.html").read_text()
    assert "noise" in page and "SfM could not register any image pair" in page

    tiny = write_config(tmp_path)  # the failed scene left out
    r = snakemake(WORKFLOW_CORES, "--configfile", str(tiny), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    assert not layout.failures().exists()
    rows = list(csv.DictReader(open(layout.summary())))
    assert [(row["scene"], row["method"]) for row in rows] == [("tiny", "oracle")] and not rows[0]["failed"]
    assert float(rows[0]["fscore"]) > 0.5
    assert float(rows[0]["depth_signed_error"]) == 0 and float(rows[0]["depth_error"]) == 0  # fused the exact depth
    assert_synth_input(results / "tiny/input", 12, 160, 120)
    assert_maps(results / "tiny/priors/oracle", load_scene(results / "tiny/input"))
    assert_mesh(results / "tiny/oracle/mesh.ply")
    m = assert_mesh_metrics(results / "tiny/oracle/metrics.json", "tiny", "oracle")
    assert float(rows[0]["fscore"]) == pytest.approx(m["fscore"])
    mesh_time = (results / "tiny/oracle/mesh.ply").stat().st_mtime_ns
    prior_time = (results / "tiny/priors/oracle/000.npz").stat().st_mtime_ns
    r = snakemake(WORKFLOW_CORES, "--configfile", str(tiny), "--replace-workflow-config", "--forcerun", "mesh")
    assert r.returncode == 0, r.stderr[-3000:]
    assert (results / "tiny/oracle/mesh.ply").stat().st_mtime_ns > mesh_time
    assert (results / "tiny/priors/oracle/000.npz").stat().st_mtime_ns == prior_time
    shutil.rmtree(results)


def user_layout(tmp_path, kind: str, views: int = 24):
    """A generated scene rearranged the way a user brings one: ``images/`` and a COLMAP
    text model with the exact poses, and the GT mesh in a folder of its own (named in the
    config); no eve3d metadata."""
    generated = generate(kind, tmp_path / "generated" / kind, views=views)
    root = tmp_path / kind
    shutil.copytree(generated / "images", root / "images")
    write_colmap(load_scene(generated), root / "sparse" / "0", binary=False)
    gt = tmp_path / "ground_truth" / f"{kind}.ply"
    gt.parent.mkdir(exist_ok=True)
    shutil.copy(generated / "gt" / "mesh.ply", gt)
    shutil.rmtree(generated)
    return root, gt


@pytest.mark.slow
def test_oracle_scores_near_perfectly_on_scenes_brought_by_a_user(tmp_path):
    """An object beside a hollow vase (surfaces no camera sees) and a room seen from
    cameras clustered near its centre, as COLMAP text models with a separate GT mesh: the
    exact depth, fused, scores F ≥ 0.98 under the synthetic protocol (the default for a
    COLMAP dataset with a gt_mesh)."""
    scenes = {}
    for kind in ("vase", "inside-room"):
        root, gt = user_layout(tmp_path, kind)
        assert (root / "sparse/0/cameras.txt").exists() and not (root / "eve3d_scene.json").exists()
        scenes[kind] = {"path": str(root), "gt_mesh": str(gt), "kind": "object" if kind == "vase" else "scene"}
    cfg = write_config(tmp_path, scenes=scenes, mesh={"coarsen": 5})
    r = snakemake(WORKFLOW_CORES, "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    results = tmp_path / "results"
    for kind in scenes:
        assert_maps(results / kind / "priors/oracle", load_scene(tmp_path / kind))
        assert_mesh(results / kind / "oracle/mesh.ply")
        m = assert_mesh_metrics(results / kind / "oracle/metrics.json", kind, "oracle")
        assert m["protocol"] == "synthetic" and m["fscore"] >= 0.98, (kind, m)
        assert "visible-GT bounding-box diagonal" in m["tau_rule"]
    vase = json.loads((results / "vase/oracle/metrics.json").read_text())
    assert vase["visible_gt_fraction"] < 0.8  # the inside and bottom of the vase, the box's underside
    room = json.loads((results / "inside-room/oracle/metrics.json").read_text())
    assert room["tau"] > 5 * 0.005 * load_scene(tmp_path / "inside-room").radius  # not tied to the camera radius


def test_scene_without_ground_truth_is_scored_on_held_out_views(tmp_path, object_dataset):
    """No ground truth given: the nvs protocol, and every trained method meshed all the same;
    a geometric protocol named without its ground truth is refused, naming the key."""
    cfg = write_config(tmp_path, methods=["oracle", "stereo-tsdf", "pgsr"], scenes={"mine": {"path": str(object_dataset)}})
    r = snakemake("-n", "-p", "--configfile", str(cfg), "--replace-workflow-config")
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-3000:]
    assert f"--protocol nvs --model {tmp_path}/results/mine/pgsr/point_cloud.ply" in out
    assert f"--out {tmp_path}/results/mine/pgsr/mesh.ply" in out and "mine/oracle" not in out
    cfg = write_config(tmp_path, methods=None, scenes={"mine": {"path": str(object_dataset)}})
    r = snakemake("-n", "-p", "--configfile", str(cfg), "--replace-workflow-config")
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "mine/eve3d/mesh.ply" in out and "mine/pgsr" not in out, out[-3000:]
    cfg = write_config(tmp_path, scenes={"mine": {"path": str(object_dataset), "protocol": "synthetic"}})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    assert "scenes.mine (protocol synthetic): give gt_mesh" in r.stdout + r.stderr
    cfg = write_config(tmp_path, scenes={"mine": {"synthetic": {"kind": "object"}, "protocol": "chamfer"}})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0 and "scenes.mine.protocol: unknown protocol 'chamfer'" in r.stdout + r.stderr


def test_dry_run_of_dtu_and_nvs_scenes(tmp_path, object_scene, object_dataset):
    """A DTU scan (default protocol dtu; no GT mesh, so no oracle) and a COLMAP scene scored
    on held-out views (protocol nvs; trained methods only, held out in training)."""
    scan = tmp_path / "scan1"
    write_dtu_layout(object_scene, scan, dtu_scale_mat())
    for name in ("stl001_total.ply", "ObsMask1_10.mat", "Plane1.mat"):
        (tmp_path / name).write_text("")
    dtu = {"stl": str(tmp_path / "stl001_total.ply"), "obs_mask": str(tmp_path / "ObsMask1_10.mat"),
           "plane": str(tmp_path / "Plane1.mat")}
    cfg = write_config(tmp_path, methods=["oracle", "stereo-tsdf", "pgsr"],
                       scenes={"scan1": {"path": str(scan), "dtu": dtu},
                               "views": {"path": str(object_dataset), "protocol": "nvs"}})
    r = snakemake("-n", "-p", "--configfile", str(cfg), "--replace-workflow-config")
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-3000:]
    assert "scan1/oracle" not in out and "views/oracle" not in out and "views/stereo-tsdf" not in out
    assert f"--protocol dtu --gt {dtu['stl']} --obs-mask {dtu['obs_mask']} --plane {dtu['plane']} --mesh " \
           f"{tmp_path}/results/scan1/pgsr/mesh.ply" in out
    # before any training, the check that the ground truth lines up with the cameras
    assert f"evaluate --check --scene {scan} --out {tmp_path}/results/scan1/ground_truth_check.json --protocol dtu" in out
    assert f"--protocol nvs --model {tmp_path}/results/views/pgsr/point_cloud.ply" in out
    assert '\\"holdout\\": 8' in out or '"holdout": 8' in out


def test_failed_rows_name_the_job_each_row_waited_for(tmp_path):
    """From Snakemake's log of failed jobs: a method's own training failure names that row
    only; a prior backend's failure names the rows left without metrics; a row with metrics
    is not listed."""
    from eve3d.core.failures import failed_jobs, failed_rows

    layout = Layout(tmp_path / "results")
    layout.metrics("tiny", "oracle").parent.mkdir(parents=True)
    layout.metrics("tiny", "oracle").write_text("{}")
    joint, priors = layout.log("tiny", "joint", "pgsr"), layout.log("tiny", "stereo_depth", "sgbm")
    joint.parent.mkdir(parents=True)
    joint.write_text("pgsr:  12%|#| 12/100\nTraceback (most recent call last):\n  File \"x.py\"\n"
                     "RuntimeError: the loss is NaN at iteration 12\n")
    priors.write_text("eve3d stereo-depth: error: /data/images/003.png: corrupt or unreadable image\n")
    log = tmp_path / "snakemake.log"
    log.write_text(f"Error in rule joint:\n    jobid: 4\n    log: {joint} (check log file(s) for error details)\n"
                   f"    shell:\n        ...\nSomething else\nError in rule stereo_depth:\n    jobid: 2\n"
                   f"    log: {priors} (check log file(s) for error details)\n")
    rows = failed_rows(layout, [("tiny", m) for m in ("oracle", "pgsr", "stereo-tsdf")], failed_jobs([log]))
    assert rows == [
        {"scene": "tiny", "method": "pgsr", "failed": "joint: RuntimeError: the loss is NaN at iteration 12",
         "log": str(joint)},
        {"scene": "tiny", "method": "stereo-tsdf",
         "failed": "stereo_depth: eve3d stereo-depth: error: /data/images/003.png: corrupt or unreadable image",
         "log": str(priors)}]


def _digests(root: Path) -> dict[str, str]:
    import hashlib

    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_killed_training_reruns_to_the_same_result(tmp_path):
    """A training job killed with SIGKILL in the middle of the workflow, then the workflow
    rerun: the same Gaussians, mesh scores and depth as an uninterrupted run (one thread, the
    same seed), resumed from the job's checkpoint, and every artefact written before the kill
    byte for byte as it was."""
    import signal
    import time

    import psutil
    import torch

    from eve3d.gaussians.model import GaussianModel

    short = {"refine_start": 10, "refine_every": 10, "refine_stop": 40, "reset_every": 0}
    runs = {}
    for name in ("straight", "killed"):
        (tmp_path / name).mkdir()
        runs[name] = write_config(tmp_path / name, methods=["pgsr"],
                                  scenes={"tiny": {"synthetic": {"kind": "object", "views": 6, "width": 64, "height": 48}}},
                                  joint={"iterations": 60, "checkpoint_every": 20, "dn_from": 20, "mv_from": 20,
                                         "densify": short})
    # -c1: the job trains on one thread; the target: the scores (no summary, no report)
    command = ["-c1", "--replace-workflow-config", "--configfile"]

    def target(name):
        return str(Layout(tmp_path / name / "results").metrics("tiny", "pgsr"))

    r = snakemake(target("straight"), *command, str(runs["straight"]))
    assert r.returncode == 0, r.stderr[-3000:]

    layout = Layout(tmp_path / "killed/results")
    checkpoint = layout.method("tiny", "pgsr") / "checkpoint.pt"
    run = subprocess.Popen([sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), target("killed"),
                            *command, str(runs["killed"])], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not checkpoint.exists() and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert checkpoint.exists(), "the training job wrote no checkpoint"
    trainer = [p for p in psutil.Process(run.pid).children(recursive=True)
               if "joint" in p.cmdline() and "eve3d" in p.cmdline()]
    assert len(trainer) == 1
    before = _digests(layout.input("tiny"))
    trainer[0].send_signal(signal.SIGKILL)
    assert run.wait(timeout=120) != 0
    assert checkpoint.exists() and not layout.model("tiny", "pgsr").exists()  # nothing that looks complete
    r = snakemake(target("killed"), *command, str(runs["killed"]))
    assert r.returncode == 0, r.stderr[-3000:]
    assert "resum" in layout.log("tiny", "joint", "pgsr").read_text()
    assert _digests(layout.input("tiny")) == before  # the earlier artefacts, untouched
    assert not checkpoint.exists()

    straight = Layout(tmp_path / "straight/results")
    a, b = (GaussianModel.load_ply(x.model("tiny", "pgsr")) for x in (straight, layout))
    assert len(a) == len(b)
    for key, value in a.params.items():
        assert torch.allclose(b.params[key], value, atol=1e-5), key
    scores = [json.loads(x.metrics("tiny", "pgsr").read_text()) for x in (straight, layout)]
    for key in ("accuracy", "completeness", "precision", "recall", "fscore"):
        assert scores[1][key] == pytest.approx(scores[0][key], rel=1e-3, abs=1e-5), key


@pytest.mark.slow
def test_photos_and_their_path_run_to_meshes_and_held_out_scores(object_photos, tmp_path):
    """An images-only scene with no other key and no methods named: SfM, the default nvs
    protocol, eve3d alone meshed with its shaded views, held-out views side by side with the
    photos."""
    data = shutil.copytree(object_photos, tmp_path / "mine")
    short = {"refine_start": 5, "refine_every": 5, "refine_stop": 25, "reset_every": 0}
    cfg = write_config(tmp_path, methods=None, scenes={"mine": {"path": str(data)}},
                       train={"max_side": 240},  # trained at 240×180
                       pretrain={"iterations": 80, "reinit_at": [], "simplify_at": [60], "densify": short},
                       joint={"iterations": 40, "dn_from": 20, "mv_from": 20, "prior_from": 5, "joint_from": 20,
                              "init_prior_points": 3000, "densify": short})
    r = snakemake(WORKFLOW_CORES, "--configfile", str(cfg), "--replace-workflow-config")
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
    assert sorted(p.name for p in layout.scene("mine").iterdir() if p.name in REGISTRY) == ["eve3d"]
    assert json.loads(layout.train_metrics("mine", PRETRAIN).read_text())["held_out"]["views"] == 2
    assert (layout.sfm("mine") / "images_2").is_dir()


def test_the_workflow_passes_each_job_its_sections_as_one_argument(tmp_path):
    """Every eve3d job of the default workflow gets its settings as one inline --config with
    `preset: null` and the resolved sections; no settings flag is written by hand."""
    import json
    import shlex

    r = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "-n", "-p", "--config",
                        f"results={tmp_path / 'results'}"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr[-3000:]
    commands = [line for line in r.stdout.splitlines() if " -m eve3d " in line and " summary " not in line]
    assert len(commands) >= 10
    reads = {"synth": {"synthetic"}, "stereo-depth": {"stereo"}, "stereo-render": {"stereo", "pretrain"},
             "pretrain": {"train", "pretrain"}, "joint": {"train", "joint"}, "mesh": {"mesh"},
             "evaluate": {"evaluate", "mesh"}, "report": {"stereo"}}
    for line in commands:
        argv = shlex.split(line.split(" -m eve3d ", 1)[1].split(" > ")[0])
        assert argv.count("--config") == 1, line
        job = json.loads(argv[argv.index("--config") + 1])
        assert job.pop("preset", "missing") is None and set(job) - {"variants"} == reads[argv[0]], line
        flags = [x for x in argv if x.startswith("--")]
        assert set(flags) <= {"--config", "--scene", "--out", "--model", "--depth", "--mesh", "--gt", "--gt-mesh",
                              "--stereo", "--priors", "--method", "--backend", "--protocol", "--exact-depth",
                              "--scene-name", "--kind", "--results", "--dataset"}, line


def test_unknown_method_in_config_is_named_before_any_job(tmp_path):
    cfg = write_config(tmp_path, methods=["oracle", "eve3dd"])
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0 and "unknown method(s) eve3dd" in r.stdout + r.stderr


def test_a_config_variant_gets_its_own_jobs(tmp_path):
    cfg = write_config(tmp_path, methods=["pgsr", "pgsr-flat"], variants={"pgsr-flat": {"method": "pgsr", "dn_weight": 0}})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config", "-p")
    assert r.returncode == 0, r.stderr[-2000:]
    out = r.stdout + r.stderr
    assert "tiny/pgsr-flat/point_cloud.ply" in out and "tiny/pgsr/point_cloud.ply" in out
    assert "--method pgsr-flat" in out and '"pgsr-flat": {"dn_weight": 0, "method": "pgsr"}' in out


def test_a_prior_method_depends_on_the_stereo_priors_in_the_workflow(tmp_path):
    cfg = write_config(tmp_path, methods=["pgsr", "eve3d", "eve3d-fast"], stereo={"backend": "sgbm"})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config", "-p")
    assert r.returncode == 0, r.stderr[-2000:]
    out = r.stdout + r.stderr
    assert "rule stereo_depth" in out and f"--priors {tmp_path}/results/tiny/priors/sgbm" in out
    assert out.count("--priors") == 2  # eve3d and eve3d-fast, not pgsr
    # the cpu preset's eve3d-fast schedule reaches the job
    assert '"eve3d-fast": {"densify": {"refine_stop": 600}, "dn_from": 250' in out
