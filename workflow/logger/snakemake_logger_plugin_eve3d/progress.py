"""What the terminal shows while the workflow runs: Snakemake's logger plugin ``eve3d``
(``snakemake --logger eve3d``; this package, ``snakemake-logger-plugin-eve3d``, registers
this handler in its ``__init__``).

One line when a job starts and one when it ends, with its stage, scene, method and wall
time; while a job runs, the latest progress line of its log file (the training bars carry
the iteration, loss and PSNR), at most once per ``interval`` seconds per job and only when
it changed. Warnings and errors pass through Snakemake's own formatter. The full output
stays in each job's log file.
"""
from __future__ import annotations

import logging
import re
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from snakemake_interface_logger_plugins.common import LogEvent

TAIL_BYTES = 4096
"""How much of a log's end is read for its latest progress line."""
_PROGRESS = re.compile(r"\d+/\d+|\d+%\|")  # a tqdm bar: "12/80" or " 15%|"
_BAR = re.compile(r"\s*\d+%\|[^|]*\|")  # the bar's drawing, dropped from the line shown


@dataclass
class RunningJob:
    rule: str
    wildcards: dict
    logs: list[str]
    started: float = field(default_factory=time.monotonic)
    shown: str = ""
    """The progress line last printed."""
    shown_at: float = 0.0

    @property
    def title(self) -> str:
        """The stage and what it works on: ``joint tiny eve3d``."""
        return " ".join([self.rule.replace("_", "-"), *map(str, self.wildcards.values())])


def latest_progress(log: str | Path) -> str | None:
    """The latest progress-bar line at the end of a job's log (tqdm rewrites its line with
    carriage returns), without the bar's drawing; None when there is none."""
    try:
        with open(log, "rb") as f:
            f.seek(0, 2)
            f.seek(max(0, f.tell() - TAIL_BYTES))
            tail = f.read().decode("utf-8", "replace")
    except OSError:
        return None
    for line in reversed(re.split(r"[\r\n]+", tail)):
        if _PROGRESS.search(line):
            return " ".join(_BAR.sub(" ", line).split())
    return None


def _wall(seconds: float) -> str:
    minutes, seconds = divmod(int(round(seconds)), 60)
    return f"{minutes} min {seconds:02d} s" if minutes else f"{seconds} s"


class ProgressHandler(logging.Handler):
    """Prints job starts and ends, and the running jobs' progress every ``interval`` seconds."""

    def __init__(self, stream: TextIO = sys.stderr, interval: float = 5.0,
                 formatter: logging.Formatter | None = None) -> None:
        super().__init__()
        self.stream = stream
        self.interval = interval
        self.fallback = formatter or logging.Formatter("%(message)s")
        self.jobs: dict[int, RunningJob] = {}
        self.done = self.total = 0
        self.lock = threading.Lock()
        self.stopped = threading.Event()
        self.poller = threading.Thread(target=self._poll, name="eve3d-progress", daemon=True)
        self.poller.start()

    def _print(self, text: str) -> None:
        with self.lock:
            print(text, file=self.stream, flush=True)

    def emit(self, record: logging.LogRecord) -> None:
        event = getattr(record, "event", None)
        try:
            if event == LogEvent.JOB_INFO:
                job = RunningJob(record.rule_name, dict(getattr(record, "wildcards", {}) or {}),
                                 [str(p) for p in getattr(record, "log", []) or []])
                self.jobs[record.jobid] = job
                self._print(f"[{self.done}/{self.total or '?'}] start   {job.title}")
            elif event == LogEvent.JOB_FINISHED:
                job = self.jobs.pop(record.job_id, None)
                if job is not None:
                    self._print(f"[{self.done + 1}/{self.total or '?'}] done    {job.title}  "
                                f"{_wall(time.monotonic() - job.started)}")
            elif event == LogEvent.PROGRESS:
                self.done, self.total = record.done, record.total
            elif event == LogEvent.JOB_ERROR:
                job = self.jobs.pop(getattr(record, "jobid", None), None)
                if job is not None:
                    self._print(f"failed  {job.title}  {_wall(time.monotonic() - job.started)}  log: "
                                f"{', '.join(job.logs) or '(none)'}")
                self._print(self.fallback.format(record))
            elif record.levelno >= logging.WARNING or event == LogEvent.ERROR:
                self._print(self.fallback.format(record))
        except Exception:  # a display problem must never stop the workflow
            self.handleError(record)

    def _poll(self) -> None:
        while not self.stopped.wait(min(1.0, self.interval)):
            now = time.monotonic()
            for job in list(self.jobs.values()):
                if now - job.shown_at < self.interval:
                    continue
                line = next(filter(None, map(latest_progress, job.logs)), None)
                if line and line != job.shown:
                    job.shown, job.shown_at = line, now
                    self._print(f"        {job.title}: {line}")

    def close(self) -> None:
        self.stopped.set()
        super().close()
