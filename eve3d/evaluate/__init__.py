"""Evaluation stage (``eve3d evaluate``): a reconstruction against ground truth.

One registry, :data:`PROTOCOLS`, names every protocol; the CLI, the config check and the
workflow read names and needs from it. One module per protocol (``synthetic``, ``dtu``,
``tnt``, ``nvs``), each declaring its ``PROTOCOL`` (a :class:`~eve3d.evaluate.protocol.Protocol`):
the registry is what this package's modules declare, so a protocol is added by its module
alone. A scene's protocol is its ``protocol:`` key, or the default of its dataset format
(:data:`DEFAULT_PROTOCOL`), never guessed from which other keys happen to be present, except
that a scene without any ground truth of its format's protocol is scored on held-out views
(:data:`WITHOUT_GT`).
"""
from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Mapping
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Scene
from eve3d.core.settings import EvalSettings, MeshSettings
from eve3d.core.timing import phase
from eve3d.evaluate.protocol import EvalInputs, Protocol


def _declared_protocols() -> dict[str, Protocol]:
    """The ``PROTOCOL`` of each module of this package that declares one, by module name."""
    modules = (importlib.import_module(f"{__name__}.{info.name}") for info in pkgutil.iter_modules(__path__))
    return {p.name: p for p in (getattr(module, "PROTOCOL", None) for module in modules) if p is not None}


PROTOCOLS: dict[str, Protocol] = _declared_protocols()
"""Every protocol, by name (in the order of their modules' names)."""

DEFAULT_PROTOCOL: dict[str, str] = {fmt: p.name for p in PROTOCOLS.values() for fmt in p.default_of}
"""Protocol of each dataset format (``eve3d.core.io.loader.dataset_format``) when its ground truth
is given and a scene names none."""

GROUND_TRUTH_INPUTS: dict[str, dict[str, str]] = {
    name: {p.name: p.config_inputs[name] for p in PROTOCOLS.values() if name in p.config_inputs}
    for name in dict.fromkeys(name for p in PROTOCOLS.values() for name in p.config_inputs)}
"""Each ground-truth input of the protocols (an :class:`EvalInputs` field, and the CLI flag of
``eve3d evaluate``) → {protocol: the workflow scene's config key that gives it}."""

WITHOUT_GT = "nvs"
"""The default protocol of a scene whose format's protocol has none of its ground truth
(a folder of photos): held-out views need nothing but the photos."""


def protocol_for(name: str | None, dataset_format: str, where: str = "protocol",
                 given: Callable[[str], bool] = lambda key: True) -> Protocol:
    """The protocol called ``name``, or when None the default of ``dataset_format`` if
    ``given`` says any of its ground-truth inputs (a config key of ``config_inputs``) is
    given, else :data:`WITHOUT_GT` (a protocol with no such inputs counts as given: T&T's
    files lie in the dataset)."""
    if name is None:
        default = PROTOCOLS[DEFAULT_PROTOCOL[dataset_format]]
        keys = default.config_inputs.values()
        name = default.name if not keys or any(map(given, keys)) else WITHOUT_GT
    if name not in PROTOCOLS:
        raise Eve3dError(f"{where}: unknown protocol {name!r}; choose one of {', '.join(PROTOCOLS)}")
    return PROTOCOLS[name]


def _inputs(scene: Path, protocol: str | None, ground_truth: Mapping[str, Path | None]) -> tuple[Protocol, Scene, dict]:
    """The protocol of a job (its default counts the ``ground_truth`` given), the scene, and
    :class:`EvalInputs`' ground-truth fields as Paths."""
    from eve3d.core.io import load_scene

    loaded = load_scene(scene, check_images=False)
    fields = {key: name for name, keys in GROUND_TRUTH_INPUTS.items() for key in keys.values()}
    chosen = protocol_for(protocol, loaded.extras.get("format", "colmap"), "--protocol",
                          lambda key: ground_truth.get(fields[key]) is not None)
    return chosen, loaded, {k: Path(v) if v else None for k, v in ground_truth.items()}


def run_ground_truth_check(settings: EvalSettings, *, scene: Path, out: Path,
                           protocol: str | None = None, ground_truth: Mapping[str, Path | None]) -> None:
    """The ``check_ground_truth`` rule: that the ground truth (:class:`EvalInputs` fields
    ``gt``, ``obs_mask``, ``plane``) lines up with ``scene``'s cameras, written to ``out``;
    ``settings.ground_truth_check`` says whether a misfit fails, warns or is not looked for."""
    import json
    import sys

    from eve3d.core.fileio import atomic_path

    chosen, loaded, gt = _inputs(scene, protocol, ground_truth)
    checked = {"protocol": chosen.name, "check": settings.ground_truth_check}
    if settings.ground_truth_check != "off":
        try:
            checked.update(chosen.check_ground_truth(EvalInputs(loaded, None, Path(out), **gt, settings=settings)))
            print(f"the ground truth of {scene} lines up with its cameras ({chosen.name} protocol): "
                  + ", ".join(f"{k} {v:.3g}" for k, v in checked.items() if isinstance(v, float)))
        except Eve3dError as e:
            if settings.ground_truth_check == "error":
                raise Eve3dError(f"{e} (evaluate.ground_truth_check: warn or off goes on regardless)") from None
            print(f"warning: {e}", file=sys.stderr)
            checked["warning"] = str(e)
    with atomic_path(Path(out)) as tmp:
        tmp.write_text(json.dumps(checked, indent=2))


def run_evaluate(settings: EvalSettings, mesh_settings: MeshSettings, *, scene: Path, out: Path,
                 protocol: str | None = None, ground_truth: Mapping[str, Path | None], mesh: Path | None = None,
                 model: Path | None = None, depth: Path | None = None, exact_depth: Path | None = None,
                 row: Mapping[str, str] | None = None) -> None:
    """The ``evaluate`` stage: score ``mesh`` (or the trained ``model``, as the protocol asks)
    against the ground truth into ``out`` (metrics.json), with the accuracy of the ``depth``
    maps it fused against ``exact_depth`` (the pixels ``mesh_settings`` fuses,
    :func:`eve3d.core.maps.fusable`);
    ``row`` (scene, method) names the record."""
    import json

    from eve3d.core.fileio import atomic_path
    from eve3d.core.layout import EVALUATION, RECORD, format_table

    with phase("read scene"):
        chosen, loaded, gt = _inputs(scene, protocol, ground_truth)
    reconstruction = model if chosen.scores == "model" else mesh
    if reconstruction is None:
        needed = "--model (a trained point_cloud.ply)" if chosen.scores == "model" else "--mesh"
        raise Eve3dError(f"the {chosen.name} protocol scores a {chosen.scores}: give {needed}")
    if bool(depth) != bool(exact_depth):
        raise Eve3dError("--depth and --exact-depth go together: the maps the mesh fused, and the exact depth of "
                         "the same views")
    with phase("score"):
        metrics = chosen.run(EvalInputs(loaded, Path(reconstruction), Path(out), **gt, settings=settings))
    if depth:
        from eve3d.evaluate.depth import depth_accuracy

        with phase("depth accuracy"):
            acc = depth_accuracy(Path(depth), Path(exact_depth), min_confidence=mesh_settings.min_confidence)
        metrics.update({"depth_signed_error": acc["median_signed_error"], "depth_error": acc["median_rel_error"],
                        "depth_density": acc["density"], "depth_on_empty": acc["on_empty"], "depth_maps": str(depth)})
    if "tau" in metrics:
        print(f"tau = {metrics['tau']:.5g} ({metrics['tau_rule']})")
    metrics.update(row or {})
    with atomic_path(Path(out)) as tmp:
        tmp.write_text(json.dumps({RECORD: EVALUATION, **metrics}, indent=2))
    print(format_table([metrics]))

