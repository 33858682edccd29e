"""Where a stage's wall time goes: named phases, summed over the job and printed as one
``timing:`` line when the stage ends (``eve3d profile`` reads it from each job's log).

``start-up`` is the time from the process's start to the first phase: the interpreter, the
imports the stage's command made and reading its settings. Phases do not overlap: a phase
opened inside another pauses the outer one. Time outside every phase is ``other``.

The parts of a training step (:func:`step_part`) are another, finer clock: a plain call
unless ``eve3d bench training`` installs its timer (:func:`timing_step_parts`).
"""
from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

PREFIX = "timing:"
"""What the line starts with (``eve3d profile`` finds it by this)."""
START_UP, OTHER = "start-up", "other"

_IMPORTED = time.perf_counter()
_spent: dict[str, float] = {}
_stack: list[list] = []  # [name, perf_counter when it last resumed]
_started: float | None = None  # perf_counter of the process's start


def process_age() -> float:
    """Seconds since this process started (Linux's /proc; elsewhere since this module was
    imported, which is close to it: the CLI imports it first)."""
    try:
        with open("/proc/self/stat") as f:
            started_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22: starttime
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(uptime - started_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - _IMPORTED


def _begin(now: float) -> None:
    global _started
    if _started is None:
        _started = now - process_age()
        _spent[START_UP] = now - _started


@contextmanager
def phase(name: str) -> Iterator[None]:
    """Count the time inside the block to ``name`` (added up over every entry)."""
    now = time.perf_counter()
    _begin(now)
    if _stack:
        outer = _stack[-1]
        _spent[outer[0]] = _spent.get(outer[0], 0.0) + now - outer[1]
    _stack.append([name, now])
    try:
        yield
    finally:
        now = time.perf_counter()
        inner = _stack.pop()
        _spent[inner[0]] = _spent.get(inner[0], 0.0) + now - inner[1]
        if _stack:
            _stack[-1][1] = now


def spent() -> dict[str, float]:
    """Seconds per phase so far, ``other`` and the ``total`` since the process started
    (empty when no phase ran)."""
    if _started is None:
        return {}
    total = time.perf_counter() - _started
    out = dict(_spent)
    out[OTHER] = max(total - sum(out.values()), 0.0)
    out["total"] = total
    return out


def summary() -> str | None:
    """The ``timing:`` line, phases in the order they first ran; None when none ran."""
    times = spent()
    if not times:
        return None
    total = times.pop("total")
    return f"{PREFIX} " + ", ".join(f"{k} {v:.1f} s" for k, v in times.items()) + f"; total {total:.1f} s"


def reset() -> None:
    """Forget every phase (a command run in a process that ran another: the tests' ``run_cli``)."""
    global _started
    _spent.clear()
    _stack.clear()
    _started = None


def parse(line: str) -> dict[str, float] | None:
    """The phases and ``total`` of a ``timing:`` line (:func:`summary`); None for another line."""
    line = line.strip()
    if not line.startswith(PREFIX):
        return None
    body, _, total = line[len(PREFIX):].rpartition("; total ")
    out = {}
    for item in filter(None, (p.strip() for p in body.split(","))):
        name, _, value = item.removesuffix(" s").rpartition(" ")  # "read photos 0.3 s"
        out[name] = float(value)
    out["total"] = float(total.split()[0])
    return out


PartTimer = Callable[[str, Callable, tuple, dict], object]
"""(part, function, args, kwargs) → what the function returns, timed."""
_part_timer: PartTimer | None = None


def step_part(part: str) -> Callable[[Callable], Callable]:
    """Mark a function as the ``part`` of a training step that ``eve3d bench training``
    charges it to (its ``STEP_PARTS``): a plain call unless a timer is installed."""
    def mark(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def call(*args, **kwargs):
            timer = _part_timer
            return fn(*args, **kwargs) if timer is None else timer(part, fn, args, kwargs)
        return call
    return mark


@contextmanager
def timing_step_parts(timer: PartTimer) -> Iterator[None]:
    """Route every :func:`step_part` call through ``timer`` inside the block."""
    global _part_timer
    outer, _part_timer = _part_timer, timer
    try:
        yield
    finally:
        _part_timer = outer
