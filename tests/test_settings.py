"""The settings layer: one declaration per setting, checked the same way on every route,
importable (and the workflow plannable) without torch."""
import dataclasses
import subprocess
import sys

import pytest
import yaml

from eve3d.scene import Eve3dError
from eve3d.settings import (SECTIONS, BaselineSettings, JointSettings, MeshSettings, PretrainSettings, StereoSettings,
                            from_mapping, pick)
from tests.conftest import REPO

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
    r = _without_torch(tmp_path, "-c", "import eve3d.settings, eve3d.config; print('ok')")
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr
    r = _without_torch(tmp_path, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "-n", "--config",
                       f"results={tmp_path / 'results'}")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "joint" in r.stdout and "evaluate" in r.stdout


def test_errors_name_the_full_key_path_and_what_is_expected():
    with pytest.raises(Eve3dError, match=r"^stereo\.mv_views: expected an integer ≥ 1, got 0$"):
        from_mapping(StereoSettings, {"mv_views": 0}, "stereo")
    with pytest.raises(Eve3dError, match=r"^stereo\.mv_views: expected at most stereo\.mv_neighbours \(4\), got 5$"):
        from_mapping(StereoSettings, {"mv_views": 5}, "stereo")
    with pytest.raises(Eve3dError, match=r"^joint\.densify\.refine_every: expected an integer ≥ 1, got 0$"):
        from_mapping(JointSettings, {"densify": {"refine_every": 0}}, "joint")
    with pytest.raises(Eve3dError, match=r"^joint\.densify: unknown key\(s\) refine_evry \(known: .*refine_every"):
        from_mapping(JointSettings, {"densify": {"refine_evry": 10}}, "joint")
    with pytest.raises(Eve3dError, match=r"^stereo\.onnx\.layout: expected one of NCHW, NHWC, got 'CHW'$"):
        from_mapping(StereoSettings, {"onnx": {"layout": "CHW"}}, "stereo")
    with pytest.raises(Eve3dError, match=r"^mesh\.voxel: expected a number > 0, got -0\.5$"):
        from_mapping(MeshSettings, {"voxel": -0.5}, "mesh")
    with pytest.raises(Eve3dError, match=r"^joint\.depth: expected one of depth, depth_expected, got 'mesh'$"):
        JointSettings(depth="mesh")  # a direct call is checked too
    with pytest.raises(Eve3dError, match=r"^pretrain\.equalize"):
        from_mapping(PretrainSettings, {"equalize": 0.5}, "pretrain")


def test_values_are_converted_to_the_declared_kind():
    s = from_mapping(PretrainSettings, {"iterations": 10.0, "reinit_at": [], "resolution": 1,
                                        "lr": {"means": 1e-4}, "background": [1, 1, 1]}, "pretrain")
    assert s.iterations == 10 and type(s.iterations) is int and type(s.resolution) is float
    assert s.reinit_at == () and s.background == (1, 1, 1) and s.lr.means == 1e-4
    assert from_mapping(MeshSettings, {"voxel": None, "largest_cluster": None}, "mesh") == MeshSettings()
    with pytest.raises(Eve3dError, match=r"^pretrain\.iterations: expected an integer ≥ 0, got 10\.5$"):
        from_mapping(PretrainSettings, {"iterations": 10.5}, "pretrain")
    with pytest.raises(Eve3dError, match=r"^mesh\.largest_cluster: expected true or false, got 'yes'$"):
        from_mapping(MeshSettings, {"largest_cluster": "yes"}, "mesh")


def test_a_stage_reads_its_part_of_a_section():
    stereo = from_mapping(StereoSettings, {"baseline": "radius", "sgm_mode": "3way", "mv_views": 2}, "stereo")
    assert pick(BaselineSettings, stereo) == BaselineSettings(baseline="radius")
    assert stereo.sgm_mode == "3way" and stereo.mv_views == 2 and stereo.backend == "sgbm"


def test_the_schema_defaults_agree_with_the_settings():
    """While the schema still carries defaults, each must be the settings class's own, and
    each key it allows a field of the class."""
    schema = yaml.safe_load((REPO / "workflow/schemas/config.schema.yaml").read_text())
    for section, cls in SECTIONS.items():
        node = schema["properties"][section]
        if "$ref" in node:
            node = schema["$defs"][node["$ref"].rsplit("/", 1)[1]]
        defaults = {f.name: getattr(cls(), f.name) for f in dataclasses.fields(cls)}
        for key, prop in node["properties"].items():
            assert key in defaults, f"{section}.{key} is in the schema but not in {cls.__name__}"
            if "default" not in prop:
                continue
            value = defaults[key]
            if dataclasses.is_dataclass(value):
                assert prop["default"] == {}, f"{section}.{key}"
            else:
                assert prop["default"] == (list(value) if isinstance(value, tuple) else value), f"{section}.{key}"
