"""eve3d.tools.bench.stereo: the priors scored against the exact depth beside them, and the
message when there is none."""
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.layout import Layout
from eve3d.core.maps import load_maps, save_maps
from eve3d.priors.oracle import priors_from_mesh
from eve3d.tools.bench.stereo import format_stereo_tables, prior_accuracy, run_bench_stereo


def test_prior_accuracy_scores_a_prior_folder_against_the_oracle_beside_it(tiny_scene, tmp_path):
    """Priors 2 % too near on the confident half of each view, unconfident elsewhere: a median
    signed error of −2 %, nothing off by 5 %, and a density of one half (to a row of pixels)."""
    layout = Layout(tmp_path / "results")
    oracle = layout.priors("s", "oracle")
    priors_from_mesh(tiny_scene, oracle, preview=False)
    for cam in tiny_scene.cameras:
        maps = load_maps(oracle / f"{cam.view_id}.npz")
        confidence = maps["confidence"].copy()
        confidence[: confidence.shape[0] // 2] = 0
        save_maps(layout.priors("s", "sgbm") / f"{cam.view_id}.npz", preview=False,
                  depth=maps["depth"] * 0.98, confidence=confidence)
    row = prior_accuracy(layout.priors("s", "sgbm"), oracle, "s")
    assert row["backend"] == "sgbm" and row["data"] == "s"
    assert row["median_signed_error"] == pytest.approx(-0.02, abs=1e-5) and row["wrong_5"] == 0
    assert 0.3 < row["density"] < 0.7
    moto = [{"backend": "sgbm", "size": "741x497", "density": 0.8, "epe": 0.9, "bad2": 8.5, "seconds": 0.4}]
    table = format_stereo_tables(moto, [row])
    assert "sgbm     741x497    0.800   0.900       8.50" in table and "-2.00 %" in table


def test_priors_without_an_oracle_or_a_scene_are_named(tmp_path):
    folder = tmp_path / "results/s/priors/sgbm"
    folder.mkdir(parents=True)
    with pytest.raises(Eve3dError, match=rf"{folder}: no oracle priors beside it .* give --scene"):
        run_bench_stereo([folder])
