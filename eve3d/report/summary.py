"""The summary table (``summary.csv``): the metrics records of every scene and method
gathered into rows, the training stages' held-out views beside them (``summary_views.csv``),
written and printed. ``summary.csv`` keeps the numbers as the protocols wrote them (distances
in the protocol's ``unit``); only the report's pages round and convert them."""
from __future__ import annotations

import csv
import json
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path
from eve3d.core.layout import (EVALUATION, METRICS_FILE, RECORD, SUMMARY_COLUMNS, TRAIN_METRICS_FILE, TRAINING,
                               VIEW_COLUMNS, format_table, locate)


def gather(metrics: list[Path], failed: Path | None = None) -> tuple[list[dict], list[dict]]:
    """The rows of the ``metrics`` records: the evaluations' (scene × method, with the rows
    of the jobs that failed, listed in ``failed``) and the training stages' held-out views
    (scene × stage), each sorted."""
    rows, view_rows = [], []
    for path in map(Path, metrics):
        try:
            m = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Eve3dError(f"{path}: cannot read metrics ({e})") from None
        if not isinstance(m, dict) or m.get(RECORD) not in (EVALUATION, TRAINING):
            found = f"{RECORD!r} is {m[RECORD]!r}" if isinstance(m, dict) and RECORD in m else f"no {RECORD!r} field"
            raise Eve3dError(f"{path}: {found}; a metrics record says what it holds: {RECORD!r}: {EVALUATION!r} "
                             f"({METRICS_FILE}, written by eve3d evaluate) or {TRAINING!r} ({TRAIN_METRICS_FILE}, "
                             f"written by pretrain and joint); rerun the stage that wrote it (snakemake --forcerun evaluate)")
        scene, stage = locate(path)  # names the row when the record does not
        if m[RECORD] == TRAINING:  # a training stage's novel-view metrics
            view_rows.append({"scene": scene, "stage": stage, **m["held_out"]})
            continue
        m.setdefault("scene", scene)
        m.setdefault("method", stage)
        rows.append(m)
    if failed:  # rows of a workflow that ended with failed jobs
        try:
            rows += json.loads(Path(failed).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Eve3dError(f"{failed}: cannot read the failed rows ({e})") from None
    rows.sort(key=lambda r: (r["scene"], r["method"]))
    view_rows.sort(key=lambda r: (r["scene"], r["stage"]))
    return rows, view_rows


def read_rows(summary: Path) -> list[dict]:
    with open(summary, newline="") as f:
        return list(csv.DictReader(f))


def views_table(summary: Path) -> Path:
    """``summary_views.csv`` beside ``summary.csv``: the training stages' held-out views."""
    return summary.with_name(f"{summary.stem}_views.csv")


def print_tables(rows: list[dict], view_rows: list[dict]) -> None:
    """The summary table, and the training stages' held-out views below it."""
    print(format_table(rows, SUMMARY_COLUMNS))
    if view_rows:
        print("\nheld-out views of the training stages (at the training resolution)")
        print(format_table(view_rows, VIEW_COLUMNS))


def write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    """``rows`` as a CSV of ``columns`` at ``path``, written atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
