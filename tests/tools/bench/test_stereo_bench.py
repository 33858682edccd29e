"""eve3d.tools.bench.stereo: a folder of priors scored against the oracle's exact depth beside
it, and the message when there is none."""
import json
import re

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.layout import Layout
from eve3d.core.maps import load_maps, save_maps
from eve3d.priors.oracle import priors_from_mesh
from eve3d.tools.bench.stereo import format_stereo_tables, run_bench_stereo


def test_priors_are_scored_against_the_oracle_beside_them(tiny_scene, tmp_path, capsys):
    """Priors 2 % too near, confident on the lower half of each view only: ``eve3d bench
    stereo --json`` finds the oracle beside them and gives a median signed error of −2 %,
    nothing off by 5 %, and as density the lower half's share of the pixels with a surface;
    beside them, the Middlebury pair's rows (``sgbm`` and ``sgbm+wls``)."""
    layout = Layout(tmp_path / "results")
    oracle = layout.priors("s", "oracle")
    priors_from_mesh(tiny_scene, oracle, preview=False)
    lower, surface = 0, 0
    for cam in tiny_scene.cameras:
        maps = load_maps(oracle / f"{cam.view_id}.npz")
        confidence = maps["confidence"].copy()
        confidence[: confidence.shape[0] // 2] = 0
        save_maps(layout.priors("s", "sgbm") / f"{cam.view_id}.npz", preview=False,
                  depth=maps["depth"] * 0.98, confidence=confidence)
        lower, surface = lower + np.count_nonzero(confidence), surface + np.count_nonzero(maps["confidence"])
    run_bench_stereo([layout.priors("s", "sgbm")], as_json=True)
    report = json.loads(capsys.readouterr().out)
    (row,) = report["priors"]
    assert row["backend"] == "sgbm" and row["data"] == "s/sgbm"
    assert row["median_signed_error"] == pytest.approx(-0.02, abs=1e-5) and row["wrong_5"] == 0
    assert row["density"] == pytest.approx(lower / surface) and 0 < lower < surface
    assert [m["backend"] for m in report["motorcycle"]] == ["sgbm", "sgbm+wls"]
    moto = [{"backend": "sgbm", "size": "741x497", "density": 0.8, "epe": 0.9, "bad2": 8.5, "seconds": 0.4}]
    table = format_stereo_tables(moto, [row])
    assert "sgbm     741x497    0.800   0.900       8.50" in table and "-2.00 %" in table


def test_priors_without_an_oracle_or_a_scene_are_named(tmp_path):
    folder = tmp_path / "results/s/priors/sgbm"
    folder.mkdir(parents=True)
    with pytest.raises(Eve3dError, match=rf"{re.escape(str(folder))}: no oracle priors beside it .* give --scene"):
        run_bench_stereo([folder])
