"""``eve3d bench degrade``: the methods against priors of known quality. The exact depth
(the ``oracle`` backend) with the errors a stereo prior makes (``stereo.oracle``: noise,
outliers, a depth on the empty background, a bias on weak texture, holes), one profile of
errors at a time, so that what costs a method its lead is told apart from the network that
made the prior.

The bench's config is a workflow config with one key more, ``profiles``: name → the
``stereo.oracle`` mapping. Every profile runs the workflow into the same results folder, so
what does not read the priors (``pgsr``, the scenes) runs once; each profile's rows are kept
in ``{results}/profiles/{name}.json`` beside the config it ran, and the table gathers them."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

from eve3d.core.errors import Eve3dError

PROFILES_DIR = "profiles"
"""Where, under the bench's results folder, each profile's rows are kept."""


def profile_rows(results: Path, names) -> dict[str, list[dict]]:
    """The rows of ``summary.csv`` each finished profile of ``names`` left (name → rows)."""
    folder = Path(results) / PROFILES_DIR
    return {name: json.loads((folder / f"{name}.json").read_text()) for name in names
            if (folder / f"{name}.json").is_file()}


def format_degrade_table(profiles: dict[str, dict], rows: dict[str, list[dict]]) -> str:
    """F per profile (rows) and scene × method (columns), each profile's errors beside it."""
    columns = list(dict.fromkeys((r["scene"], r["method"]) for rs in rows.values() for r in rs))
    names = [f"{scene}/{method}" for scene, method in columns]
    head = f"{'F':<16} " + " ".join(f"{n:>{max(len(n), 6)}}" for n in names) + "  errors"
    lines = [head, "-" * len(head)]
    for name, rs in rows.items():
        f = {(r["scene"], r["method"]): r.get("fscore") for r in rs}
        cells = " ".join(f"{'-' if f.get(c) in (None, '') else format(float(f[c]), '.4f'):>{max(len(n), 6)}}"
                         for c, n in zip(columns, names))
        errors = ", ".join(f"{k} {v:g}" for k, v in (profiles.get(name) or {}).items()) or "none (exact)"
        lines.append(f"{name:<16} {cells}  {errors}")
    return "\n".join(lines)


def run_bench_degrade(config_file: str, cores: int = 2, report_only: bool = False, as_json: bool = False) -> None:
    """Run the bench's config once per profile (unless ``report_only``), then print the table.
    Every profile's config is checked before the first runs."""
    import csv

    from eve3d.config import SNAKEFILE, resolve_config
    from eve3d.core.fileio import atomic_path
    from eve3d.core.layout import Layout

    try:
        raw = yaml.safe_load(Path(config_file).read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise Eve3dError(f"{config_file}: cannot read the bench's config ({e})") from None
    profiles = raw.pop("profiles", None)
    if not isinstance(profiles, dict) or not profiles:
        raise Eve3dError(f"{config_file}: profiles: expected a mapping of name → stereo.oracle errors")
    configs = {name: {**raw, "stereo": {**raw.get("stereo", {}), "backend": "oracle", "oracle": errors or {}}}
               for name, errors in profiles.items()}
    for name, config in configs.items():  # a wrong key stops here, naming it, before any job
        resolve_config(config, f"{config_file} (profile {name})")
    results = Path(resolve_config(configs[next(iter(configs))], config_file)["results"])
    for name, config in ({} if report_only else configs).items():
        config_path = results / PROFILES_DIR / f"{name}.yaml"
        with atomic_path(config_path) as tmp:
            tmp.write_text(yaml.safe_dump(config))
        print(f"profile {name}: {profiles[name] or 'exact'}", file=sys.stderr, flush=True)
        cmd = [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", str(config_path),
               "--replace-workflow-config", f"-c{cores}", "--quiet", "rules", "progress"]
        if subprocess.run(cmd).returncode != 0:
            raise Eve3dError(f"profile {name} of {config_file} failed (its logs: {Layout(results).logs()}/)")
        with open(Layout(results).summary(), newline="") as summary:
            rows = list(csv.DictReader(summary))
        with atomic_path(results / PROFILES_DIR / f"{name}.json") as tmp:
            tmp.write_text(json.dumps(rows))
    rows = profile_rows(results, profiles)
    print(json.dumps({"profiles": profiles, "rows": rows}, indent=2) if as_json else format_degrade_table(profiles, rows))
