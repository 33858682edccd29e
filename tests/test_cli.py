"""eve3d.cli: each stage's settings from one route (class default < preset < --config < --set < flag)."""
import dataclasses

import pytest

from eve3d.core.errors import Eve3dError
from eve3d.core.settings import JointSettings, MeshSettings, PretrainSettings
from eve3d.core.settings_stereo import BaselineSettings


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
