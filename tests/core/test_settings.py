"""eve3d.core.settings: the settings classes' own checks, the training size, importable (and planned) without torch."""
import subprocess
import sys

import numpy as np
import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.settings import RenderSettings
from eve3d.core.settings_stereo import SgbmSettings
from tests.helpers import REPO, SNAKEFILE

# Blocks every import of torch in the interpreter it is put in front of.
NO_TORCH = """
import sys
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch is blocked by this test")
sys.meta_path.insert(0, _Block())
"""


def _without_torch(tmp_path, *args: str) -> subprocess.CompletedProcess:
    (tmp_path / "sitecustomize.py").write_text(NO_TORCH)
    env = {"PYTHONPATH": f"{tmp_path}:{REPO}", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=REPO, env=env)


def test_settings_and_planning_need_no_torch(tmp_path):
    """The settings import, and `snakemake -n` plans the default config, with torch unimportable."""
    r = _without_torch(tmp_path, "-c", "import torch")
    assert r.returncode != 0 and "blocked" in r.stderr  # the block works
    r = _without_torch(tmp_path, "-c", "import eve3d.core.settings, eve3d.config; print('ok')")
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr
    r = _without_torch(tmp_path, "-m", "snakemake", "-s", str(SNAKEFILE), "-n", "--config",
                       f"results={tmp_path / 'results'}")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "joint" in r.stdout and "evaluate" in r.stdout


def test_sgbm_mode_out_of_range_is_named():
    with pytest.raises(Eve3dError, match="stereo.sgm_mode"):
        SgbmSettings(sgm_mode="fast")


def test_training_size_is_capped_by_the_longest_side():
    from eve3d.core.scene import Camera

    cam = Camera("v.png", 4032, 3024, np.eye(3), np.eye(3), np.zeros(3))
    assert RenderSettings(max_side=512).scale(cam) == pytest.approx(512 / 4032)
    assert RenderSettings(resolution=0.1, max_side=512).scale(cam) == pytest.approx(0.1)
    assert RenderSettings(resolution=0.75, max_side=0).scale(cam) == 0.75


def test_pretrain_equalize_out_of_range_is_named():
    from eve3d.core.settings import PretrainSettings

    with pytest.raises(Eve3dError, match="pretrain.equalize"):
        PretrainSettings(equalize=0.5)
