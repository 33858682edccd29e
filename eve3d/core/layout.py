"""The results tree, declared once: where every artefact of the workflow lies.

The rules (outputs, logs, benchmarks), the workflow's input functions, ``eve3d summary``
and ``eve3d bench methods`` all ask a :class:`Layout` for their paths, and the stages
that write fixed names inside their output folder use the file-name constants below::

    {results}/summary.csv                     all scenes × methods (summary_views.csv beside it)
    {results}/report/                         the report's pages; {results}/report.html (snakemake --report)
    {results}/logs/{scene}/{rule}[_{what}].log
    {results}/benchmarks/{scene}/{rule}[_{what}].tsv
    {results}/.cores/{pid}                    the training jobs running side by side (eve3d.core.cores)
    {results}/{scene}/input/                  generated synthetic dataset
    {results}/{scene}/ground_truth_check.json the ground truth lines up (dtu, tnt; before training)
    {results}/{scene}/sfm/                    posed dataset of an image-only one
    {results}/{scene}/stereo/                 virtual right views
    {results}/{scene}/priors/{backend}/       depth priors
    {results}/{scene}/pretrain/               point_cloud.ply, environment.npz, tone_curve.json, train_metrics.json
    {results}/{scene}/{method}/               point_cloud.ply, environment.npz, depth/, priors/, train_metrics.json,
                                              mesh.ply, mesh_views/, metrics.json, held_out/

A wildcard in place of a name gives the Snakemake pattern:
``Layout("results").mesh("{scene}", "{method}")`` is ``results/{scene}/{method}/mesh.ply``.

Two kinds of metrics record, told apart by their ``record`` field: ``metrics.json`` holds
an evaluation (``"record": "evaluation"``, written by ``eve3d evaluate``), and
``train_metrics.json`` a training stage's own scores (``"record": "training"``: pretrain
and joint). No torch here: the workflow plans with it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MODEL_FILE = "point_cloud.ply"
"""A training stage's Gaussians (3DGS PLY)."""
ENVIRONMENT_FILE = "environment.npz"
"""Beside a trained model's PLY: its environment at infinity (``eve3d.gaussians.environment``),
with ``environment.png``, its map, beside it."""
TONE_FILE = "tone_curve.json"
"""Written by the pretrain beside its PLY: the (256,) curve its photos were fitted through."""
TRAIN_METRICS_FILE = "train_metrics.json"
"""A training stage's record (``"record": "training"``)."""
DEPTH_DIR = "depth"
"""A trained method's rendered depth maps, which its mesh fuses."""
PRIORS_DIR = "priors"
"""Depth priors: per scene ``priors/{backend}``; in a learnable method's folder its final D̂."""
PREVIEWS_DIR = "previews"
MESH_FILE = "mesh.ply"
MESH_VIEWS_DIR = "mesh_views"
"""Shaded renders of a mesh (PNG), written beside it by the mesh stage."""
HELD_OUT_DIR = "held_out"
"""The nvs protocol's held-out views: rendered | photo (PNG), beside the metrics."""
METRICS_FILE = "metrics.json"
"""An evaluation record (``"record": "evaluation"``)."""
SUMMARY_FILE = "summary.csv"
GROUND_TRUTH_CHECK_FILE = "ground_truth_check.json"
REPORT_DIR = "report"
REPORT_FILE = "report.html"

PRETRAIN = "pretrain"
"""The pretrain stage's folder, beside the methods' folders of a scene."""

RECORD = "record"
"""The field of a metrics file that says what it holds: EVALUATION or TRAINING."""
EVALUATION = "evaluation"
TRAINING = "training"

SUMMARY_COLUMNS = ("scene", "method", "protocol", "unit", "tau", "points", "accuracy", "completeness", "chamfer",
                   "precision", "recall", "fscore", "depth_signed_error", "depth_error", "depth_on_empty", "psnr",
                   "ssim", "failed", "log")
"""The columns of ``summary.csv`` (``eve3d summary``) and of the report's table; a row whose
jobs failed has only ``failed`` (the rule and its first error line) and ``log``."""
VIEW_COLUMNS = ("scene", "stage", "views", "psnr", "ssim")
"""The columns of ``summary_views.csv``: the training stages' held-out views."""


def format_table(rows: list[dict], columns: tuple[str, ...] = SUMMARY_COLUMNS) -> str:
    """A plain-text table of metric rows (missing values as '-')."""
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else ("-" if v is None else str(v))

    cols = [c for c in columns if any(c in r for r in rows)]
    table = [cols] + [[cell(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(cols))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in table]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths)] + lines[1:])


@dataclass(frozen=True)
class Layout:
    """The results tree under ``root`` (the config's ``results``). Every method returns a
    Path; give wildcards (``"{scene}"``) for Snakemake patterns."""

    root: Path | str

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    # -- per scene -----------------------------------------------------------------------
    def scene(self, scene: str) -> Path:
        return self.root / scene

    def input(self, scene: str) -> Path:
        """The generated dataset of a synthetic scene."""
        return self.scene(scene) / "input"

    def generated_gt_mesh(self, scene: str) -> Path:
        """The GT mesh inside a generated dataset (eve3d.synth writes it there)."""
        return self.input(scene) / "gt" / "mesh.ply"

    def ground_truth_check(self, scene: str) -> Path:
        """What the check that a benchmark scene's ground truth lines up with its cameras
        measured (written before any training)."""
        return self.scene(scene) / GROUND_TRUTH_CHECK_FILE

    def sfm(self, scene: str) -> Path:
        """The posed dataset that SfM makes of an image-only one."""
        return self.scene(scene) / "sfm"

    def stereo(self, scene: str) -> Path:
        """Virtual stereo pairs: the right views rendered by the pretrained model."""
        return self.scene(scene) / "stereo"

    def priors(self, scene: str, backend: str) -> Path:
        return self.scene(scene) / PRIORS_DIR / backend

    # -- per training stage or method ----------------------------------------------------
    def method(self, scene: str, method: str) -> Path:
        """A method's folder; ``method`` PRETRAIN gives the pretrain stage's."""
        return self.scene(scene) / method

    def pretrain(self, scene: str) -> Path:
        return self.method(scene, PRETRAIN)

    def model(self, scene: str, method: str) -> Path:
        """The trained Gaussians of a method, or of the pretrain (``method`` PRETRAIN)."""
        return self.method(scene, method) / MODEL_FILE

    def tone_curve(self, scene: str) -> Path:
        return self.pretrain(scene) / TONE_FILE

    def train_metrics(self, scene: str, method: str) -> Path:
        """A training stage's record: a trained method's, or the pretrain's (PRETRAIN)."""
        return self.method(scene, method) / TRAIN_METRICS_FILE

    def depth(self, scene: str, method: str) -> Path:
        """The depth maps a trained method renders for its mesh."""
        return self.method(scene, method) / DEPTH_DIR

    def learned_priors(self, scene: str, method: str) -> Path:
        """The final learnable priors D̂ of a method that learns them."""
        return self.method(scene, method) / PRIORS_DIR

    def mesh(self, scene: str, method: str) -> Path:
        return self.method(scene, method) / MESH_FILE

    def metrics(self, scene: str, method: str) -> Path:
        """The evaluation record of a method's reconstruction."""
        return self.method(scene, method) / METRICS_FILE

    # -- over the whole run --------------------------------------------------------------
    def logs(self, scene: str | None = None) -> Path:
        return self.root / "logs" / (scene or "")

    def log(self, scene: str, rule: str, what: str | None = None) -> Path:
        """A job's log: ``rule`` of a scene, ``what`` naming the job among the rule's
        (a method, a backend)."""
        return self.logs(scene) / f"{job_name(rule, what)}.log"

    def core_share(self) -> Path:
        """Where the training jobs running side by side register (``eve3d.core.cores``)."""
        return self.root / ".cores"

    def benchmarks(self, scene: str | None = None) -> Path:
        """The folder of Snakemake's ``benchmark:`` files (of one scene)."""
        return self.root / "benchmarks" / (scene or "")

    def benchmark(self, scene: str, rule: str, what: str | None = None) -> Path:
        """A job's Snakemake ``benchmark:`` file (wall seconds in its first column,
        :func:`benchmark_seconds`)."""
        return self.benchmarks(scene) / f"{job_name(rule, what)}.tsv"

    def summary(self) -> Path:
        return self.root / SUMMARY_FILE

    def failures(self) -> Path:
        """The rows of the scenes and methods whose jobs failed (``eve3d.core.failures``)."""
        return self.root / "failed.json"

    def report_pages(self) -> Path:
        """The pages ``eve3d report`` writes for Snakemake's ``--report`` (``eve3d.report``)."""
        return self.root / REPORT_DIR

    def report(self) -> Path:
        """The self-contained HTML report ``snakemake --report`` writes (docs/benchmarks.md)."""
        return self.root / REPORT_FILE


def benchmark_seconds(path: Path | str) -> float | None:
    """Wall seconds from a Snakemake benchmark file (None when the job did not run here)."""
    path = Path(path)
    if not path.is_file():
        return None
    rows = path.read_text().splitlines()
    return float(rows[1].split("\t")[0]) if len(rows) > 1 else None


def job_name(rule: str, what: str | None = None) -> str:
    return f"{rule}_{what}" if what else rule


def locate(path: Path | str) -> tuple[str, str]:
    """The scene and the method (or PRETRAIN) of a file in a method's folder, e.g. of
    ``{results}/{scene}/{method}/metrics.json``: the inverse of :meth:`Layout.method`."""
    path = Path(path)
    return path.parent.parent.name, path.parent.name
