"""eve3d.core.layout: the results tree (Snakemake's patterns, planned without torch)."""
import subprocess
import sys

from eve3d.core.layout import PRETRAIN, Layout, locate
from tests.helpers import REPO


def test_wildcards_give_the_snakemake_patterns():
    layout = Layout("results")
    assert str(layout.mesh("{scene}", "{method}")) == "results/{scene}/{method}/mesh.ply"
    assert str(layout.metrics("{scene}", "{method}")) == "results/{scene}/{method}/metrics.json"
    assert str(layout.model("{scene}", PRETRAIN)) == "results/{scene}/pretrain/point_cloud.ply"
    assert str(layout.train_metrics("{scene}", PRETRAIN)) == "results/{scene}/pretrain/train_metrics.json"
    assert str(layout.priors("{scene}", "{backend}")) == "results/{scene}/priors/{backend}"
    assert str(layout.log("{scene}", "joint", "{method}")) == "results/logs/{scene}/joint_{method}.log"
    assert str(layout.benchmark("obj", "pretrain")) == "results/benchmarks/obj/pretrain.tsv"
    assert str(Layout("/data/run/").summary()) == "/data/run/summary.csv"
    assert locate(layout.metrics("obj", "pgsr")) == ("obj", "pgsr")


def test_layout_plans_without_torch():
    code = "import sys, eve3d.core.layout; assert 'torch' not in sys.modules and 'numpy' not in sys.modules"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
