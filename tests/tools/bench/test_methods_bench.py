"""eve3d.tools.bench.methods: the tables of ``eve3d bench methods`` and ``eve3d bench real``,
read from a finished run's results folder."""
import json

import numpy as np
import pytest

from eve3d.core.layout import PRETRAIN, Layout
from eve3d.core.maps import load_maps, save_maps
from eve3d.priors.oracle import priors_from_mesh
from eve3d.tools.bench.methods import format_methods_report, format_real_report, methods_report, real_report


def write_benchmark(path, seconds: float) -> None:
    """A Snakemake ``benchmark:`` file: a header, then the wall seconds first."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"s\th:m:s\tmax_rss\n{seconds}\t0:00:{seconds:02.0f}\t100\n")


def write_metrics(path, **scores) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(scores))


def test_methods_report_reads_each_scores_time_and_priors(tiny_scene, tmp_path):
    """Two scenes, two methods: each row's scores and its own stages' seconds (joint + mesh;
    a missing benchmark file leaves the row's seconds and their mean empty), the means over
    the scenes, the shared stages per scene, and D* (the oracle's depth 3 % too far on every
    pixel) scored against the oracle depth: +3 %."""
    layout = Layout(tmp_path / "results")
    config = {"results": str(layout.root), "stereo": {"backend": "sgbm"}, "methods": ["pgsr", "eve3d"],
              "scenes": {"a": {}, "b": {}}}
    for i, scene in enumerate(("a", "b")):
        for j, method in enumerate(("pgsr", "eve3d")):
            write_metrics(layout.metrics(scene, method), chamfer=0.01 * (1 + i + j), precision=0.8, recall=0.6 + 0.1 * j,
                          fscore=0.7 + 0.1 * i + 0.05 * j)
            write_benchmark(layout.benchmark(scene, "mesh", method), 2)
            if (scene, method) != ("b", "eve3d"):
                write_benchmark(layout.benchmark(scene, "joint", method), 10 * (j + 1))
    write_benchmark(layout.benchmark("a", "pretrain"), 30)
    oracle = layout.priors("a", "oracle")
    priors_from_mesh(tiny_scene, oracle, preview=False)
    for cam in tiny_scene.cameras:
        maps = load_maps(oracle / f"{cam.view_id}.npz")
        save_maps(layout.priors("a", "sgbm") / f"{cam.view_id}.npz", preview=False,
                  depth=maps["depth"] * 1.03, confidence=maps["confidence"])

    report = methods_report(config)
    rows = {(r["scene"], r["method"]): r for r in report["rows"]}
    assert rows["a", "pgsr"]["fscore"] == pytest.approx(0.7) and rows["b", "eve3d"]["chamfer"] == pytest.approx(0.03)
    assert rows["a", "eve3d"]["seconds"] == 22 and rows["b", "eve3d"]["seconds"] is None
    means = {r["method"]: r for r in report["means"]}
    assert means["pgsr"]["scene"] == "mean of 2" and means["pgsr"]["fscore"] == pytest.approx(0.75)
    assert means["pgsr"]["seconds"] == 12 and means["eve3d"]["seconds"] is None
    assert report["shared_seconds"]["a"] == {"pretrain": 30, "stereo_render": None, "stereo_depth_sgbm": None}
    (star,) = report["priors"]
    assert star["priors"] == "D* (sgbm)" and star["data"] == "a"
    assert star["median_signed_error"] == pytest.approx(0.03, abs=1e-5) and star["wrong_5"] == 0
    table = format_methods_report(report)
    assert "mean of 2" in table and "a / D* (sgbm)" in table and "+3.00 %" in table


def test_real_report_reads_photos_times_held_out_views_priors_and_meshes(tiny_dataset, tiny_scene, tmp_path):
    """A posed capture: its photos and registered views, every job's seconds, the held-out
    scores of the pretrain and of a method, exact priors whose neighbouring views agree, and
    a mesh's extent against the sparse points' box."""
    import open3d as o3d

    layout = Layout(tmp_path / "results")
    config = {"results": str(layout.root), "stereo": {"backend": "oracle"}, "methods": ["eve3d"],
              "scenes": {"cap": {"path": str(tiny_dataset)}}}
    write_benchmark(layout.benchmark("cap", "joint", "eve3d"), 40)
    write_metrics(layout.train_metrics("cap", PRETRAIN), held_out={"psnr": 20.0, "ssim": 0.7, "views": 1})
    write_metrics(layout.metrics("cap", "eve3d"), psnr=22.5, ssim=0.8, views=1)
    priors_from_mesh(tiny_scene, layout.priors("cap", "oracle"), preview=False)
    box = o3d.geometry.TriangleMesh.create_box(1.0, 2.0, 0.5)
    layout.mesh("cap", "eve3d").parent.mkdir(parents=True, exist_ok=True)
    o3d.io.write_triangle_mesh(str(layout.mesh("cap", "eve3d")), box)

    (row,) = real_report(config)["scenes"]
    assert row["photos"] == row["registered"] == len(tiny_scene.cameras) and row["points"] == len(tiny_scene.points)
    assert row["seconds"] == {"joint_eve3d": 40}
    assert row["held_out"] == {PRETRAIN: {"psnr": 20.0, "ssim": 0.7, "views": 1},
                               "eve3d": {"psnr": 22.5, "ssim": 0.8, "views": 1}}
    assert row["priors"]["median_disagreement"] < 0.005 and row["priors"]["compared"] > 0
    mesh = row["meshes"]["eve3d"]
    assert mesh["triangles"] == 12 and mesh["extent"] == [1.0, 2.0, 0.5]
    lo, hi = tiny_scene.sparse_box()  # the sparse points' 5–95 % box
    assert mesh["sparse_extent"] == pytest.approx(hi - lo, abs=1e-4)
    assert mesh["extent_ratio"] == pytest.approx(np.max([1.0, 2.0, 0.5] / (hi - lo)))
    table = format_real_report(real_report(config))
    assert f"cap: {row['registered']} of {row['photos']} photos registered" in table and "22.50" in table
