"""The Snakemake workflow: config validation, dry runs (local and SLURM), a tiny real run."""
import csv
import shutil
import subprocess
import sys

import yaml

from tests.conftest import REPO

SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def snakemake(*args, cwd=REPO):
    return subprocess.run([*SNAKEMAKE, "-s", str(REPO / "Snakefile"), *args], capture_output=True, text=True, cwd=cwd)


def write_config(tmp_path, **overrides):
    config = {"preset": "cpu", "results": str(tmp_path / "results"), "methods": ["oracle"],
              "scenes": {"tiny": {"synthetic": {"kind": "object", "views": 12, "width": 160, "height": 120}}},
              "mesh": {"coarsen": 8}}
    config.update(overrides)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_default_config_dry_run_lists_every_stage(tmp_path):
    r = snakemake("-n", "--config", f"results={tmp_path}")
    assert r.returncode == 0, r.stderr
    for rule in ("synth", "stereo_depth", "stereo_render", "pretrain", "joint", "mesh", "evaluate", "summary"):
        assert rule in r.stdout + r.stderr


def test_slurm_profile_dry_runs_without_slurm(tmp_path):
    r = snakemake("-n", "--profile", str(REPO / "workflow/profiles/slurm"), "--config", f"results={tmp_path}")
    assert r.returncode == 0, r.stderr[-3000:]


def test_bad_config_value_is_named(tmp_path):
    cfg = write_config(tmp_path, mesh={"voxel": -0.5})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    assert "mesh.voxel" in r.stdout + r.stderr and "-0.5" in r.stdout + r.stderr


def test_bad_training_key_is_named_before_any_job(tmp_path):
    cfg = write_config(tmp_path, joint={"scale_wieght": 1.0})
    r = snakemake("-n", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode != 0
    assert "scale_wieght" in r.stdout + r.stderr and "scale_weight" in r.stdout + r.stderr


def test_tiny_training_run(tmp_path):
    """pretrain, stereo priors, stereo-tsdf, 3dgs and pgsr through the workflow on a tiny
    scene with very short schedules."""
    short = {"refine_start": 5, "refine_every": 5, "refine_stop": 25, "reset_every": 0}
    cfg = write_config(tmp_path, methods=["stereo-tsdf", "3dgs", "pgsr"],
                       pretrain={"iterations": 80, "reinit_at": [], "simplify_at": [60], "densify": short},
                       joint={"iterations": 40, "dn_from": 20, "mv_from": 20, "densify": short})
    results = tmp_path / "results"
    r = snakemake("-c2", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    rows = list(csv.DictReader(open(results / "summary.csv")))
    assert [row["method"] for row in rows] == ["3dgs", "pgsr", "stereo-tsdf"]
    assert all(0 < float(row["fscore"]) <= 1 for row in rows)
    views = list(csv.DictReader(open(results / "summary_views.csv")))
    assert views[0]["stage"] == "pretrain" and int(views[0]["views"]) == 2
    assert float(views[0]["psnr"]) > 15
    assert (results / "tiny/stereo/right/000.png").exists() and (results / "tiny/priors/sgbm/000.npz").exists()
    for method in ("3dgs", "pgsr"):
        assert (results / f"tiny/{method}/depth/000.npz").exists()
        assert (results / f"tiny/{method}/previews/000.depth.png").exists()
    assert not list(results.glob("tiny/*/checkpoint.pt"))  # removed once a stage's outputs exist


def test_tiny_run_then_rerun_one_stage(tmp_path):
    cfg = write_config(tmp_path)
    results = tmp_path / "results"
    r = snakemake("-c2", "--configfile", str(cfg), "--replace-workflow-config")
    assert r.returncode == 0, r.stderr[-3000:]
    rows = list(csv.DictReader(open(results / "summary.csv")))
    assert [(row["scene"], row["method"]) for row in rows] == [("tiny", "oracle")]
    assert float(rows[0]["fscore"]) > 0.5
    mesh_time = (results / "tiny/oracle/mesh.ply").stat().st_mtime_ns
    prior_time = (results / "tiny/priors/oracle/000.npz").stat().st_mtime_ns
    # --forcerun reruns one stage and what depends on it, nothing upstream.
    r = snakemake("-c2", "--configfile", str(cfg), "--replace-workflow-config", "--forcerun", "mesh")
    assert r.returncode == 0, r.stderr[-3000:]
    assert (results / "tiny/oracle/mesh.ply").stat().st_mtime_ns > mesh_time
    assert (results / "tiny/priors/oracle/000.npz").stat().st_mtime_ns == prior_time
    shutil.rmtree(results)
