"""eve3d.tools.bench.training: its table, parts that add up to the step, profiling that leaves training unchanged."""
import json

import torch

from eve3d.config import job_config
from eve3d.joint import setup_joint
from eve3d.tools.bench.training import STEP_PARTS, bench_training, format_training_table, profile_steps
from tests.helpers import joint_settings


def test_training_bench_parts_add_up_to_the_step():
    """Two steps of pgsr (a neighbour render inside the loss) on an 8-view 64×48 object."""
    config = job_config('{"synthetic": {"width": 64, "height": 48, "views": 8}}')
    report = bench_training(["pgsr"], steps=2, warmup=1, gaussians=300, config=config)
    json.dumps(report)  # what --json prints
    (row,) = report["stages"]
    assert row["stage"] == "pgsr" and row["steps"] == 2 and row["renders"] == 2 and row["pairs"] > 0
    assert list(row["parts_ms"]) == list(STEP_PARTS)
    assert abs(sum(row["parts_ms"].values()) - row["step_ms"]) < 1e-6
    assert min(row["parts_ms"].values()) >= 0 and row["peak_mb"] > 0
    ran = {k for k, v in row["parts_ms"].items() if v > 0}  # each part the code marks is reached and timed
    assert ran >= {"projection", "rasterize", "losses", "losses_backward", "rasterize_backward", "projection_backward",
                   "optimizer", "densify"}, row["parts_ms"]

    lines = format_training_table(report).splitlines()
    assert lines[0].split()[-1] == "pgsr"
    cells = {line[:-10].strip(): line.split()[-1] for line in lines[2:] if line and not line.startswith("-")}
    assert [label for label in cells if label in STEP_PARTS.values()] == list(STEP_PARTS.values())
    parts = [float(cells[label]) for label in STEP_PARTS.values()]
    assert abs(sum(parts) - float(cells["step"])) <= 0.05 * (len(parts) + 1)  # each cell rounded to 0.1 ms
    assert {"Gaussians", "renders per step", "pairs per step", "peak MB"} <= set(cells)


def test_profiling_leaves_training_unchanged(tiny_scene, tmp_path, one_thread):
    """The same steps with and without the bench's wrappers and hooks: the same Gaussians,
    bit for bit (densification at step 30 included)."""
    models = []
    for profiled in (False, True):
        run = setup_joint(tiny_scene, tmp_path / str(profiled), joint_settings(checkpoint_every=0))
        if profiled:
            profile_steps(run.trainer, run.loss, None, start=20, warmup=1, steps=10)
        else:
            run.trainer.state.step = 20
            run.trainer.state.densify_stats["birth"].fill_(20)
            run.trainer.run(run.loss, until=31)
        models.append(run.trainer.model.params)
    plain, profiled = models
    for name, value in plain.items():
        assert torch.equal(value, profiled[name]), name
