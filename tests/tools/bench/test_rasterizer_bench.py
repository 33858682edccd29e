"""eve3d.tools.bench.rasterizer: the Gaussians it renders, its table and JSON, one tiny size measured in a child."""
import json
import math
from dataclasses import asdict, fields

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from eve3d.gaussians.render import render
from eve3d.tools.bench.rasterizer import (RASTERIZER_SIZES, RasterizerTiming, format_rasterizer_table,
                                          rasterizer_json, run_bench_rasterizer, surface_gaussians, time_rasterizer)


def test_surface_gaussians_are_discs_on_the_object_seen_by_the_camera():
    (means, quats, scales, opacities, colors), cam = surface_gaussians(400, 40, 30)
    assert [p.shape for p in (means, quats, scales, opacities, colors)] == [(400, 3), (400, 4), (400, 3), (400,),
                                                                             (400, 3)]
    assert all(p.dtype == np.float32 and p.flags.c_contiguous for p in (means, quats, scales, opacities, colors))
    # discs: the third axis 2 % of the first, the second at most the first
    assert np.allclose(scales[:, 2], 0.02 * scales[:, 0], rtol=1e-5) and (scales[:, 1] <= scales[:, 0]).all()
    spacing_ratio = scales[:, 0].max() / scales[:, 0].min()
    assert 1.5 < spacing_ratio <= 2.0 + 1e-5   # 0.4-0.8 × one spacing
    assert np.allclose(np.linalg.norm(quats, axis=1), 1, atol=1e-5)
    assert 0.3 <= opacities.min() and opacities.max() <= 1 and 0 <= colors.min() and colors.max() <= 1
    # on the table top (z = 0) each disc lies flat: its thin axis (the rotation's third column) is vertical
    normal = Rotation.from_quat(quats[:, [1, 2, 3, 0]]).as_matrix()[:, :, 2]
    top = np.abs(means[:, 2]) < 1e-6
    assert top.sum() > 50 and np.allclose(np.abs(normal[top, 2]), 1, atol=1e-4)
    # the first camera of the synthetic object's spiral: 3 units away, f = 1.1 × width, most centres in view
    assert (cam.width, cam.height) == (40, 30) and cam.K[0, 0] == pytest.approx(44.0)
    assert np.linalg.norm(cam.center) == pytest.approx(3.0)
    uv, z = cam.project(means.astype(np.float64))
    assert (z > 0).all() and cam.in_image(uv, z).mean() > 0.7
    again, _ = surface_gaussians(400, 40, 30)   # seeded: the same scene for each size and run
    assert all(np.array_equal(a, b) for a, b in zip(again, (means, quats, scales, opacities, colors)))
    assert not np.array_equal(surface_gaussians(400, 40, 30, seed=1)[0][0], means)


def test_rasterizer_table_and_json():
    rows = [RasterizerTiming(5_000, 160, 120, "cpu", 123_456, 3.14159, 10.06, 512.4),
            RasterizerTiming(100_000, 640, 480, "gsplat", None, 12.26, 30.0, 2048.6)]
    lines = format_rasterizer_table(rows).splitlines()
    assert lines == ["gaussians width height backend      pairs forward ms backward ms  peak MB",
                     "-" * len(lines[0]),
                     "    5,000   160    120     cpu    123,456        3.1        10.1      512",
                     "  100,000   640    480  gsplat          -       12.3        30.0     2049"]
    assert [field.name for field in fields(RasterizerTiming)] == list(json.loads(rasterizer_json(rows))[0])
    assert json.loads(rasterizer_json(rows)) == [asdict(r) for r in rows]
    assert format_rasterizer_table([]).splitlines()[1] == "-" * len(lines[0])
    assert [w / h for _, w, h in RASTERIZER_SIZES] == [4 / 3] * 3 and sorted(RASTERIZER_SIZES) == list(RASTERIZER_SIZES)


def test_time_rasterizer_renders_the_scene_it_is_given():
    """Forward and backward of 300 Gaussians at 32×24 (the torch backend, no compiler): the
    pairs it reports are those of a render of the same scene."""
    params, cam = surface_gaussians(300, 32, 24)
    timing = time_rasterizer(params, cam, backend="torch", repeats=2)
    out = render(*(torch.from_numpy(p) for p in params), cam, backend="torch")
    assert (timing.gaussians, timing.width, timing.height, timing.backend) == (300, 32, 24, "torch")
    assert timing.pairs == out.n_pairs > 300
    assert all(math.isfinite(v) and v > 0 for v in (timing.forward_ms, timing.backward_ms, timing.peak_mb))


def test_bench_rasterizer_measures_each_size_in_a_child_process(capsys):
    """``eve3d bench rasterizer --json`` at one size of 200 Gaussians at 16×12: a row per
    size, measured in a spawned process (its own peak memory, torch imported)."""
    run_bench_rasterizer(sizes=((200, 16, 12),), backend="torch", repeats=1, as_json=True)
    (row,) = json.loads(capsys.readouterr().out)
    assert {k: row[k] for k in ("gaussians", "width", "height", "backend")} == {
        "gaussians": 200, "width": 16, "height": 12, "backend": "torch"}
    assert row["pairs"] > 0 and all(math.isfinite(row[k]) and row[k] > 0 for k in ("forward_ms", "backward_ms"))
    assert math.isfinite(row["peak_mb"]) and row["peak_mb"] > 100   # a process with torch in it
