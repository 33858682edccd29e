"""The report's HTML tables: ``summary.html`` (per protocol, every scene × method of
``summary.csv`` with units in the headers, :data:`SHOWN` and :data:`DISTANCE_SHOWN`, and the
best value of each scene's methods in bold; then each method's means and, for a benchmark,
the published figures of DESIGN §4) and ``runtimes.html`` (every job's wall seconds)."""
from __future__ import annotations

import html
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from eve3d.core.layout import SUMMARY_COLUMNS

STYLE = ("<style>body{font-family:sans-serif;margin:1em}table{border-collapse:collapse;margin-bottom:1.5em}"
         "th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}th{background:#eee}"
         "td:first-child,td:nth-child(2){text-align:left;white-space:nowrap}td.best{background:#e3f1e3}"
         "tr.unranked td{color:#777;font-style:italic}</style>")


def as_number(text: str | None) -> float | None:
    try:
        return float(text) if text not in (None, "") else None
    except ValueError:
        return None


@dataclass(frozen=True)
class Shown:
    """How the report shows a summary.csv column."""

    label: str
    kind: str
    """``distance`` (in the protocol's unit, see :data:`DISTANCE_SHOWN`), ``fraction`` (0–1),
    ``percent`` (a fraction shown ×100), ``dB``, ``s`` or ``count``."""
    best: str | None = None
    """Which value of a scene's methods is best: ``low``, ``high``, ``zero`` (closest to 0);
    None: not ranked."""


SHOWN = {"tau": Shown("τ", "distance"), "accuracy": Shown("accuracy", "distance", "low"),
         "completeness": Shown("completeness", "distance", "low"), "chamfer": Shown("Chamfer", "distance", "low"),
         "precision": Shown("precision", "fraction", "high"), "recall": Shown("recall", "fraction", "high"),
         "fscore": Shown("F-score", "fraction", "high"),
         "depth_signed_error": Shown("depth signed error", "percent", "zero"),
         "depth_error": Shown("depth error", "percent", "low"), "depth_on_empty": Shown("depth on empty", "percent", "low"),
         "psnr": Shown("PSNR", "dB", "high"), "ssim": Shown("SSIM", "fraction", "high"), "scenes": Shown("scenes", "count"),
         "seconds": Shown("wall time", "s")}
"""The report's header, kind and ranking of each numeric column; the rest are shown as text."""

DISTANCE_SHOWN = {"mm": ("mm", "mm", 1.0), "m": ("mm", "mm", 1e3),
                  "scene units": ("×10⁻³", "thousandths of the scene's unit", 1e3)}
"""A protocol's distance unit (``unit`` in summary.csv) → the unit the report's headers show,
its name, and the factor to it: DTU in its mm, T&T's metres in mm (its τ are 3–30 mm), a
generated scene's own unit in thousandths (its objects span about 1)."""

BEST_NOTE = ("<p><b>Bold</b>: the best value of each column among a scene's methods (ties all marked); "
             "oracle (grey) fuses the exact depth, a ceiling, and is not ranked. Means are ranked among the methods "
             "scored on all of the protocol's scenes.</p>")


def distance_shown(unit: str | None) -> tuple[str, str, float]:
    """:data:`DISTANCE_SHOWN` of ``unit``: a unit it does not list is shown as it is."""
    return DISTANCE_SHOWN.get(unit, (unit or "", unit or "", 1.0))


def _shown(column: str, value, unit: str | None) -> str:
    """``value`` as the report prints it: 3 significant digits for distances, 3 decimals for
    fractions, 2 for percent and dB, 1 for seconds; text as it is."""
    spec, number = SHOWN.get(column), as_number(value) if isinstance(value, str) else value
    if spec is None or not isinstance(number, (int, float)):
        return "" if value is None else str(value)
    if spec.kind == "count":
        return f"{number:.0f}"
    if spec.kind == "distance":
        number *= distance_shown(unit)[2]
        return f"{number:.3g}" if abs(number) < 1000 else f"{number:.0f}"
    if spec.kind == "percent":
        return f"{100 * number:.2f}"
    return {"dB": f"{number:.2f}", "s": f"{number:.1f}"}.get(spec.kind, f"{number:.3f}")


def header(column: str, unit: str | None) -> str:
    spec = SHOWN.get(column)
    if spec is None:
        return column
    shown = {"distance": distance_shown(unit)[0], "percent": "%", "dB": "dB", "s": "s"}.get(spec.kind)
    return f"{spec.label} ({shown})" if shown else spec.label


def ranked(method: str) -> bool:
    from eve3d.core.methods import REGISTRY

    return not (method in REGISTRY and REGISTRY[method].upper_bound)


def _best_cells(rows: list[Mapping], columns: list[str], unit: str | None, contest: Callable[[Mapping], bool]
                ) -> set[tuple[int, str]]:
    """(row index, column) of the best shown value of each ranked column among the rows
    ``contest`` admits."""
    best = set()
    for column in columns:
        spec = SHOWN.get(column)
        if spec is None or spec.best is None:
            continue
        shown = {i: _shown(column, r.get(column), unit) for i, r in enumerate(rows) if contest(r)}
        entrants = [(i, float(text)) for i, text in shown.items() if text not in ("", "nan")]
        if len(entrants) < 2:
            continue
        key = {"low": lambda v: v, "high": lambda v: -v, "zero": abs}[spec.best]
        top = min(key(v) for _, v in entrants)
        best |= {(i, column) for i, v in entrants if key(v) == top}
    return best


def _table(css: str, table_id: str, columns: list[str], rows: list[Mapping], unit: str | None = None,
           best: set[tuple[int, str]] = frozenset()) -> str:
    head = "".join(f"<th>{html.escape(header(c, unit))}</th>" for c in columns)
    body = "".join(("<tr>" if "method" not in r or ranked(r["method"]) else "<tr class='unranked'>") + "".join(
        f"<td class='best'><b>{html.escape(_shown(c, r.get(c), unit))}</b></td>" if (i, c) in best
        else f"<td>{html.escape(_shown(c, r.get(c), unit))}</td>" for c in columns) + "</tr>"
        for i, r in enumerate(rows))
    return f'<table class="{css}" id="{table_id}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def means(rows: list[dict]) -> list[dict]:
    """Each method's mean of every ranked metric over the scenes that have it (rows of one
    protocol)."""
    out = []
    rows = [r for r in rows if not r.get("failed")]
    for method in sorted({r["method"] for r in rows}):
        mine = [r for r in rows if r["method"] == method]
        row = {"source": "this run (mean)", "method": method, "scenes": len(mine)}
        for metric, spec in SHOWN.items():
            values = [v for v in (as_number(r.get(metric)) for r in mine) if v is not None]
            if spec.best and values:
                row[metric] = float(np.mean(values))
        out.append(row)
    return out


def _present(columns, rows: list[Mapping]) -> list[str]:
    return [c for c in columns if any(r.get(c) not in (None, "") for r in rows)]


def protocol_tables(protocol: str, rows: list[dict], published: list[dict]) -> str:
    """One protocol's rows (scene × method, the best of each scene marked) and its means,
    with the published figures of the metrics it measures."""
    unit = next((r.get("unit") for r in rows if r.get("unit")), None)
    columns = [c for c in _present(SUMMARY_COLUMNS, rows) if c not in ("protocol", "unit", "failed", "log")]
    best = set()
    for scene in {r["scene"] for r in rows}:
        best |= _best_cells(rows, columns, unit, lambda r, s=scene: r["scene"] == s and ranked(r["method"]))
    mean_rows = means(rows)
    full = max((r["scenes"] for r in mean_rows), default=0)
    mean_best = _best_cells(mean_rows, list(SHOWN), unit, lambda r: r["scenes"] == full and ranked(r["method"]))
    mean_rows += [r for r in published if any(m in r for m in columns)]
    mean_columns = ["source", "method", "scenes"] + [c for c in _present(SHOWN, mean_rows) if c in columns]
    shown_unit = f" (distances in {distance_shown(unit)[1]})" if unit else ""
    return (f"<h3>{html.escape(protocol)} protocol{html.escape(shown_unit)}</h3>"
            f"{_table('summary', f'summary-{protocol}', columns, rows, unit, best)}"
            f"<h4>Means</h4>{_table('means', f'means-{protocol}', mean_columns, mean_rows, unit, mean_best)}")


def summary_page(rows: list[dict], published: list[dict], title: str) -> str:
    """Per protocol, the table of every scene and method with the best of each scene marked,
    and each method's means beside the published figures; then the jobs that failed."""
    scored = [r for r in rows if r.get("protocol")]
    failed = [r for r in rows if not r.get("protocol")]
    parts = [protocol_tables(p, [r for r in scored if r["protocol"] == p], published)
             for p in sorted({r["protocol"] for r in scored})]
    if failed:
        parts.append("<h3>Failed jobs</h3>" + _table("summary", "summary-failed", ["scene", "method", "failed", "log"],
                                                    failed))
    note = ("<p>Published rows: the Eve3D paper's figures (GPU, half resolution; DESIGN §4), means over all of "
            "the benchmark's scenes; this run's means are over its own scenes (`scenes`), which may be fewer.</p>"
            if published else "")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>{STYLE}</head>"
            f"<body><h2>{html.escape(title)}</h2>{''.join(parts)}{BEST_NOTE}{note}</body></html>")


def runtimes_page(rows: list[dict]) -> str:
    """The table of every job's wall seconds, and each scene's total."""
    total = [{"scene": s, "job": "all jobs", "seconds": sum(r["seconds"] for r in rows if r["scene"] == s)}
             for s in sorted({r["scene"] for r in rows})]
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Run times</title>{STYLE}</head><body>"
            f"<h2>Run times per job</h2>{_table('runtimes', 'runtimes', ['scene', 'job', 'seconds'], rows + total)}"
            f"</body></html>")
