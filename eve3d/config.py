"""Workflow configuration: preset merge, JSON-schema validation with defaults, clear errors.

Precedence (low → high): schema defaults, ``config/presets/{preset}.yaml``, the user's config.
"""
from __future__ import annotations

import copy
from pathlib import Path

import yaml

from eve3d.scene import Eve3dError

REPO = Path(__file__).resolve().parent.parent
SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"
PRESETS = REPO / "config" / "presets"


def deep_merge(base: dict, override: dict) -> dict:
    """``override`` on top of ``base``, recursively for nested mappings."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _validator(schema: dict):
    """A draft 2020-12 validator that also fills in schema defaults."""
    from jsonschema import Draft202012Validator, validators

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if "default" in sub and name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
        yield from Draft202012Validator.VALIDATORS["properties"](validator, properties, instance, schema)

    return validators.extend(Draft202012Validator, {"properties": set_defaults})(schema)


def resolve_config(user: dict, source: str = "config", schema_path: Path = SCHEMA,
                   preset_dir: Path = PRESETS) -> dict:
    """Merge the preset under ``user``, validate, fill defaults; errors name ``source`` and
    the offending key."""
    preset_name = user.get("preset", "cpu")
    preset_path = preset_dir / f"{preset_name}.yaml"
    if not preset_path.is_file():
        known = ", ".join(sorted(p.stem for p in preset_dir.glob("*.yaml")))
        raise Eve3dError(f"{source}: preset {preset_name!r} not found in {preset_dir} (known: {known})")
    config = deep_merge(yaml.safe_load(preset_path.read_text()) or {}, user)
    schema = yaml.safe_load(schema_path.read_text())
    errors = sorted(_validator(schema).iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        lines = [f"{'.'.join(map(str, e.absolute_path)) or '(top level)'}: {e.message}" for e in errors]
        raise Eve3dError(f"{source}: invalid configuration:\n  " + "\n  ".join(lines))
    for name, scene in config["scenes"].items():
        if "synthetic" not in scene and "path" not in scene:
            raise Eve3dError(f"{source}: scenes.{name}: give either 'synthetic' (generate it) or 'path' (a dataset)")
    return config


def load_config(path: str | Path) -> dict:
    path = Path(path)
    try:
        user = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise Eve3dError(f"{path}: cannot read configuration ({e})") from None
    return resolve_config(user, str(path))
