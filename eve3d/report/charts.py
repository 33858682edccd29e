"""The report's charts (matplotlib, PNG): bars per scene and method of the F-score, Chamfer
distance and held-out PSNR (``charts/{metric}.png``), in the tables' units, and every job's
wall seconds (``charts/runtimes.png``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eve3d.report.tables import SHOWN, as_number, distance_shown, header

METRICS_CHARTED = ("fscore", "chamfer", "psnr")
"""summary.csv columns drawn as bar charts."""


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, out: Path, **options) -> None:
    """``fig`` as a PNG at ``out``, written atomically, then closed."""
    from eve3d.core.fileio import atomic_path

    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", **options)
    pyplot().close(fig)


def bar_chart(rows: list[dict], metric: str, out: Path) -> bool:
    """Bars of ``metric`` per scene, one colour per method, in the unit the tables show
    (rows of one distance unit); False when no row has it."""
    have = [r for r in rows if as_number(r.get(metric)) is not None]
    if not have:
        return False
    unit = have[0].get("unit") or None
    scale = distance_shown(unit)[2] if SHOWN[metric].kind == "distance" else 1.0
    scenes = sorted({r["scene"] for r in have})
    methods = sorted({r["method"] for r in have})
    width = 0.8 / len(methods)
    fig, ax = pyplot().subplots(figsize=(max(4.0, 1.2 * len(scenes) * max(1, len(methods)) / 2), 3.2))
    for k, method in enumerate(methods):
        values = {r["scene"]: scale * as_number(r[metric]) for r in have if r["method"] == method}
        xs = [i + (k - (len(methods) - 1) / 2) * width for i, s in enumerate(scenes) if s in values]
        ax.bar(xs, [values[s] for s in scenes if s in values], width, label=method)
    ax.set_xticks(range(len(scenes)), scenes, rotation=30 if len(scenes) > 4 else 0)
    ax.set_ylabel(f"{header(metric, unit)}, {SHOWN[metric].best}er is better")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out, dpi=100)
    return True


def charts(rows: list[dict], folder: Path) -> list[Path]:
    """:func:`bar_chart` of each of :data:`METRICS_CHARTED`, one chart per distance unit
    (``{metric}.png``, or ``{metric}-{protocol}.png`` when protocols of several units ran)."""
    written = []
    units = {r.get("unit") or None for r in rows if r.get("protocol")}
    for metric in METRICS_CHARTED:
        if SHOWN[metric].kind == "distance" and len(units) > 1:
            groups = {f"{metric}-{p}": [r for r in rows if r.get("protocol") == p]
                      for p in sorted({r["protocol"] for r in rows if r.get("protocol")})}
        else:
            groups = {metric: rows}
        for name, group in groups.items():
            if bar_chart(group, metric, folder / f"{name}.png"):
                written.append(folder / f"{name}.png")
    return written


def runtimes_chart(rows: list[dict], out: Path) -> None:
    """One horizontal bar per scene, split into its jobs."""
    scenes = sorted({r["scene"] for r in rows}) or ["(no benchmark files)"]
    jobs = sorted({r["job"] for r in rows})
    fig, ax = pyplot().subplots(figsize=(8, 1.2 + max(0.45 * len(scenes), 0.16 * len(jobs))))
    left = np.zeros(len(scenes))
    for job in jobs:
        seconds = np.array([sum(r["seconds"] for r in rows if r["scene"] == s and r["job"] == job) for s in scenes])
        ax.barh(scenes, seconds, left=left, label=job)
        left += seconds
    ax.set_xlabel("wall seconds")
    if jobs:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    save_figure(fig, out, dpi=100, bbox_inches="tight")
