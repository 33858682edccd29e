"""The summary table (``eve3d summary``, :func:`run_summary`) and the report's pages
(``eve3d report``, :func:`run_report`): what Snakemake's ``--report`` gathers into one
self-contained HTML file, from the outputs the ``report`` rule marks with ``report(...)``.

* ``summary.html`` and ``runtimes.html``: the tables (:mod:`eve3d.report.tables`), from
  ``summary.csv`` (:mod:`eve3d.report.summary`) and Snakemake's ``benchmark:`` files;
* ``charts/{metric}.png`` and ``charts/runtimes.png``: the bar charts (:mod:`eve3d.report.charts`);
* ``scenes/{scene}/{method}.png``: a sheet of maps per scene and method (:mod:`eve3d.report.sheets`);
* ``scenes3d/{scene}.html``: each scene in 3D (:mod:`eve3d.report.views3d`).
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from eve3d.core.layout import SUMMARY_COLUMNS, VIEW_COLUMNS, Layout, benchmark_seconds
from eve3d.core.settings_stereo import StereoSettings
from eve3d.core.timing import phase
from eve3d.report.charts import charts, runtimes_chart
from eve3d.report.sheets import scene_panels, scene_sheet
from eve3d.report.summary import gather, print_tables, read_rows, views_table, write_csv
from eve3d.report.tables import as_number, distance_shown, ranked, runtimes_page, summary_page


def read_runtimes(layout: Layout) -> list[dict]:
    """Wall seconds of every job with a Snakemake ``benchmark:`` file (first column ``s``)."""
    rows = []
    for path in sorted(layout.benchmarks().glob("*/*.tsv")):
        seconds = benchmark_seconds(path)
        if seconds is not None:
            rows.append({"scene": path.parent.name, "job": path.stem, "seconds": seconds})
    return rows


def write_report(layout: Layout, out: Path, datasets: Mapping[str, Path], backend: str,
                 benchmark: str | None = None, ground_truth: Mapping[str, Path] | None = None) -> list[Path]:
    """Every page of the module docstring under ``out``; the files written. ``ground_truth``:
    each scene's GT surface (mesh or point cloud), shown in its 3D view."""
    from eve3d.core.datasets import BENCHMARKS
    from eve3d.core.fileio import atomic_path
    from eve3d.core.io import load_scene
    from eve3d.report.views3d import scene_view

    rows = read_rows(layout.summary())
    published = BENCHMARKS[benchmark].published_rows() if benchmark else []
    title = f"{BENCHMARKS[benchmark].title}: results" if benchmark else "eve3d results"
    runtimes = read_runtimes(layout)
    written = []
    with phase("tables"):
        for name, text in (("summary.html", summary_page(rows, published, title)),
                           ("runtimes.html", runtimes_page(runtimes))):
            with atomic_path(out / name) as tmp:
                tmp.write_text(text)
            written.append(out / name)
    with phase("charts"):
        written += charts(rows, out / "charts")
        runtimes_chart(runtimes, out / "charts" / "runtimes.png")
        written.append(out / "charts" / "runtimes.png")
    for folder in ("scenes", "scenes3d"):  # the rule's outputs, even where no scene has a page
        (out / folder).mkdir(parents=True, exist_ok=True)
    for scene in sorted({r["scene"] for r in rows}):
        loaded = load_scene(datasets[scene], check_images=False) if scene in datasets else None
        cameras = loaded.cameras if loaded else []
        # the GT surface: the config's (--gt), or the one the dataset's layout names (T&T's points)
        gt = (ground_truth or {}).get(scene) or (Path(loaded.extras["gt_points"]) if loaded and
                                                 "gt_points" in (loaded.extras or {}) else None)
        photo = cameras[0].image_path if cameras else None
        methods = sorted((r["method"] for r in rows if r["scene"] == scene), key=lambda m: (not ranked(m), m))
        with phase("scene sheets"):
            for method in methods:
                panels = scene_panels(layout, scene, method, photo, backend)
                if panels:
                    path = out / "scenes" / scene / f"{method}.png"
                    scene_sheet(panels, f"{scene} · {method}", path)
                    written.append(path)
        unit = next((r.get("unit") for r in rows if r["scene"] == scene and r.get("unit")), None)
        label, _, factor = distance_shown(unit)
        with phase("3D views"):
            if scene_view(layout, scene, methods, (label, factor), gt, cameras, out / "scenes3d" / f"{scene}.html"):
                written.append(out / "scenes3d" / f"{scene}.html")
    return written


def run_summary(metrics: list[Path], *, out: Path, failed: Path | None = None) -> None:
    """The ``summary`` rule: the ``metrics`` records gathered into ``out`` (summary.csv) and
    the training stages' held-out views into ``summary_views.csv`` beside it, each printed;
    ``failed`` holds the rows of jobs that failed (``eve3d.core.failures``)."""
    rows, view_rows = gather(metrics, failed)
    out = Path(out)
    write_csv(out, SUMMARY_COLUMNS, rows)
    if view_rows:
        write_csv(views_table(out), VIEW_COLUMNS, view_rows)
    print_tables(rows, view_rows)


def run_show_summary(*, summary: Path) -> None:
    """``eve3d summary --show``: the tables of a written ``summary.csv`` (and the views' beside
    it), as the summary printed them, without gathering anything (the workflow prints its
    table last this way)."""
    from eve3d.core.errors import Eve3dError

    def typed(row: dict) -> dict:  # numbers as numbers, empty cells absent: as the records were
        return {k: (as_number(v) if as_number(v) is not None else v) for k, v in row.items() if v not in (None, "")}

    summary = Path(summary)
    if not summary.is_file():
        raise Eve3dError(f"{summary}: no summary table (the workflow's summary rule writes it)")
    views = views_table(summary)
    print_tables([typed(r) for r in read_rows(summary)], [typed(r) for r in read_rows(views)] if views.is_file() else [])


def run_report(settings: StereoSettings, benchmark: str | None = None, *, results: Path, out: Path,
               datasets: Mapping[str, Path], ground_truth: Mapping[str, Path] | None = None) -> None:
    """The ``report_pages`` rule: the pages of ``results`` into ``out`` (``settings.backend``:
    the priors shown; ``benchmark``: its published figures join the means; ``ground_truth``:
    each scene's GT surface for its 3D view)."""
    written = write_report(Layout(results), Path(out), datasets, settings.backend, benchmark,
                           {scene: Path(path) for scene, path in (ground_truth or {}).items()})
    print(f"wrote {len(written)} report pages to {out}")
