"""Training jobs sharing the cores: the last one left takes them all (eve3d.core.cores)."""
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
        (tmp_path / str(os.getppid())).touch()  # a second job, alive
        (tmp_path / str(finished_pid())).touch()  # a job killed without removing its file
        assert share.jobs() == 2 and share.threads() == 2
        (tmp_path / str(os.getppid())).unlink()  # the other job ends
        assert share.threads() == 4
    assert not (tmp_path / str(os.getpid())).exists()  # unregistered on leaving


def test_one_core_each_at_least(tmp_path):
    for pid in (os.getppid(), 1):
        (tmp_path / str(pid)).touch()
    with CoreShare(tmp_path, 2) as share:
        assert share.jobs() == 3 and share.threads() == 1


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
