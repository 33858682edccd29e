"""Submission to a real Slurm: a one-node cluster of Debian's slurm-wlm and munge, started
on this machine, runs the tiny scene through ``profiles/slurm``; the plugin's
``sbatch`` lines say what each job asked for."""
from __future__ import annotations

import csv
import math
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yte

from tests.helpers import REPO, SNAKEFILE, write_config

DAEMONS = ("munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "squeue", "sinfo", "srun")


def _slurm_conf(root: Path, host: str) -> str:
    """One node, one partition, no accounting; the node says it has 32 cores, 128 GB and two
    GPUs (a count only, no device), so that GPU jobs run and the profile's requests fit side
    by side: the pretrain and pgsr's joint each ask for 8 cores and a GPU."""
    return f"""\
ClusterName=eve3dtest
SlurmctldHost={host}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort=26817
SlurmdPort=26818
AuthType=auth/munge
AuthInfo=socket={root}/munge.socket
CredType=cred/munge
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SlurmdParameters=config_overrides
GresTypes=gpu
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName={host} NodeAddr=127.0.0.1 CPUs=32 RealMemory=128000 Gres=gpu:2 State=UNKNOWN
PartitionName=eve3dtest Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"""


@pytest.fixture(scope="module")
def slurm_cluster(tmp_path_factory):
    """A running one-node cluster: its environment (``SLURM_CONF``). The daemons run in the
    foreground as this test's children and are stopped by their own process ids."""
    missing = [name for name in DAEMONS + CLIENTS if not shutil.which(name)]
    if missing:  # the set-up (make install) installs them: a missing one is a failure, not a skip
        pytest.fail(f"{', '.join(missing)} not found: install Debian's slurm-wlm and munge (make install)")
    if os.geteuid() != 0:
        pytest.skip("slurmd runs as root")
    root = tmp_path_factory.mktemp("slurm")
    for folder in ("state", "spool"):
        (root / folder).mkdir()
    key = root / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o400)
    host = socket.gethostname().split(".")[0]  # slurmd names its node by the short host name
    (root / "slurm.conf").write_text(_slurm_conf(root, host))
    (root / "gres.conf").write_text(f"AutoDetect=off\nNodeName={host} Name=gpu File=/dev/null\nNodeName={host} Name=gpu File=/dev/zero\n")
    # The jobstep plugin drops SLURM_* from the environment of the srun inside each job,
    # which then looks for /etc/slurm/slurm.conf: a shim first on PATH gives it this one.
    shim = root / "bin" / "srun"
    shim.parent.mkdir()
    shim.write_text(f"#!/bin/sh\nSLURM_CONF={root}/slurm.conf exec {shutil.which('srun')} \"$@\"\n")
    shim.chmod(0o755)
    # This interpreter's folder next: `snakemake` and the jobs' `python` are this environment's
    # (make test does not put it on PATH; an earlier test that built the C++ rasteriser did).
    path = os.pathsep.join([str(shim.parent), str(Path(sys.executable).parent), os.environ["PATH"]])
    env = {**os.environ, "SLURM_CONF": str(root / "slurm.conf"), "PATH": path}
    commands = [
        ["munged", "--foreground", "--force", f"--socket={root}/munge.socket", f"--key-file={key}",
         f"--pid-file={root}/munged.pid", f"--seed-file={root}/munged.seed", f"--log-file={root}/munged.log"],
        ["slurmctld", "-D", "-i", "-f", env["SLURM_CONF"]],
        ["slurmd", "-D", "-f", env["SLURM_CONF"]],  # -f: the jobs' srun finds it too
    ]
    daemons = []
    try:
        for command in commands:
            daemons.append(subprocess.Popen(command, env=env, stdout=open(root / f"{command[0]}.out", "w"),
                                            stderr=subprocess.STDOUT))
            time.sleep(0.5)
        for _ in range(60):  # the node registers within a few seconds
            state = subprocess.run(["sinfo", "-h", "-o", "%t"], env=env, capture_output=True, text=True).stdout
            if state.strip() == "idle":
                break
            time.sleep(0.5)
        else:
            logs = "\n".join((root / f"{c[0]}.out").read_text()[-1000:] for c in commands)
            pytest.fail(f"the test cluster did not come up (sinfo: {state!r}):\n{logs}")
        yield env
    finally:
        for daemon in reversed(daemons):
            daemon.terminate()
        for daemon in daemons:
            try:
                daemon.wait(timeout=20)
            except subprocess.TimeoutExpired:
                daemon.kill()


def sbatch_requests(log: str) -> dict[str, dict[str, str]]:
    """What each rule's jobs asked for, from the plugin's ``sbatch call:`` lines in the
    workflow's log: {rule: {option: value}}, an option without a value mapped to ""."""
    requests = {}
    for line in log.splitlines():
        if "sbatch call:" not in line:
            continue
        tokens = shlex.split(line.split("sbatch call:", 1)[1].split(" --wrap=")[0])
        options, i = {}, 1
        while i < len(tokens):
            key, _, value = tokens[i].partition("=")
            if not value and i + 1 < len(tokens) and not tokens[i + 1].startswith("-"):
                value, i = tokens[i + 1], i + 1
            options[key], i = value, i + 1
        rule = re.match(r"rule_(\w+?)(_wildcards|$)", options["--comment"]).group(1)
        requests.setdefault(rule, []).append(options)
    return requests


def profile_requests(rule: str, profile: dict) -> dict[str, str]:
    """What the profile asks for a rule's jobs: time (min), memory (MB) and cores."""
    resources = {**profile["default-resources"], **profile["set-resources"].get(rule, {})}
    return {"-t": str(resources["runtime"]), "--mem": str(resources["mem_mb"]),
            "--cpus-per-task": str(profile["set-threads"].get(rule, 1))}


@pytest.mark.slow
def test_tiny_scene_runs_through_the_slurm_profile(slurm_cluster, tmp_path):
    """Every stage kind, on short schedules, through sbatch and srun: the results are
    complete, each job asked for the profile's time, memory and cores in the site's
    partition, and exactly the Gaussian training and rendering jobs asked for a GPU."""
    short = {"refine_start": 5, "refine_every": 5, "refine_stop": 15, "reset_every": 0}
    tiny = {"kind": "object", "views": 8, "width": 96, "height": 72}
    cfg = write_config(tmp_path, methods=["oracle", "stereo-tsdf", "pgsr"], scenes={"tiny": {"synthetic": tiny}},
                       pretrain={"iterations": 20, "reinit_at": [], "simplify_at": [], "densify": short},
                       joint={"iterations": 20, "dn_from": 10, "mv_from": 10, "densify": short},
                       # a 20-step pretrain is a blur: the stereo's checks against it (its alpha, the
                       # neighbours' agreement with its depth, its edges) left stereo-tsdf a few faces
                       # or none (7 at 076d7bc), and this test is about the cluster
                       stereo={"min_alpha": 0.0, "mv_ncc_threshold": 0.0, "edge_window": 0})
    env = {**slurm_cluster, "EVE3D_SLURM_PARTITION": "eve3dtest", "EVE3D_SLURM_GPU_MODEL": ""}
    # The plugin checks the first time after --slurm-init-seconds-before-status-checks and then,
    # while nothing has finished, each time 10 s later than the last: a tiny job is done 8–10 s
    # after its sbatch (two Snakemake starts inside), so at 12 s each stage waits 12 s (at 6 s,
    # 6 + 16 = 22 s: the test took 188 s, at 12 s 125 s).
    r = subprocess.run(["snakemake", "-s", str(SNAKEFILE), "--profile", str(REPO / "profiles/slurm"),
                        "--configfile", str(cfg), "--replace-workflow-config", "--slurm-status-command", "squeue",
                        "--slurm-init-seconds-before-status-checks", "12", "--latency-wait", "5", "--jobs", "4",
                        "--retries", "0", "--omit-from", "report_pages", "--slurm-logdir", str(tmp_path / "slurm_logs"), "--verbose",
                        "--logger", "eve3d"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    shown = r.stdout + r.stderr
    assert r.returncode == 0, shown[-4000:]
    log = next((tmp_path / ".snakemake/log").glob("*.snakemake.log")).read_text()  # verbose: the sbatch lines
    rows = list(csv.DictReader(open(tmp_path / "results" / "summary.csv")))
    assert sorted(row["method"] for row in rows) == ["oracle", "pgsr", "stereo-tsdf"]
    scores = {row["method"]: float(row["fscore"]) for row in rows}
    assert scores["oracle"] > 0.8 and all(math.isfinite(f) for f in scores.values()), scores  # the exact depth, fused
    for job in ("synth tiny", "pretrain tiny", "joint tiny pgsr", "mesh tiny stereo-tsdf"):  # the logger plugin
        assert re.search(rf"done +{job} +\d+ (s|min)", shown), shown[-3000:]
    requests = sbatch_requests(log)
    gpu = {"pretrain", "stereo_render", "joint"}  # the sgbm and oracle priors need none
    assert set(requests) == gpu | {"synth", "stereo_depth", "mesh", "evaluate", "summary"}
    assert len(requests["mesh"]) == len(requests["evaluate"]) == 3 and len(requests["stereo_depth"]) == 2
    profile = yte.process_yaml(open(REPO / "profiles/slurm/config.yaml"), require_use_yte=True)
    for rule, jobs in requests.items():
        for asked in jobs:
            assert asked["-p"] == "eve3dtest", (rule, asked)
            assert {key: asked[key] for key in ("-t", "--mem", "--cpus-per-task")} == profile_requests(rule, profile)
            assert asked.get("--gpus") == ("1" if rule in gpu else None), (rule, asked)
