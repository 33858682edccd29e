"""eve3d.report.tables: the summary page's units and the best of each scene marked."""
from eve3d.report.tables import summary_page


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
