"""eve3d.tools.bench.degrade: the table of ``eve3d bench degrade`` from a finished run's
profiles, and a config whose profiles are wrong refused before any job."""
import json

import pytest
import yaml

from eve3d.core.errors import Eve3dError
from eve3d.tools.bench.degrade import PROFILES_DIR, run_bench_degrade


def bench_config(tmp_path, profiles) -> str:
    path = tmp_path / "degrade.yaml"
    path.write_text(yaml.safe_dump({"preset": "cpu", "results": str(tmp_path / "results"), "methods": ["pgsr", "eve3d"],
                                    "scenes": {"obj": {"synthetic": {"kind": "object"}}}, "profiles": profiles}))
    return str(path)


def test_the_table_has_each_profiles_f_and_errors(tmp_path, capsys):
    """Two finished profiles (their rows as the bench keeps them), one not run: a row each for
    those that ran, F per scene and method, and the errors each put into the exact depth."""
    config = bench_config(tmp_path, {"exact": {}, "noisy": {"noise": 0.02, "holes": 0.5}, "later": {"outliers": 0.1}})
    folder = tmp_path / "results" / PROFILES_DIR
    folder.mkdir(parents=True)
    for name, f in (("exact", 0.95), ("noisy", 0.81)):
        rows = [{"scene": "obj", "method": "eve3d", "fscore": str(f)}, {"scene": "obj", "method": "pgsr", "fscore": "0.8"}]
        (folder / f"{name}.json").write_text(json.dumps(rows))
    run_bench_degrade(config, report_only=True)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["F", "obj/eve3d", "obj/pgsr", "errors"]
    assert lines[2].split() == ["exact", "0.9500", "0.8000", "none", "(exact)"]
    assert lines[3].split() == ["noisy", "0.8100", "0.8000", "holes", "0.5,", "noise", "0.02"] and len(lines) == 4
    run_bench_degrade(config, report_only=True, as_json=True)
    assert json.loads(capsys.readouterr().out)["rows"]["noisy"][0]["fscore"] == "0.81"


def test_a_wrong_profile_is_named_before_any_job(tmp_path):
    with pytest.raises(Eve3dError, match=r"\(profile bad\): stereo\.oracle: unknown key\(s\) nois "):
        run_bench_degrade(bench_config(tmp_path, {"exact": {}, "bad": {"nois": 0.02}}))
    with pytest.raises(Eve3dError, match=r"profile big.*stereo\.oracle\.holes"):
        run_bench_degrade(bench_config(tmp_path, {"big": {"holes": 2}}))
    with pytest.raises(Eve3dError, match="profiles: expected a mapping"):
        run_bench_degrade(bench_config(tmp_path, []))
    assert not (tmp_path / "results").exists()
