"""Evaluation stage (``eve3d evaluate``): a reconstruction against ground truth.

One registry, :data:`PROTOCOLS`, names every protocol; the CLI, the config check and the
workflow read names and needs from it. A scene's protocol is its ``protocol:`` key, or the
default of its dataset format (:data:`DEFAULT_PROTOCOL`), never guessed from which other
keys happen to be present, except that a scene without any ground truth of its format's
protocol is scored on held-out views (:data:`WITHOUT_GT`). One module per protocol:

* ``synthetic`` (:mod:`.synthetic`): a scene with a known GT mesh; completeness over the GT
  surface the cameras see, exact point-to-triangle distances.
* ``dtu`` (:mod:`.dtu`): DTUeval-python's semantics, in DTU mm.
* ``tnt`` (:mod:`.tnt`): the Tanks and Temples toolbox, ported to current open3d.
* ``nvs`` (:mod:`.nvs`): held-out PSNR/SSIM of a trained model on every 8th view.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Scene
from eve3d.core.settings import EvalSettings, MeshSettings
from eve3d.core.settings_fields import flag
from eve3d.core.timing import phase


@dataclass
class EvalInputs:
    """What one evaluation job is given; each protocol names the fields it needs."""

    scene: Scene
    reconstruction: Path | None
    """The mesh (``mesh.ply``) or, for protocols that score renderings, the trained model;
    None for a ground-truth check (:meth:`Protocol.check_ground_truth`)."""
    out: Path
    """``metrics.json``; protocols with more artefacts write them beside it."""
    gt: Path | None = None
    """GT mesh (synthetic) or GT point cloud (DTU ``stl…_total.ply``)."""
    obs_mask: Path | None = None
    """DTU ``ObsMask{scan}_10.mat``."""
    plane: Path | None = None
    """DTU ``Plane{scan}.mat``."""
    settings: EvalSettings = field(default_factory=EvalSettings)


@dataclass(frozen=True)
class Protocol:
    name: str
    summary: str
    scores: str
    """What of a method it scores: ``mesh`` (``{method}/mesh.ply``) or ``model``
    (``{method}/point_cloud.ply``: only methods that train Gaussians)."""
    entry: str
    """``module:function`` taking :class:`EvalInputs` and returning the metrics."""
    config_inputs: dict = field(default_factory=dict)
    """:class:`EvalInputs` field → the workflow scene's config key that gives it (each also a
    CLI flag, ``--obs-mask`` for ``obs_mask``)."""
    formats: tuple[str, ...] = ()
    """Dataset formats it applies to (empty: any)."""
    default_of: tuple[str, ...] = ()
    """Dataset formats (``eve3d.core.io.loader.FORMATS``) whose scenes it scores when they
    name no protocol and its ground truth is given (:data:`DEFAULT_PROTOCOL`)."""
    own_poses: bool = False
    """The ground truth lies in the dataset's own frame, so SfM poses (a frame of their own)
    cannot be scored."""
    joint_settings: dict = field(default_factory=dict)
    """What the protocol asks of the joint stage's training (nvs: views held out)."""
    unit: str | None = None
    """The unit of its distances (τ, accuracy, completeness, Chamfer); None: it measures none."""
    check: str = ""
    """``module:function`` that checks, before any training, that the ground truth lines up
    with the scene's cameras (raises :class:`Eve3dError` naming the file; returns what it
    measured); empty: nothing to check."""

    def run(self, inputs: EvalInputs) -> dict:
        """Score ``inputs.reconstruction``."""
        return self._call(self.entry, inputs)

    def check_ground_truth(self, inputs: EvalInputs) -> dict:
        """The :attr:`check` of ``inputs`` (no reconstruction needed)."""
        return self._call(self.check, inputs) if self.check else {"protocol": self.name}

    def _call(self, entry: str, inputs: EvalInputs) -> dict:
        missing = [name for name in self.config_inputs if getattr(inputs, name) is None]
        if missing:
            flags = ", ".join(map(flag, missing))
            raise Eve3dError(f"the {self.name} protocol needs {', '.join(missing)} (eve3d evaluate {flags})")
        fmt = inputs.scene.extras.get("format")
        if self.formats and fmt not in self.formats:
            raise Eve3dError(f"{inputs.scene.root}: the {self.name} protocol needs a {' or '.join(self.formats)} "
                             f"dataset, this one is {fmt}")
        module, function = entry.split(":")
        metrics = getattr(importlib.import_module(f"eve3d.evaluate.{module}"), function)(inputs)
        return {"protocol": self.name, "unit": self.unit, **metrics, "evaluator": f"eve3d.evaluate.{module}.{function}",
                "versions": library_versions()}


SCORING_LIBRARIES = ("eve3d", "open3d", "numpy", "scipy", "torch")
"""Libraries whose versions a score records: published T&T figures differ between the
toolbox on open3d 0.9 and later ports."""


def library_versions() -> dict[str, str]:
    """The versions of :data:`SCORING_LIBRARIES` that this process has loaded (those that
    took part in a score), and the commit of this checkout when it is a git one
    (``eve3d_commit``, ``+dirty`` with uncommitted changes)."""
    import subprocess
    import sys

    versions = {name: sys.modules[name].__version__ for name in SCORING_LIBRARIES if name in sys.modules}
    repo = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(repo), "describe", "--always", "--dirty=+dirty", "--abbrev=12"],
                                capture_output=True, text=True, timeout=10)
        if commit.returncode == 0 and commit.stdout.strip():
            versions["eve3d_commit"] = commit.stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        pass  # no git: the package version stands alone
    return versions


PROTOCOLS: dict[str, Protocol] = {p.name: p for p in (
    Protocol("synthetic", "GT mesh: visible GT surface, exact point-to-triangle distances, F-score at τ",
             "mesh", "synthetic:evaluate_synthetic", {"gt": "gt_mesh"}, default_of=("colmap",), own_poses=True,
             unit="scene units"),
    Protocol("dtu", "DTUeval-python: mask culling, 0.2 mm sampling, ObsMask crop, Chamfer in mm",
             "mesh", "dtu:evaluate_dtu", {"gt": "dtu.stl", "obs_mask": "dtu.obs_mask", "plane": "dtu.plane"},
             formats=("dtu",), default_of=("dtu",), unit="mm", check="dtu:check_alignment"),
    Protocol("tnt", "Tanks and Temples toolbox: trajectory alignment, ICP, polygon crop, F-score at τ",
             "mesh", "tnt:evaluate_tnt", formats=("tnt",), default_of=("tnt",), own_poses=True, unit="m",
             check="tnt:check_alignment"),
    Protocol("nvs", "held-out views (every 8th, Mip-NeRF 360): PSNR and SSIM of the rendered model",
             "model", "nvs:evaluate_views", joint_settings={"holdout": 8}),
)}

GIVEN_TAU = "given (evaluate.tau)"
"""``tau_rule`` of a τ the user set."""

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


def check(settings: EvalSettings, *, scene: Path, out: Path, protocol: str | None = None,
          ground_truth: Mapping[str, Path | None]) -> None:
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


def run(settings: EvalSettings, mesh_settings: MeshSettings, *, scene: Path, out: Path, protocol: str | None = None,
        ground_truth: Mapping[str, Path | None], mesh: Path | None = None, model: Path | None = None,
        depth: Path | None = None, exact_depth: Path | None = None, row: Mapping[str, str] | None = None) -> None:
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

