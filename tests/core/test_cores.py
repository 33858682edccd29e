"""Jobs sharing the cores: a training job takes what the others leave, and the last one left
takes them all (eve3d.core.cores)."""
import os
import subprocess
import sys

import torch

from eve3d.core.cores import ENV, EVERY, CoreShare


def finished_pid() -> int:
    """The id of a process that has ended."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_the_cores_go_to_the_jobs_alive(tmp_path):
    with CoreShare(tmp_path, 4) as share:
        assert share.threads() == 4  # alone
        (tmp_path / str(os.getppid())).touch()  # a second training job, alive
        (tmp_path / str(finished_pid())).touch()  # a job killed without removing its file
        assert share.jobs() == (2, 0) and share.threads() == 2
        (tmp_path / str(os.getppid())).unlink()  # the other job ends
        assert share.threads() == 4
    assert not (tmp_path / str(os.getpid())).exists()  # unregistered on leaving


def test_a_job_that_keeps_its_threads_leaves_the_rest(tmp_path):
    """A mesh or a score beside the last training job: that job takes the cores left, not
    all of them (two jobs on two threads each made both several times slower)."""
    with CoreShare(tmp_path, 2) as share, CoreShare(tmp_path, 2, keeps=1) as mesh:
        assert mesh.entry.name == f"{os.getpid()}.1"
        assert share.jobs() == (1, 1) and share.threads() == 1
    (tmp_path / f"{finished_pid()}.1").touch()  # a mesh that has ended
    with CoreShare(tmp_path, 4) as share:
        (tmp_path / f"{os.getppid()}.3").touch()  # more kept than the cores: one thread still
        assert share.threads() == 1
        (tmp_path / f"{os.getppid()}.3").unlink()
        assert share.threads() == 4


def test_a_process_registers_once(tmp_path):
    """A training stage inside a registered command leaves the command's registration be."""
    with CoreShare(tmp_path, 2) as command:
        with CoreShare(tmp_path, 2) as stage:
            assert not stage.registered
        assert command.entry.exists()
    assert not command.entry.exists()


def test_one_core_each_at_least(tmp_path):
    for pid in (os.getppid(), 1):
        (tmp_path / str(pid)).touch()
    with CoreShare(tmp_path, 2) as share:
        assert share.jobs() == (3, 0) and share.threads() == 1


def test_rebalance_sets_torch_threads(tmp_path):
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        with CoreShare(tmp_path, 2) as share:
            share.rebalance(EVERY + 1)  # not a step to look at
            assert torch.get_num_threads() == 1
            share.rebalance(EVERY)
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_from_environment(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    with CoreShare.from_environment() as alone:  # none: registers nowhere, never sets threads
        assert alone.directory is None
        before = torch.get_num_threads()
        alone.rebalance(0)
        assert torch.get_num_threads() == before
    monkeypatch.setenv(ENV, f"{tmp_path}:3")
    share = CoreShare.from_environment()
    assert share.directory == tmp_path and share.cores == 3
    monkeypatch.setenv(ENV, "no cores given")
    assert CoreShare.from_environment().directory is None


def test_every_workflow_job_registers_as_its_command_says(tmp_path, monkeypatch):
    """The CLI registers each job: a training stage takes its share, any other command keeps
    the threads Snakemake gave it (OMP_NUM_THREADS)."""
    from eve3d import cli

    monkeypatch.setenv(ENV, f"{tmp_path}:2")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert cli._core_share(cli._cmd_joint).entry.name == str(os.getpid())
    assert cli._core_share(cli._cmd_pretrain).entry.name == str(os.getpid())
    assert cli._core_share(cli._cmd_mesh).entry.name == f"{os.getpid()}.1"
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert cli._core_share(cli._cmd_stereo_depth).entry.name == f"{os.getpid()}.2"
