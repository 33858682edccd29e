"""``eve3d profile``: where a whole workflow run's wall time went, job by job and inside each
job, from what the run left behind: Snakemake's log of the run (when each job started and
finished, its threads, its log file) and the ``timing:`` line each stage prints at its end
(``eve3d.core.timing``).

Snakemake stamps its log to the second, so a job's start and end, and the time between jobs,
are known to about a second; the phases inside a job to a millisecond.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from eve3d.core import timing
from eve3d.core.errors import Eve3dError

_STAMP = re.compile(r"^\[(\w{3} \w{3} +\d+ \d\d:\d\d:\d\d \d{4})\]$")
_RULE = re.compile(r"^(?:local)?rule (\w+):$", re.MULTILINE)
_FIELD = re.compile(r"^    (\w+): (.*)$")
_FINISHED = re.compile(r"^Finished jobid: (\d+)")
_WORKDIR = re.compile(r"^  Working directory: (.+)$")
_ELAPSED = re.compile(r"^Elapsed time: (\d+):(\d\d):(\d\d(?:\.\d+)?)")
TOP_PHASES = 4
"""Phases shown per job in the table, longest first (the rest are added into ``rest``)."""


@dataclass
class Job:
    """One job of the run, as Snakemake's log and the job's own log describe it."""

    rule: str
    started: float
    """Seconds from the run's start."""
    wildcards: str = ""
    jobid: int = -1
    threads: int = 1
    priority: float = 0
    """Snakemake's priority of the job (the longest chain's jobs start first)."""
    log: str = ""
    benchmark: str = ""
    ended: float | None = None
    cpu: float | None = None
    """CPU seconds of the job's processes (Snakemake's benchmark file)."""
    phases: dict[str, float] = field(default_factory=dict)
    """Seconds per phase from the job's ``timing:`` line (empty when it printed none)."""

    @property
    def title(self) -> str:
        values = [v.split("=", 1)[-1] for v in self.wildcards.split(", ") if v]
        return " ".join([self.rule.replace("_", "-"), *values])

    @property
    def wall(self) -> float | None:
        return None if self.ended is None else self.ended - self.started


@dataclass
class Run:
    """A workflow run: its jobs, its wall time and the cores it was given."""

    log: Path
    jobs: list[Job]
    wall: float
    cores: int


GATHERING_RULES = ("all", "summary", "report_pages")
"""Rules that only gather results: a run of these alone (a rerun of ``summary`` after a
change of its code) is not the run a profile is asked for."""


def latest_log(workdir: Path) -> Path:
    """The newest Snakemake log in ``workdir`` (``.snakemake/log/``) of a run that ran a stage."""
    folder = workdir / ".snakemake" / "log"
    for log in sorted(folder.glob("*.snakemake.log"), reverse=True):
        rules = set(_RULE.findall(log.read_text(errors="replace")))
        if rules - set(GATHERING_RULES):
            return log
    raise Eve3dError(f"{folder}: no Snakemake log of a run that ran a stage; run the workflow first, "
                     "or give --log FILE")


def read_run(log: Path) -> Run:
    """The jobs of the Snakemake run that wrote ``log``, with each job's phases read from its
    own log file (paths relative to the run's working directory)."""
    try:
        lines = log.read_text(errors="replace").splitlines()
    except OSError as e:
        raise Eve3dError(f"{log}: cannot read the Snakemake log ({e.strerror})") from None
    jobs = log_jobs(lines)
    if not jobs:
        raise Eve3dError(f"{log}: no job in this Snakemake log (a dry run, or nothing to do)")
    workdir, cores, elapsed = log.parent.parent.parent, 1, None
    for line in lines:
        if m := _WORKDIR.match(line):
            workdir = Path(m.group(1))
        elif line.startswith("Provided cores: "):  # "Provided cores: 2", at one "1 (use --cores to define parallelism)"
            cores = int(line.split()[2])
        elif m := _ELAPSED.match(line):
            elapsed = int(m.group(1)) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
    for job in jobs:
        job.phases = job_phases(workdir / job.log) if job.log else {}
        job.cpu = benchmark_cpu(workdir / job.benchmark) if job.benchmark else None
    ends = [j.ended for j in jobs if j.ended is not None]
    return Run(log, jobs, elapsed or max(ends, default=max(j.started for j in jobs)), cores)


def log_jobs(lines: list[str]) -> list[Job]:
    """The jobs that Snakemake's log of a run, or a dry run's output, lists (the target ``all``
    left out: it does no work), by start: rule, wildcards, threads, log and benchmark files,
    and from a run's time stamps when each started and finished (seconds from the first)."""
    first: datetime | None = None
    now = 0.0
    jobs: dict[int, Job] = {}
    current: Job | None = None
    for line in lines:
        if m := _STAMP.match(line):
            stamp = datetime.strptime(" ".join(m.group(1).split()), "%a %b %d %H:%M:%S %Y")
            first = first or stamp
            now = (stamp - first).total_seconds()
            current = None
        elif m := _RULE.match(line):
            current = Job(m.group(1), now)
        elif current is not None and (m := _FIELD.match(line)):
            key, value = m.groups()
            if key == "jobid":
                current.jobid = int(value)
                jobs[current.jobid] = current
            elif key == "wildcards":
                current.wildcards = value
            elif key in ("log", "benchmark"):
                setattr(current, key, value.split(", ")[0])
            elif key in ("threads", "priority"):
                setattr(current, key, type(getattr(current, key))(value))
        elif m := _FINISHED.match(line):
            if (job := jobs.get(int(m.group(1)))) is not None:
                job.ended = now
    return sorted((j for j in jobs.values() if j.rule != "all"), key=lambda j: (j.started, j.jobid))


def job_phases(log: Path) -> dict[str, float]:
    """The last ``timing:`` line of a job's log (empty when none: an older eve3d, or a job
    that failed)."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return {}
    for line in reversed(re.split(r"[\r\n]+", text)):
        if (phases := timing.parse(line)) is not None:
            return phases
    return {}


def benchmark_cpu(path: Path) -> float | None:
    """The CPU seconds in a Snakemake benchmark file (None when it has none)."""
    try:
        header, values = path.read_text().splitlines()[:2]
        return float(dict(zip(header.split("\t"), values.split("\t")))["cpu_time"])
    except (OSError, ValueError, KeyError):
        return None


def between_jobs(run: Run) -> float:
    """Seconds of the run in which no job ran: Snakemake's own time (building the DAG,
    checking outputs, choosing the next job), known to about a second a job."""
    spans = sorted((j.started, j.ended) for j in run.jobs if j.ended is not None)
    busy, reach = 0.0, 0.0
    for start, end in spans:
        start = max(start, reach)
        if end > start:
            busy += end - start
            reach = end
    return max(run.wall - busy, 0.0)


def profile_rows(run: Run) -> list[dict]:
    """One row per job: start, wall, threads, start-up, the longest phases and the rest."""
    rows = []
    for job in run.jobs:
        phases = {k: v for k, v in job.phases.items() if k not in ("total", timing.START_UP)}
        top = sorted(phases.items(), key=lambda kv: -kv[1])[:TOP_PHASES]
        rest = sum(phases.values()) - sum(v for _, v in top)
        rows.append({"job": job.title, "threads": job.threads, "start_s": job.started, "wall_s": job.wall,
                     "cores_used": None if job.cpu is None or not job.wall else job.cpu / job.wall,
                     "start_up_s": job.phases.get(timing.START_UP),
                     "phases": ", ".join(f"{k} {v:.1f}" for k, v in top) + (f", rest {rest:.1f}" if rest >= 0.05 else "")})
    return rows


def phase_totals(run: Run) -> dict[str, float]:
    """Seconds per phase added over every job, longest first (a job's ``other`` included)."""
    totals: dict[str, float] = {}
    for job in run.jobs:
        for k, v in job.phases.items():
            if k != "total":
                totals[k] = totals.get(k, 0.0) + v
    return dict(sorted(totals.items(), key=lambda kv: -kv[1]))


def _seconds(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}" if v < 100 else f"{v:.0f}"


def format_profile(run: Run, markdown: bool = False) -> str:
    """The profile as text: the jobs, the phases over all jobs, and the run's totals."""
    jobs = [[r["job"], str(r["threads"]), "-" if r["cores_used"] is None else f"{r['cores_used']:.2f}",
             _seconds(r["start_s"]), _seconds(r["wall_s"]), _seconds(r["start_up_s"]), r["phases"] or "-"]
            for r in profile_rows(run)]
    totals = phase_totals(run)
    job_seconds = sum(j.wall or 0 for j in run.jobs)
    cpu = sum(j.cpu or 0 for j in run.jobs)
    summary = [["run's wall time", _seconds(run.wall)],
               ["jobs' wall time added up", _seconds(job_seconds)],
               ["no job running (Snakemake between jobs)", _seconds(between_jobs(run))],
               [f"CPU time of the jobs / ({run.cores} cores × the run's wall time)",
                f"{cpu / max(run.cores * run.wall, 1e-9):.0%}"]]
    parts = [f"profile of {run.log}",
             _table(["job", "threads", "cores used", "start s", "wall s", "start-up s", "longest phases (s)"], jobs,
                    markdown),
             _table(["phase, over all jobs", "s"], [[k, _seconds(v)] for k, v in totals.items()], markdown),
             _table(["run", ""], summary, markdown)]
    return "\n\n".join(parts)


def _table(header: list[str], rows: list[list[str]], markdown: bool) -> str:
    if markdown:
        return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                         + ["| " + " | ".join(r) + " |" for r in rows])
    widths = [max(len(x) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in [header, *rows]]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths)] + lines[1:])


def run_profile(*, log: Path | None = None, workdir: Path = Path("."), markdown: bool = False) -> None:
    """``eve3d profile``: print the profile of the run that wrote ``log`` (default: the
    newest run in ``workdir``)."""
    print(format_profile(read_run(Path(log) if log else latest_log(Path(workdir))), markdown))
