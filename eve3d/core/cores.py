"""Training jobs that share the cores: each takes its part of them, and the last one left
takes them all (issue 78).

The workflow runs `training_jobs` training jobs side by side, each on its share of the cores
(the demo: `pgsr` on one core beside the chain pretrain → stereo → `eve3d` on the other).
When one of them ends, the other would go on with its share while the freed core waits. A
job started with ``EVE3D_CORE_SHARE=DIR:CORES`` in its environment registers itself in
``DIR`` (a file named by its process id) and, every :data:`EVERY` steps, takes CORES over the
number of registered jobs still alive as its threads (``torch.set_num_threads``: the C++
rasteriser's OpenMP regions share torch's runtime, so they follow).
"""
from __future__ import annotations

import os
from pathlib import Path

ENV = "EVE3D_CORE_SHARE"
EVERY = 25
"""Steps between two looks at the other jobs (a look lists one small folder)."""


def alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a job killed without removing its file is not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


class CoreShare:
    """This job's part of ``cores`` shared with the jobs registered in ``directory``; a
    context manager that registers the job while it trains."""

    def __init__(self, directory: Path | None, cores: int):
        self.directory, self.cores = directory and Path(directory), max(1, cores)
        self.entry = self.directory / str(os.getpid()) if self.directory else None

    @classmethod
    def from_environment(cls) -> CoreShare:
        """The share ``EVE3D_CORE_SHARE`` describes; where it is unset or malformed, none (no
        directory: entering and :meth:`rebalance` do nothing, and a job run by hand keeps the
        threads it was given)."""
        directory, _, cores = os.environ.get(ENV, "").rpartition(":")
        return cls(Path(directory), int(cores)) if directory and cores.isdigit() else cls(None, 1)

    def __enter__(self) -> CoreShare:
        if self.entry:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.entry.touch()
        return self

    def __exit__(self, *exc) -> None:
        if self.entry:
            self.entry.unlink(missing_ok=True)

    def jobs(self) -> int:
        """The registered jobs still alive, this one included."""
        pids = [int(p.name) for p in self.directory.iterdir() if p.name.isdigit()]
        return max(1, sum(alive(pid) for pid in pids))

    def threads(self) -> int:
        """This job's threads: the cores over the jobs alive, at least one."""
        return max(1, self.cores // self.jobs())

    def rebalance(self, step: int) -> None:
        """Every :data:`EVERY` steps, take :meth:`threads` threads (sharing with nobody: nothing)."""
        if self.directory and step % EVERY == 0:
            import torch

            threads = self.threads()
            if threads != torch.get_num_threads():
                torch.set_num_threads(threads)
