"""What the benchmarks share: a process's peak memory, and a function run in a fresh process."""
from __future__ import annotations

import multiprocessing
import resource
from collections.abc import Callable


def peak_rss_mb() -> float:
    """This process's peak resident memory. Read from /proc (VmHWM), which starts afresh
    at exec: getrusage's ru_maxrss keeps the spawning parent's peak."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def in_child(ctx: multiprocessing.context.BaseContext, fn: Callable, args: tuple):
    """``fn(args)`` in a fresh process of ``ctx``."""
    pool = ctx.Pool(1)
    result = pool.apply(fn, (args,))
    pool.close()  # not terminate(): pycolmap's signal handler would print a stack trace
    pool.join()
    return result
