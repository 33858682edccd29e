"""Workflow configuration: preset merge, the schema's structure check, every section built by
its settings class (``eve3d.core.settings``: defaults and bounds), clear errors.

Precedence (low → high): the settings classes' defaults, ``config/presets/{preset}.yaml``,
the user's config.
"""
from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from eve3d.core.errors import Eve3dError
from eve3d.core.settings_fields import deep_merge

REPO = Path(__file__).resolve().parent.parent
SNAKEFILE = REPO / "workflow" / "Snakefile"
SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"
PRESETS = REPO / "config" / "presets"



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


def with_preset(user: dict, source: str = "config", preset_dir: Path = PRESETS) -> dict:
    """``user`` merged over its preset (``cpu`` unless it names one)."""
    preset_name = user.get("preset", "cpu")
    if preset_name is None:  # a job's resolved sections (job_config)
        return copy.deepcopy(user)
    preset_path = preset_dir / f"{preset_name}.yaml"
    if not preset_path.is_file():
        known = ", ".join(sorted(p.stem for p in preset_dir.glob("*.yaml")))
        raise Eve3dError(f"{source}: preset {preset_name!r} not found in {preset_dir} (known: {known})")
    return deep_merge(yaml.safe_load(preset_path.read_text()) or {}, user)


def resolve_config(user: dict, source: str = "config", schema_path: Path = SCHEMA,
                   preset_dir: Path = PRESETS) -> dict:
    """Merge the preset under ``user``, validate, fill defaults; errors name ``source`` and
    the offending key."""
    config = with_preset(user, source, preset_dir)
    schema = yaml.safe_load(schema_path.read_text())
    errors = sorted(_validator(schema).iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        lines = [f"{'.'.join(map(str, e.absolute_path)) or '(top level)'}: {e.message}" for e in errors]
        raise Eve3dError(f"{source}: invalid configuration:\n  " + "\n  ".join(lines))
    from eve3d.core.datasets import expand_benchmark
    from eve3d.synth import KINDS

    if config.get("only") is not None:  # run some of the scenes (a benchmark's downloaded ones)
        unknown = [s for s in config["only"] if s not in config["scenes"]]
        if unknown:
            raise Eve3dError(f"{source}: only: unknown scene(s) {', '.join(map(str, unknown))} "
                             f"(scenes: {', '.join(config['scenes'])})")
        config["scenes"] = {s: config["scenes"][s] for s in config["only"]}
    config = expand_benchmark(config, source)
    for name, scene in config["scenes"].items():
        if "synthetic" not in scene and "path" not in scene:
            raise Eve3dError(f"{source}: scenes.{name}: give either 'synthetic' (generate it) or 'path' (a dataset)")
        kind = scene.get("synthetic", {}).get("kind")
        if kind is not None and kind not in KINDS:
            raise Eve3dError(f"{source}: scenes.{name}.synthetic.kind: {kind!r} is not one of {', '.join(KINDS)}")
    return with_section_defaults(config, source)


def with_section_defaults(config: dict, source: str = "config") -> dict:
    """Every section of ``eve3d.core.settings.SECTIONS`` built by its settings class (the one
    place its defaults and bounds live) and written back whole; a scene's own ``synthetic``
    and ``evaluate`` keys are checked too. Errors name ``source`` and the key path."""
    import dataclasses

    from eve3d.core.settings import SECTIONS, EvalSettings, SyntheticSettings
    from eve3d.core.settings_fields import from_mapping

    try:
        for section, cls in SECTIONS.items():
            config[section] = dataclasses.asdict(from_mapping(cls, config.get(section) or {}, section))
        for name, scene in config["scenes"].items():
            own = {k: v for k, v in scene.get("synthetic", {}).items() if k != "kind"}
            from_mapping(SyntheticSettings, own, f"scenes.{name}.synthetic")
            if "evaluate" in scene:
                from_mapping(EvalSettings, {**config["evaluate"], **scene["evaluate"]}, f"scenes.{name}.evaluate")
    except Eve3dError as e:
        raise Eve3dError(f"{source}: {e}") from None
    return config


def scene_value(scene: dict, key: str):
    """A dotted key (``dtu.stl``) of a scene's config, or None."""
    for part in key.split("."):
        scene = scene.get(part) if isinstance(scene, dict) else None
    return scene


def has_gt_mesh(scene: dict) -> bool:
    """Whether a workflow scene has a GT mesh (generated scenes bring their own)."""
    return "synthetic" in scene or "gt_mesh" in scene


def named_methods(config: dict, name: str, scores: str | None = None) -> list[str]:
    """The methods scene ``name`` of a resolved workflow ``config`` asks for: its own, else
    the config's, else the default of what its protocol scores (``scores``, or found from the
    scene; ``eve3d.core.methods.default_methods``)."""
    from eve3d.core.methods import default_methods

    scene = config["scenes"][name]
    if scene.get("methods") is not None:
        return list(scene["methods"])
    if config.get("methods") is not None:
        return list(config["methods"])
    return default_methods(scores or scene_protocol(name, scene).scores)


def scene_protocol(name: str, scene: dict):
    """The evaluation protocol (``eve3d.evaluate.Protocol``) of the workflow scene ``name``:
    its ``protocol`` key, else the default of its dataset format when any of that protocol's
    ground truth is given, else ``nvs`` (``eve3d.evaluate.protocol_for``); an error names the
    key when the protocol is unknown or the scene lacks what the protocol needs."""
    from eve3d.core.io.loader import dataset_format, has_poses
    from eve3d.evaluate import protocol_for

    # A generated scene is a COLMAP dataset with exact poses that does not exist yet.
    fmt = "colmap" if "synthetic" in scene else dataset_format(Path(scene["path"]))

    def given(key):
        return scene_value(scene, key) is not None or (key == "gt_mesh" and has_gt_mesh(scene))

    protocol = protocol_for(scene.get("protocol"), fmt, f"scenes.{name}.protocol", given)
    where = f"scenes.{name} (protocol {protocol.name})"
    if protocol.formats and fmt not in protocol.formats:
        raise Eve3dError(f"{where}: {scene.get('path')} is a {fmt} dataset, the protocol scores "
                         f"{' or '.join(protocol.formats)} datasets")
    if protocol.own_poses and "path" in scene and not has_poses(Path(scene["path"])):
        raise Eve3dError(f"{where}: {scene['path']} has no poses, and SfM would pose it in a frame of its own, "
                         f"where its ground truth does not lie; bring the dataset with its poses")
    for key in protocol.config_inputs.values():
        if not given(key):
            raise Eve3dError(f"{where}: give {key}" + (
                ", a GT mesh in the dataset's frame (or protocol: nvs to score held-out views)"
                if key == "gt_mesh" else ""))
    return protocol


def scene_sections(config: Mapping, scene: str) -> dict:
    """``config`` as the jobs of ``scene`` read it: the scene's own ``train`` keys (a
    benchmark's per-scene training resolution) merged over the ``train`` section."""
    own = config["scenes"][scene].get("train")
    return {**config, "train": deep_merge(config.get("train") or {}, own)} if own else dict(config)


def load_config(path: str | Path) -> dict:
    path = Path(path)
    try:
        user = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise Eve3dError(f"{path}: cannot read configuration ({e})") from None
    return resolve_config(user, str(path))


TRAINING_SECTIONS = ("train", "pretrain", "joint")
"""Sections merged per training stage: ``train`` under ``pretrain`` or ``joint``."""


def load_mapping(spec: str, option: str) -> dict:
    """A mapping given on the command line: a YAML/JSON file, or inline JSON (``{...}``)."""
    inline = spec.lstrip().startswith("{")
    source = option if inline else spec
    try:
        value = yaml.safe_load(spec if inline else Path(spec).read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise Eve3dError(f"{source}: cannot read it ({e})") from None
    if not isinstance(value, dict):
        raise Eve3dError(f"{source}: expected a mapping of keys")
    return value


def job_config(spec: str | None = None, overrides: Sequence[str] = (), flags: Mapping[str, Any] | None = None) -> dict:
    """The one route from configuration to a stage's job (``eve3d <stage>``), low → high:
    ``spec`` (a workflow config file, or an inline YAML/JSON mapping: the workflow passes each
    job the resolved sections it reads this way, with ``preset: null``) over its preset (``cpu``
    unless it names one), then the ``SECTION.KEY=VALUE`` overrides (``--set``, values parsed
    as YAML), then ``flags`` (the stage's own flags, by dotted key)."""
    from eve3d.core.settings import SECTIONS

    config = with_preset(load_mapping(spec, "--config") if spec else {}, "--config")
    known = (*TRAINING_SECTIONS, *SECTIONS, "variants")
    parsed = []
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or key.split(".")[0] not in known or "." not in key:
            raise Eve3dError(f"--set {item!r}: expected SECTION.KEY=VALUE with SECTION one of {', '.join(known)}")
        parsed.append((key, yaml.safe_load(value)))
    for key, value in parsed + list((flags or {}).items()):
        *parents, leaf = key.split(".")
        node = config
        for part in parents:
            if node.get(part) is None:
                node[part] = {}
            node = node[part]
            if not isinstance(node, dict):
                raise Eve3dError(f"--set {key}: {part} is not a section")
        node[leaf] = value
    return config


def stage_settings(cls: type, section: str, config: Mapping, overrides: dict | None = None, **fixed: Any) -> Any:
    """A stage's settings from a config: its ``section`` (a training stage's over the shared
    ``train`` section), then ``overrides`` (a method's settings) merged key by key, plus
    ``fixed``; built strictly by ``cls`` (errors name the key path)."""
    from eve3d.core.settings_fields import from_mapping

    training = section in TRAINING_SECTIONS[1:]
    shared = config.get("train") or {} if training else {}
    own = config.get(section) or {}
    # A layer that a higher one may shadow is checked alone too: a value it overrides
    # (train.iterations under the preset's pretrain.iterations, joint's under a variant's) is never
    # read, and a bad one passed without a word.
    for layer, name in ((shared, "train"), (own if overrides else {}, section)):
        if layer:
            from_mapping(cls, layer, where=name)
    values = deep_merge(deep_merge(shared, own), overrides or {})
    values.update(fixed)
    where = f"{section} (train + {section} sections)" if training else section
    return from_mapping(cls, values, where=where)


def method_settings(name: str, config: Mapping, where: str, **fixed: Any) -> Any:
    """The joint stage's settings of the trained method ``name`` (a registered method or a
    variant of ``config``): ``train`` + ``joint``, the method's own settings over them, plus
    ``fixed``. ``where`` names the option that gave the name, for the errors."""
    from eve3d.core.methods import method
    from eve3d.core.settings import JointSettings

    m = method(name, config.get("variants") or {}, where)
    if not m.trains:
        raise Eve3dError(f"{where} {m.name}: {m.summary}; it is not trained by the joint stage")
    return stage_settings(JointSettings, "joint", config, overrides=m.settings, method=m.name, **fixed)
