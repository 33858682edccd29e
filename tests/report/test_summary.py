"""eve3d.report.summary (through ``eve3d summary``): the summary gathered from the metrics records."""
import csv
import json
from pathlib import Path

from eve3d.core.layout import EVALUATION, PRETRAIN, RECORD, TRAINING, Layout
from tests.helpers import run_cli


def write_record(path: Path, record: dict) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))
    return path


def test_summary_reads_what_each_record_holds(tmp_path):
    layout = Layout(tmp_path / "results")
    scores = {"protocol": "synthetic", "fscore": 0.75, "chamfer": 0.01}
    files = [write_record(layout.metrics("obj", "pgsr"), {RECORD: EVALUATION, **scores}),
             # an evaluation without scene/method fields: the tree names its row
             write_record(layout.metrics("obj", "oracle"), {RECORD: EVALUATION, **scores, "fscore": 0.99}),
             write_record(layout.train_metrics("obj", PRETRAIN), {
                 RECORD: TRAINING, "held_out": {"psnr": 21.5, "ssim": 0.88, "views": 4}, "train": {}})]
    r = run_cli("summary", *files, "--out", layout.summary())
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(layout.summary())))
    assert [(row["scene"], row["method"], row["fscore"]) for row in rows] == [("obj", "oracle", "0.99"),
                                                                            ("obj", "pgsr", "0.75")]
    views = list(csv.DictReader(open(layout.root / "summary_views.csv")))
    assert [(v["scene"], v["stage"], v["psnr"]) for v in views] == [("obj", "pretrain", "21.5")]
    shown = run_cli("summary", "--show", "--out", layout.summary())  # the tables again, from the files
    assert shown.returncode == 0 and shown.stdout == r.stdout, (shown.stdout, r.stdout)
    missing = run_cli("summary", "--show", "--out", tmp_path / "none.csv")
    assert missing.returncode == 2 and f"{tmp_path / 'none.csv'}: no summary table" in missing.stderr


def test_summary_refuses_a_file_that_does_not_say_what_it_holds(tmp_path):
    layout = Layout(tmp_path / "results")
    old = write_record(layout.metrics("obj", "pgsr"), {"protocol": "synthetic", "fscore": 0.75})
    r = run_cli("summary", old, "--out", layout.summary())
    assert r.returncode == 2 and f"{old}: no 'record' field" in r.stderr and "--forcerun evaluate" in r.stderr
    write_record(old, {RECORD: "mesh", "fscore": 0.75})
    r = run_cli("summary", old, "--out", layout.summary())
    assert r.returncode == 2 and f"{old}: 'record' is 'mesh'" in r.stderr
    assert not layout.summary().exists()
