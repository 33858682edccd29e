"""eve3d.report: the summary gathered from the metrics records, the summary page, the scene sheets' error maps."""
import csv
import json
from pathlib import Path

import numpy as np

from eve3d.core.layout import EVALUATION, PRETRAIN, RECORD, TRAINING, Layout
from eve3d.evaluate.common import write_error_maps
from eve3d.report import ERROR_MAP_BACKGROUND, ERROR_MAP_PIXELS, _error_map
from tests.helpers import run_cli


def test_error_map_is_seen_from_above_with_y_up(tmp_path):
    """A white floor of 2 × 1 under a dark roof over its top-left corner: each pixel shows
    its highest point, so the corner is dark; the longest side spans ERROR_MAP_PIXELS; +y
    is up, as on a plot; a pixel without a point shows the background."""
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform((0, 0), (2, 1), (100_000, 2)), np.zeros(100_000)]
    roof = np.c_[rng.uniform((0, 0.75), (0.5, 1), (60_000, 2)), np.ones(60_000)]  # 34 a pixel
    points, top = np.r_[floor, roof], 1.0
    distances = np.r_[np.zeros(len(floor)), np.full(len(roof), top)]
    write_error_maps(tmp_path, points, distances, points, distances, top)
    image = _error_map(tmp_path / "precision.ply")
    height, width, _ = image.shape
    assert width == ERROR_MAP_PIXELS and abs(height - ERROR_MAP_PIXELS // 2) <= 1
    shown = (image != ERROR_MAP_BACKGROUND).any(-1)
    assert 0.7 < shown.mean() < 1  # 3.5 floor points a pixel leave a few empty
    corner = image[: height // 4 - 2, : width // 4 - 2][shown[: height // 4 - 2, : width // 4 - 2]]
    rest = image[height // 4 + 2:][shown[height // 4 + 2:]]
    assert len(corner) > 100 and np.all(corner == corner[0]) and corner[0].max() < 0.1  # the roof hides the floor
    assert len(rest) > 1000 and np.all(rest == 1)  # below it, the white floor


def _cells(page: str, table_id: str) -> list[dict]:
    """The rows of table ``table_id`` of ``page``: header → (text, bold)."""
    from html.parser import HTMLParser

    class Parser(HTMLParser):
        def __init__(self):
            super().__init__()
            self.inside, self.header, self.rows, self.cell, self.bold = False, [], [], None, False

        def handle_starttag(self, tag, attrs):
            if tag == "table":
                self.inside = dict(attrs).get("id") == table_id
            elif self.inside and tag == "tr":
                self.rows.append([])
            elif self.inside and tag in ("td", "th"):
                self.cell, self.bold = "", False
            elif self.inside and tag == "b":
                self.bold = True

        def handle_endtag(self, tag):
            if self.inside and tag in ("td", "th"):
                self.rows[-1].append((self.cell, self.bold))
                self.cell = None
            elif tag == "table":
                self.inside = False

        def handle_data(self, data):
            if self.cell is not None:
                self.cell += data

    parser = Parser()
    parser.feed(page)
    header = [text for text, _ in parser.rows[0]]
    return [dict(zip(header, row)) for row in parser.rows[1:]]


def test_summary_page_shows_units_and_marks_the_best_of_each_scene():
    """DTU distances in mm as they are, T&T's metres in mm; the best of a scene's methods is
    bold in each ranked column (the oracle, a ceiling, is not ranked; a tie marks both), and
    the means mark the best among methods scored on every scene."""
    from eve3d.report import summary_page

    dtu = [{"scene": s, "method": m, "protocol": "dtu", "unit": "mm", "chamfer": str(c), "accuracy": str(a)}
           for s, m, c, a in (("scan24", "pgsr", 0.612, 0.5), ("scan24", "eve3d", 0.5449, 0.5),
                              ("scan24", "oracle", 0.1, 0.1), ("scan37", "pgsr", 0.8, 0.7),
                              ("scan37", "eve3d", 0.9, 0.6))]
    tnt = [{"scene": "Barn", "method": m, "protocol": "tnt", "unit": "m", "tau": "0.01", "fscore": str(f)}
           for m, f in (("pgsr", 0.51234), ("eve3d", 0.58))]
    failed = [{"scene": "scan37", "method": "stereo-tsdf", "failed": "stereo: out of memory", "log": "x.log"}]
    page = summary_page(dtu + tnt + failed, [{"source": "published", "method": "pgsr", "chamfer": 0.52}], "t")

    rows = _cells(page, "summary-dtu")
    assert "Chamfer (mm)" in rows[0] and "accuracy (mm)" in rows[0]
    chamfer = {(r["scene"][0], r["method"][0]): r["Chamfer (mm)"] for r in rows}
    assert chamfer[("scan24", "eve3d")] == ("0.545", True) and chamfer[("scan24", "pgsr")] == ("0.612", False)
    assert chamfer[("scan24", "oracle")] == ("0.1", False)  # lower, but not ranked
    assert chamfer[("scan37", "pgsr")] == ("0.8", True)
    accuracy = {(r["scene"][0], r["method"][0]): r["accuracy (mm)"][1] for r in rows}
    assert accuracy[("scan24", "eve3d")] and accuracy[("scan24", "pgsr")]  # a tie
    means = {(r["source"][0], r["method"][0]): r for r in _cells(page, "means-dtu")}
    mine = "this run (mean)"
    assert means[(mine, "eve3d")]["Chamfer (mm)"] == ("0.722", False)
    assert means[(mine, "pgsr")]["Chamfer (mm)"] == ("0.706", True) and means[(mine, "pgsr")]["scenes"][0] == "2"
    assert means[("published", "pgsr")]["Chamfer (mm)"] == ("0.52", False)

    barn = {r["method"][0]: r for r in _cells(page, "summary-tnt")}
    assert barn["pgsr"]["τ (mm)"] == ("10", False) and barn["pgsr"]["F-score"] == ("0.512", False)
    assert barn["eve3d"]["F-score"] == ("0.580", True)
    assert "means-tnt" in page and "Chamfer" not in str(_cells(page, "means-tnt")[0])  # T&T's table has no Chamfer
    assert _cells(page, "summary-failed")[0]["failed"][0] == "stereo: out of memory"


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
