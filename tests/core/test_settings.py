"""The settings layer: one declaration per setting, checked the same way on every route,
importable (and the workflow plannable) without torch."""
import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import yaml

from eve3d.core.scene import Eve3dError
from eve3d.core.settings import (SECTIONS, BaselineSettings, JointSettings, MeshSettings, PretrainSettings,
                                 RenderSettings, SgbmSettings, StereoSettings)
from eve3d.core.settings_fields import from_mapping, pick
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


def test_defaults_live_once_in_the_settings():
    """The schema holds no leaf default but the workflow's own keys (preset, results, methods,
    training_jobs: no settings class reads them), and a resolved
    config carries every section whole, with the settings classes' defaults."""
    from eve3d.config import resolve_config
    from eve3d.core.settings import SGM_MODES, SgbmSettings

    schema = yaml.safe_load((REPO / "workflow/schemas/config.schema.yaml").read_text())

    def leaf_defaults(node, path=""):
        if isinstance(node, dict):
            if "default" in node and node["default"] != {}:
                yield path
            for key, value in node.items():
                yield from leaf_defaults(value, f"{path}.{key}")
        elif isinstance(node, list):
            for value in node:
                yield from leaf_defaults(value, path)

    assert sorted(leaf_defaults(schema)) == [".properties.methods", ".properties.preset", ".properties.results",
                                          ".properties.training_jobs"]
    config = resolve_config({"scenes": {"a": {"synthetic": {"kind": "object", "views": 8}}},
                             "stereo": {"sgm_mode": "3way"}})
    for section, cls in SECTIONS.items():
        assert set(config[section]) == {f.name for f in dataclasses.fields(cls)}, section
    assert config["stereo"]["sgm_mode"] == "3way" and config["stereo"]["block_size"] == SgbmSettings().block_size
    assert config["synthetic"]["views"] == 32 and config["mesh"]["coarsen"] == 5  # the class's, then the cpu preset's
    for mode in SGM_MODES:
        assert from_mapping(StereoSettings, {"sgm_mode": mode}, "stereo").sgm_mode == mode
    with pytest.raises(Eve3dError, match=r"scenes\.a\.synthetic\.views: expected an integer ≥ 2, got 1"):
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object", "views": 1}}}})
    with pytest.raises(Eve3dError, match=r"scenes\.a\.evaluate\.tau: expected a number > 0, got 0"):
        resolve_config({"scenes": {"a": {"synthetic": {"kind": "object"}, "evaluate": {"tau": 0}}}})


def test_config_readme_tables_are_generated_from_the_settings():
    """config/README.md's key tables are what `python -m eve3d.tools.keydoc` writes, and every key
    has a docstring to fill its row and its CLI help."""
    from eve3d.core.settings_fields import keys, sections_of
    from eve3d.tools.keydoc import README, TABLES, with_tables

    text = README.read_text()
    assert with_tables(text) == text, "config/README.md is out of date: run `python -m eve3d.tools.keydoc`"
    for _, cls in TABLES:
        for c in [cls, *sections_of(cls).values()]:
            assert [k.name for k in keys(c) if not k.doc] == [], c.__name__
    assert "| `mesh.voxel`" not in text and "| `voxel` | `null` | a number > 0 or null |" in text


def test_every_stage_reads_settings_by_one_route(tmp_path):
    """A stage's flags are generated from its settings class and are shorthands of --set; the
    precedence is class default < preset < --config < --set < flag; `preset: null` (what the
    workflow passes) merges no preset."""
    from eve3d.cli import _config, _settings, build_parser
    from eve3d.config import job_config

    parser = build_parser()

    def mesh(*argv):
        a = parser.parse_args(["mesh", "--scene", "s", "--depth", "d", "--out", "m.ply", *argv])
        return _settings(a, MeshSettings, "mesh")

    assert mesh().coarsen == 5  # the cpu preset's
    assert mesh("--config", '{"preset": null}').coarsen == MeshSettings().coarsen
    config = tmp_path / "c.yaml"
    config.write_text("preset: fast\nmesh: {trunc_factor: 3}\n")
    assert (mesh("--config", str(config)).coarsen, mesh("--config", str(config)).trunc_factor) == (2, 3)
    assert mesh("--config", str(config), "--set", "mesh.trunc_factor=2").trunc_factor == 2
    assert mesh("--config", str(config), "--set", "mesh.trunc_factor=2", "--trunc-factor", "1.5").trunc_factor == 1.5
    assert mesh("--no-largest-cluster").largest_cluster is False
    with pytest.raises(Eve3dError, match=r"^mesh\.voxel \(--voxel\): expected a number > 0, got -1\.0$"):
        mesh("--voxel", "-1")
    with pytest.raises(Eve3dError, match=r"^--set 'mesh': expected SECTION\.KEY=VALUE"):
        job_config(None, ["mesh"])
    # every settings class a stage reads has its flags, each named as the key
    helps = {name: p.format_help() for name, p in parser._subparsers._group_actions[0].choices.items()}
    for stage, cls, skip in [("mesh", MeshSettings, ()), ("stereo-render", BaselineSettings, ()),
                             ("pretrain", PretrainSettings, ()), ("joint", JointSettings, ("method", "priors"))]:
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING and f.name not in skip and not f.type.startswith("dict"):
                assert f"--{f.name.replace('_', '-')}" in helps[stage], (stage, f.name)
    # the render settings a model was trained with reach stereo-render
    a = parser.parse_args(["stereo-render", "--scene", "s", "--model", "m", "--out", "o", "--no-antialiased",
                           "--set", "train.backend=torch"])
    rendered = _settings(a, PretrainSettings, "pretrain", _config(a))
    assert (rendered.antialiased, rendered.backend) == (False, "torch")


def test_the_workflow_passes_each_job_its_sections_as_one_argument(tmp_path):
    """Every eve3d job of the default workflow gets its settings as one inline --config with
    `preset: null` and the resolved sections; no settings flag is written by hand."""
    import json
    import shlex

    r = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "-n", "-p", "--config",
                        f"results={tmp_path / 'results'}"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr[-3000:]
    commands = [line for line in r.stdout.splitlines() if " -m eve3d " in line and " summary " not in line]
    assert len(commands) >= 10
    reads = {"synth": {"synthetic"}, "stereo-depth": {"stereo"}, "stereo-render": {"stereo", "pretrain"},
             "pretrain": {"train", "pretrain"}, "joint": {"train", "joint"}, "mesh": {"mesh"},
             "evaluate": {"evaluate", "mesh"}, "report": {"stereo"}}
    for line in commands:
        argv = shlex.split(line.split(" -m eve3d ", 1)[1].split(" > ")[0])
        assert argv.count("--config") == 1, line
        job = json.loads(argv[argv.index("--config") + 1])
        assert job.pop("preset", "missing") is None and set(job) - {"variants"} == reads[argv[0]], line
        flags = [x for x in argv if x.startswith("--")]
        assert set(flags) <= {"--config", "--scene", "--out", "--model", "--depth", "--mesh", "--gt", "--gt-mesh",
                              "--stereo", "--priors", "--method", "--backend", "--protocol", "--exact-depth",
                              "--scene-name", "--kind", "--results", "--dataset"}, line


def test_sgbm_mode_out_of_range_is_named():
    with pytest.raises(Eve3dError, match="stereo.sgm_mode"):
        SgbmSettings(sgm_mode="fast")


def test_training_size_is_capped_by_the_longest_side():
    from eve3d.core.scene import Camera

    cam = Camera("v.png", 4032, 3024, np.eye(3), np.eye(3), np.zeros(3))
    assert RenderSettings(max_side=512).scale(cam) == pytest.approx(512 / 4032)
    assert RenderSettings(resolution=0.1, max_side=512).scale(cam) == pytest.approx(0.1)
    assert RenderSettings(resolution=0.75, max_side=0).scale(cam) == 0.75
