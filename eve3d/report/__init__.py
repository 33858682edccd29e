"""The summary table (``eve3d summary``, :func:`run_summary`) and the report's pages
(``eve3d report``, :func:`run`): what Snakemake's ``--report`` gathers into one
self-contained HTML file, from the outputs the ``report`` rule marks with ``report(...)``.

* ``summary.html``: per protocol, every scene × method of ``summary.csv`` (tables
  ``.summary``), units in the headers (:data:`SHOWN`, :data:`DISTANCE_SHOWN`) and the best
  value of each scene's methods in bold; then each method's means and, for a benchmark, the
  published figures of DESIGN §4 (tables ``.means``).
* ``charts/{metric}.png``: bar charts per scene and method of the F-score, Chamfer distance
  and held-out PSNR, those the rows have (matplotlib), in the tables' units.
* ``scenes3d/{scene}.html``: each scene in 3D (:mod:`eve3d.report.views3d`).
* ``scenes/{scene}/{method}.png``: one sheet per scene and method: the photo of its first
  view, the stereo prior, the refined prior D̂ (methods that learn it), the rendered depth
  and normals, the shaded mesh, and the precision / recall error maps (the points scored,
  coloured by distance, seen along z) or the held-out renders beside their photos.
* ``runtimes.html`` and ``charts/runtimes.png``: wall seconds of every job, from Snakemake's
  ``benchmark:`` files.

``summary.csv`` keeps the numbers as the protocols wrote them (distances in the protocol's
``unit``); only the pages round and convert them.
"""
from __future__ import annotations

import csv
import html
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eve3d.core.layout import HELD_OUT_DIR, MESH_VIEWS_DIR, SUMMARY_COLUMNS, Layout, benchmark_seconds
from eve3d.core.settings import StereoSettings
from eve3d.core.timing import phase

METRICS_CHARTED = ("fscore", "chamfer", "psnr")
"""summary.csv columns drawn as bar charts."""
STYLE = ("<style>body{font-family:sans-serif;margin:1em}table{border-collapse:collapse;margin-bottom:1.5em}"
         "th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}th{background:#eee}"
         "td:first-child,td:nth-child(2){text-align:left;white-space:nowrap}td.best{background:#e3f1e3}"
         "tr.unranked td{color:#777;font-style:italic}</style>")


def read_rows(summary: Path) -> list[dict]:
    with open(summary, newline="") as f:
        return list(csv.DictReader(f))


def _number(text: str | None) -> float | None:
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
    spec, number = SHOWN.get(column), _number(value) if isinstance(value, str) else value
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


def _header(column: str, unit: str | None) -> str:
    spec = SHOWN.get(column)
    if spec is None:
        return column
    shown = {"distance": distance_shown(unit)[0], "percent": "%", "dB": "dB", "s": "s"}.get(spec.kind)
    return f"{spec.label} ({shown})" if shown else spec.label


def _ranked(method: str) -> bool:
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
    head = "".join(f"<th>{html.escape(_header(c, unit))}</th>" for c in columns)
    body = "".join(("<tr>" if "method" not in r or _ranked(r["method"]) else "<tr class='unranked'>") + "".join(
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
            values = [v for v in (_number(r.get(metric)) for r in mine) if v is not None]
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
        best |= _best_cells(rows, columns, unit, lambda r, s=scene: r["scene"] == s and _ranked(r["method"]))
    mean_rows = means(rows)
    full = max((r["scenes"] for r in mean_rows), default=0)
    mean_best = _best_cells(mean_rows, list(SHOWN), unit, lambda r: r["scenes"] == full and _ranked(r["method"]))
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


def _pyplot():
    """matplotlib's pyplot on the Agg backend (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: Path, **options) -> None:
    """``fig`` as a PNG at ``out``, written atomically, then closed."""
    from eve3d.core.fileio import atomic_path

    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", **options)
    _pyplot().close(fig)


def bar_chart(rows: list[dict], metric: str, out: Path) -> bool:
    """Bars of ``metric`` per scene, one colour per method, in the unit the tables show
    (rows of one distance unit); False when no row has it."""
    have = [r for r in rows if _number(r.get(metric)) is not None]
    if not have:
        return False
    unit = have[0].get("unit") or None
    scale = distance_shown(unit)[2] if SHOWN[metric].kind == "distance" else 1.0
    scenes = sorted({r["scene"] for r in have})
    methods = sorted({r["method"] for r in have})
    width = 0.8 / len(methods)
    fig, ax = _pyplot().subplots(figsize=(max(4.0, 1.2 * len(scenes) * max(1, len(methods)) / 2), 3.2))
    for k, method in enumerate(methods):
        values = {r["scene"]: scale * _number(r[metric]) for r in have if r["method"] == method}
        xs = [i + (k - (len(methods) - 1) / 2) * width for i, s in enumerate(scenes) if s in values]
        ax.bar(xs, [values[s] for s in scenes if s in values], width, label=method)
    ax.set_xticks(range(len(scenes)), scenes, rotation=30 if len(scenes) > 4 else 0)
    ax.set_ylabel(f"{_header(metric, unit)}, {SHOWN[metric].best}er is better")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, out, dpi=100)
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


def read_runtimes(layout: Layout) -> list[dict]:
    """Wall seconds of every job with a Snakemake ``benchmark:`` file (first column ``s``)."""
    rows = []
    for path in sorted(layout.benchmarks().glob("*/*.tsv")):
        seconds = benchmark_seconds(path)
        if seconds is not None:
            rows.append({"scene": path.parent.name, "job": path.stem, "seconds": seconds})
    return rows


def runtimes_page(rows: list[dict]) -> str:
    """The table of every job's wall seconds, and each scene's total."""
    total = [{"scene": s, "job": "all jobs", "seconds": sum(r["seconds"] for r in rows if r["scene"] == s)}
             for s in sorted({r["scene"] for r in rows})]
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Run times</title>{STYLE}</head><body>"
            f"<h2>Run times per job</h2>{_table('runtimes', 'runtimes', ['scene', 'job', 'seconds'], rows + total)}"
            f"</body></html>")


def runtimes_chart(rows: list[dict], out: Path) -> None:
    """One horizontal bar per scene, split into its jobs."""
    scenes = sorted({r["scene"] for r in rows}) or ["(no benchmark files)"]
    jobs = sorted({r["job"] for r in rows})
    fig, ax = _pyplot().subplots(figsize=(8, 1.2 + max(0.45 * len(scenes), 0.16 * len(jobs))))
    left = np.zeros(len(scenes))
    for job in jobs:
        seconds = np.array([sum(r["seconds"] for r in rows if r["scene"] == s and r["job"] == job) for s in scenes])
        ax.barh(scenes, seconds, left=left, label=job)
        left += seconds
    ax.set_xlabel("wall seconds")
    if jobs:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    _save(fig, out, dpi=100, bbox_inches="tight")


HELD_OUT_SHOWN = 8
"""Held-out views a scene sheet shows at most (render beside photo), in view order."""
ERROR_MAP_PIXELS = 240
"""Longest side, in pixels, of an error map's picture on a scene sheet."""
ERROR_MAP_BACKGROUND = (0.8, 0.8, 0.88)
"""Where no scored point falls: a light blue grey, off the white–black scale."""


def _error_map(path: Path) -> np.ndarray | None:
    """An error map (``precision.ply`` / ``recall.ply``: points coloured by distance, already
    thinned by ``evaluate.common.write_error_maps``) seen from above, along −z: an RGB image
    in which each pixel takes the colour of its highest point; None when the map is empty.
    Drawn as an image rather than as 200,000 matplotlib markers, which are slow to draw
    (docs/results.md, "Figures behind the code's choices")."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    points, colours = np.asarray(cloud.points), np.asarray(cloud.colors)
    if not len(points):
        return None
    low, extent = points[:, :2].min(0), np.ptp(points[:, :2], axis=0)
    scale = (ERROR_MAP_PIXELS - 1) / max(extent.max(), 1e-12)
    width, height = (np.floor(extent * scale).astype(int) + 1)
    col, row = np.floor((points[:, :2] - low) * scale).astype(int).T
    row = height - 1 - row  # +y up, as on a plot
    pixel = row * width + col
    order = np.lexsort((-points[:, 2], pixel))  # by pixel, the highest point first
    first = order[np.r_[True, pixel[order][1:] != pixel[order][:-1]]]
    image = np.empty((height * width, 3))
    image[:] = ERROR_MAP_BACKGROUND
    image[pixel[first]] = colours[first]
    return image.reshape(height, width, 3)


def scene_panels(layout: Layout, scene: str, method: str, photo: Path | None, backend: str) -> list[tuple[str, object]]:
    """(title, image path or error-map image) of one scene and method, those that exist."""
    folder = layout.method(scene, method)
    candidates = []
    if photo is not None:  # the maps of the photo's view
        view = photo.stem
        candidates = [("photo", photo),
                      ("stereo prior D* (the scene's)", layout.priors(scene, backend) / f"{view}.depth.png"),
                      ("refined prior D̂", layout.learned_priors(scene, method) / f"{view}.depth.png"),
                      ("rendered depth", layout.depth(scene, method) / f"{view}.depth.png"),
                      ("rendered normals", layout.depth(scene, method) / f"{view}.normal.png")]
    candidates.append(("shaded mesh", folder / MESH_VIEWS_DIR / "overview.png"))
    panels = [(title, path) for title, path in candidates if path.is_file()]
    held = sorted((folder / HELD_OUT_DIR).glob("*.png"))
    panels += [(f"held out {path.stem}: render | photo", path) for path in held[:HELD_OUT_SHOWN]]
    for name in ("precision", "recall"):
        if (folder / f"{name}.ply").is_file():
            image = _error_map(folder / f"{name}.ply")
            if image is not None:
                panels.append((f"{name} errors (white 0, black ≥ 3τ; DTU 10 mm), along z", image))
    return panels


def scene_sheet(panels: list[tuple[str, object]], title: str, out: Path) -> None:
    """The panels side by side, two rows when there are many."""
    from eve3d.core.fileio import read_image

    cols = min(4, max(1, len(panels)))
    rows = max(1, -(-len(panels) // cols))
    fig, axes = _pyplot().subplots(rows, cols, figsize=(3.2 * cols, 2.7 * rows + 0.4), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (name, item) in zip(axes.ravel(), panels):
        ax.imshow(item if isinstance(item, np.ndarray) else read_image(Path(item)))
        ax.set_title(name, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, out, dpi=90)


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
        methods = sorted((r["method"] for r in rows if r["scene"] == scene), key=lambda m: (not _ranked(m), m))
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
    import json

    from eve3d.core.errors import Eve3dError
    from eve3d.core.layout import EVALUATION, METRICS_FILE, RECORD, TRAIN_METRICS_FILE, TRAINING, VIEW_COLUMNS, locate

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
    out = Path(out)
    _write_csv(out, SUMMARY_COLUMNS, rows)
    if view_rows:
        _write_csv(views_table(out), VIEW_COLUMNS, view_rows)
    print_tables(rows, view_rows)


def views_table(summary: Path) -> Path:
    """``summary_views.csv`` beside ``summary.csv``: the training stages' held-out views."""
    return summary.with_name(f"{summary.stem}_views.csv")


def print_tables(rows: list[dict], view_rows: list[dict]) -> None:
    """The summary table, and the training stages' held-out views below it."""
    from eve3d.core.layout import VIEW_COLUMNS, format_table

    print(format_table(rows, SUMMARY_COLUMNS))
    if view_rows:
        print("\nheld-out views of the training stages (at the training resolution)")
        print(format_table(view_rows, VIEW_COLUMNS))


def run_show_summary(*, summary: Path) -> None:
    """``eve3d summary --show``: the tables of a written ``summary.csv`` (and the views' beside
    it), as the summary printed them, without gathering anything (``make demo`` prints its
    table last this way)."""
    from eve3d.core.errors import Eve3dError

    def typed(row: dict) -> dict:  # numbers as numbers, empty cells absent: as the records were
        return {k: (_number(v) if _number(v) is not None else v) for k, v in row.items() if v not in (None, "")}

    summary = Path(summary)
    if not summary.is_file():
        raise Eve3dError(f"{summary}: no summary table (the workflow's summary rule writes it)")
    views = views_table(summary)
    print_tables([typed(r) for r in read_rows(summary)], [typed(r) for r in read_rows(views)] if views.is_file() else [])


def _write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    from eve3d.core.fileio import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)


def run_report(settings: StereoSettings, benchmark: str | None = None, *, results: Path, out: Path,
               datasets: Mapping[str, Path], ground_truth: Mapping[str, Path] | None = None) -> None:
    """The ``report_pages`` rule: the pages of ``results`` into ``out`` (``settings.backend``:
    the priors shown; ``benchmark``: its published figures join the means; ``ground_truth``:
    each scene's GT surface for its 3D view)."""
    written = write_report(Layout(results), Path(out), datasets, settings.backend, benchmark,
                           {scene: Path(path) for scene, path in (ground_truth or {}).items()})
    print(f"wrote {len(written)} report pages to {out}")

