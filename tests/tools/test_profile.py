"""eve3d profile: a run's jobs, their phases and the time between them, from a Snakemake log
written as Snakemake 9 writes it (a real run's: tests/workflow/test_workflow.py)."""
from pathlib import Path

import pytest

from eve3d.core.errors import Eve3dError
from eve3d.tools.profile import between_jobs, format_profile, latest_log, phase_totals, read_run
from tests.helpers import run_cli

LOG = """\
  Working directory: {workdir}
Provided cores: 2
Select jobs to execute...
[Sat Nov 28 23:29:39 2026]
localrule pretrain:
    input: results/s/input
    log: results/logs/s/pretrain.log
    jobid: 2
    benchmark: results/benchmarks/s/pretrain.tsv
    wildcards: scene=s
    threads: 2
[Sat Nov 28 23:31:09 2026]
Finished jobid: 2 (Rule: pretrain)
[Sat Nov 28 23:31:12 2026]
localrule joint:
    log: results/logs/s/joint_eve3d.log
    jobid: 1
    wildcards: scene=s, method=eve3d
    threads: 2
[Sat Nov 28 23:31:12 2026]
localrule mesh:
    log: results/logs/s/mesh_pgsr.log
    jobid: 3
    wildcards: scene=s, method=pgsr
[Sat Nov 28 23:31:20 2026]
Finished jobid: 3 (Rule: mesh)
[Sat Nov 28 23:33:42 2026]
Finished jobid: 1 (Rule: joint)
[Sat Nov 28 23:33:42 2026]
localrule all:
    jobid: 0
Elapsed time: 0:04:03.500000
"""


@pytest.fixture
def run_dir(tmp_path):
    logs = tmp_path / "results/logs/s"
    logs.mkdir(parents=True)
    (logs / "pretrain.log").write_text("pretrain: 10%|█| 8/80\r\nwrote x\ntiming: start-up 4.0 s, read photos 1.5 s, "
                                       "steps 80.0 s, other 2.0 s; total 87.5 s\n")
    (logs / "joint_eve3d.log").write_text("joint: 100%|█| 40/40\ntiming: start-up 4.5 s, steps 120.0 s, "
                                          "export depths 20.0 s, other 3.0 s; total 147.5 s\n")
    (logs / "mesh_pgsr.log").write_text("eve3d mesh: error: something\n")  # no timing line: a failed job
    bench = tmp_path / "results/benchmarks/s"
    bench.mkdir(parents=True)
    (bench / "pretrain.tsv").write_text("s\th:m:s\tmax_rss\tcpu_time\n89.1\t0:01:29\t900\t135.0\n")
    log = tmp_path / ".snakemake/log/2026-11-28T232939.1.snakemake.log"
    log.parent.mkdir(parents=True)
    log.write_text(LOG.format(workdir=tmp_path))
    later = log.with_name("2026-11-28T234000.1.snakemake.log")  # make demo's rerun of the summary alone
    later.write_text("[Sat Nov 28 23:40:00 2026]\nlocalrule summary:\n    jobid: 5\n")
    return tmp_path


def test_jobs_phases_and_gaps_from_the_logs(run_dir):
    run = read_run(latest_log(run_dir))
    assert run.cores == 2 and run.wall == pytest.approx(243.5)
    assert [(j.title, j.started, j.wall, j.threads) for j in run.jobs] == [
        ("pretrain s", 0, 90, 2), ("joint s eve3d", 93, 150, 2), ("mesh s pgsr", 93, 8, 1)]
    pretrain, joint, mesh = run.jobs
    assert pretrain.phases["steps"] == 80.0 and pretrain.phases["total"] == 87.5 and pretrain.cpu == 135.0
    assert joint.phases["export depths"] == 20.0 and joint.cpu is None and mesh.phases == {}
    # 3 s between the pretrain and the joint, and 0.5 s after the last job
    assert between_jobs(run) == pytest.approx(3.5)
    assert phase_totals(run) == {"steps": 200.0, "export depths": 20.0, "start-up": 8.5, "other": 5.0,
                                 "read photos": 1.5}
    text = format_profile(run)
    assert "steps 120.0, export depths 20.0, other 3.0" in text
    markdown = format_profile(run, markdown=True)
    assert "| pretrain s | 2 | 1.50 | 0.0 | 90.0 | 4.0 | steps 80.0, other 2.0, read photos 1.5 |" in markdown
    assert "| no job running (Snakemake between jobs) | 3.5 |" in markdown


def test_cli_and_clear_errors(run_dir, tmp_path):
    r = run_cli("profile", "--workdir", run_dir)
    assert r.returncode == 0 and "2026-11-28T232939.1.snakemake.log" in r.stdout and "mesh s pgsr" in r.stdout
    r = run_cli("profile", "--workdir", tmp_path / "nowhere")
    assert r.returncode == 2 and "no Snakemake log of a run that ran a stage" in r.stderr
    with pytest.raises(Eve3dError, match="cannot read"):
        read_run(Path(tmp_path / "missing.log"))


def test_a_one_core_run_is_read(run_dir):
    """At -c1 Snakemake says "Provided cores: 1 (use --cores to define parallelism)"."""
    log = latest_log(run_dir)
    one_core = "Provided cores: 1 (use --cores to define parallelism)"
    log.write_text(log.read_text().replace("Provided cores: 2", one_core))
    assert read_run(log).cores == 1
