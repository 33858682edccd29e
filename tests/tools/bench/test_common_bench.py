"""eve3d.tools.bench.common: a function run in a fresh process, which reports its own peak
memory rather than its parent's."""
import multiprocessing
import os

from eve3d.tools.bench.common import in_child, peak_rss_mb


def test_a_child_reports_its_own_peak_not_its_parents():
    """The parent touches 400 MB before it starts the child; the child's peak is its own
    (getrusage's would carry the parent's over)."""
    block = bytearray(400 * 2**20)
    block[:: 4096] = b"x" * len(block[:: 4096])  # every page touched
    del block
    assert peak_rss_mb() >= 400
    pid, peak = in_child(multiprocessing.get_context("spawn"), _pid_and_peak, ())
    assert pid != os.getpid() and 0 < peak < 300


def _pid_and_peak(_args):
    return os.getpid(), peak_rss_mb()
