"""eve3d.tools.bench.scale: ``eve3d bench scale --memory`` at a tiny size."""
import json

from eve3d.config import job_config


def test_scale_bench_memory_mode_at_a_tiny_size(tmp_path):
    """``eve3d bench scale --memory`` on 6 views of 96×54 and 5000 GT samples (synthetic
    protocol only): each step in a process of its own, with its time and peak memory, and
    the table that prints them (no thresholds: memory and time are read, never tested)."""
    from eve3d.tools.bench.scale import bench_scale, format_scale_report

    config = job_config(None, ["synthetic.views=6", "synthetic.width=96", "synthetic.height=54"])
    report = bench_scale(tmp_path / "work", config, memory=True, gt_points=5000, protocols=["synthetic"])
    json.dumps(report)  # what --json prints
    assert [(r["stage"], r["detail"]) for r in report["stages"]] == [
        ("set-up", "room, exact depth at 96x54"), ("mesh", "room, 6 views 96x54"),
        ("evaluate", "synthetic, 0.005M samples")]
    assert all(r["seconds"] > 0 and r["peak_mb"] > 50 for r in report["stages"])
    assert 0 < report["scores"]["synthetic"]["n_gt"] <= 5000 and report["scores"]["synthetic"]["fscore"] > 0.5
    lines = format_scale_report(report).splitlines()
    assert lines[0].split() == ["stage", "detail", "seconds", "peak", "MB", "load"]
    assert lines[6].startswith("total") and "largest peak" in lines[6]
    assert any(line.startswith("memory mode: room, 6 views, 96x54; preset cpu") for line in lines)
