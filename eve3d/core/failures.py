"""Failed jobs, as rows of the summary: when a workflow ends with failed jobs (``snakemake
--keep-going`` goes on with the other scenes), each scene and method without its metrics
is listed with the first line of the error of the job it waited for, and that job's log.

The failed jobs are Snakemake's own list ("Error in rule …" in its log); a job's log is
``Layout.log(scene, rule, what)``, which names its scene and, for per-method or per-backend
jobs, what it works on.
"""
from __future__ import annotations

import json
import re
from collections.abc import Iterable
from pathlib import Path

from eve3d.core.fileio import atomic_path
from eve3d.core.layout import Layout

_ERROR_BLOCK = re.compile(r"^Error in rule (\w+):\n((?:[ \t]+.*\n?)*)", re.M)
_LOG_LINE = re.compile(r"^\s+log: (\S+)", re.M)
_ERROR_LINE = re.compile(r"\berror\b|^\w*(Error|Exception)\b|Killed|Traceback", re.I)


def failed_jobs(snakemake_logs: Iterable[str | Path]) -> list[tuple[str, Path]]:
    """(rule, job log) of each job that Snakemake's logs (``onerror``'s ``log``) say failed,
    in the order they failed."""
    text = ""
    for path in snakemake_logs:
        try:
            text += Path(path).read_text(errors="replace") + "\n"  # a log cut short ends mid-line
        except OSError:
            pass
    jobs = []
    for rule, block in _ERROR_BLOCK.findall(text):
        log = _LOG_LINE.search(block)
        if log and (rule, Path(log.group(1))) not in jobs:
            jobs.append((rule, Path(log.group(1))))
    return jobs


def first_error_line(log: Path) -> str:
    """The line of a job's log that says what went wrong: eve3d's own ``error:`` line, a
    Python exception's last line, or else the log's last line."""
    try:
        lines = [line.strip() for line in re.split(r"[\r\n]+", log.read_text(errors="replace")) if line.strip()]
    except OSError:
        return f"(no log at {log})"
    if not lines:
        return "(empty log: the job was killed before it wrote anything?)"
    ours = [line for line in lines if ": error: " in line]
    if ours:
        return ours[0]
    exceptions = [line for line in lines if re.match(r"^[\w.]*(Error|Exception)\b", line)]
    return (exceptions or [line for line in lines if _ERROR_LINE.search(line)] or lines)[-1]


def failed_rows(layout: Layout, expected: Iterable[tuple[str, str]], jobs: list[tuple[str, Path]]) -> list[dict]:
    """A summary row for each expected (scene, method) without metrics whose scene has a
    failed job it may have waited for: a job of the whole scene, or of this method, or of
    a prior backend (named after no method). ``failed`` is "rule: first error line", ``log``
    the job's log."""
    expected = list(expected)
    methods = {method for _, method in expected}
    rows = []
    for scene, method in expected:
        if layout.metrics(scene, method).exists():
            continue
        for rule, log in jobs:
            if log.parent != layout.logs(scene):
                continue
            what = log.stem[len(rule) + 1:] or None
            if what in (None, method) or what not in methods:
                rows.append({"scene": scene, "method": method, "failed": f"{rule}: {first_error_line(log)}",
                             "log": str(log)})
                break
    return rows


def write_failures(path: Path, rows: list[dict]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(rows, indent=1))
