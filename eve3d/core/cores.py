"""Jobs that share the cores: each training job takes its part of what the other jobs leave,
and the last one left takes them all (issue 78).

The workflow runs `training_jobs` training jobs side by side, each on its share of the cores
(the demo: `pgsr` on one core beside the chain pretrain → stereo → `eve3d` on the other),
and the meshes and scores of the methods done beside them. Every job started with
``EVE3D_CORE_SHARE=DIR:CORES`` in its environment registers in ``DIR`` while it runs: a file
named by its process id, with ``.N`` added for a job that keeps its N threads (a mesh, a
score, a stereo match); a training job's file has the bare id. Every :data:`EVERY` steps a
training job takes, as its threads (``torch.set_num_threads``: the C++ rasteriser's OpenMP
regions share torch's runtime, so they follow), the cores the other jobs alive leave over the
training jobs alive. A job that shared a core with a training job on two threads made both
several times slower (docs/development.md, "Oversubscription").
"""
from __future__ import annotations

import os
from pathlib import Path

ENV = "EVE3D_CORE_SHARE"
EVERY = 10
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
    context manager that registers the job while it runs. ``keeps``: the threads of a job
    that keeps them; None for a training job, which takes its share."""

    def __init__(self, directory: Path | None, cores: int, keeps: int | None = None):
        self.directory, self.cores = directory and Path(directory), max(1, cores)
        name = str(os.getpid()) if keeps is None else f"{os.getpid()}.{max(1, keeps)}"
        self.entry = self.directory / name if self.directory else None
        self.registered = False

    @classmethod
    def from_environment(cls, keeps: int | None = None) -> CoreShare:
        """The share ``EVE3D_CORE_SHARE`` describes; where it is unset or malformed, none (no
        directory: entering and :meth:`rebalance` do nothing, and a job run by hand keeps the
        threads it was given)."""
        directory, _, cores = os.environ.get(ENV, "").rpartition(":")
        return cls(Path(directory), int(cores), keeps) if directory and cores.isdigit() else cls(None, 1)

    def __enter__(self) -> CoreShare:
        # a process registers once: a training stage inside a registered command leaves it be
        if self.entry and not self.entry.exists():
            self.directory.mkdir(parents=True, exist_ok=True)
            self.entry.touch()
            self.registered = True
        return self

    def __exit__(self, *exc) -> None:
        if self.registered:
            self.entry.unlink(missing_ok=True)

    def jobs(self) -> tuple[int, int]:
        """The training jobs alive (this one counted at least) and the threads that the other
        jobs alive keep."""
        training = kept = 0
        for p in self.directory.iterdir():
            pid, _, keeps = p.name.partition(".")
            if pid.isdigit() and (not keeps or keeps.isdigit()) and alive(int(pid)):
                training += not keeps
                kept += int(keeps or 0)
        return max(1, training), kept

    def threads(self) -> int:
        """This training job's threads: the cores the other jobs leave, over the training jobs
        alive, at least one."""
        training, kept = self.jobs()
        return max(1, (self.cores - kept) // training)

    def rebalance(self, step: int) -> None:
        """Every :data:`EVERY` steps, take :meth:`threads` threads (sharing with nobody: nothing)."""
        if self.directory and step % EVERY == 0:
            import torch

            threads = self.threads()
            if threads != torch.get_num_threads():
                torch.set_num_threads(threads)
