"""Methods: the one registry of reconstruction methods that the CLI, the config check and
the workflow read.

A method either fuses depth maps that another stage made (``oracle``: the exact depth of a
GT mesh; ``stereo-tsdf``: the stereo priors as they are), or is trained by the joint stage.
A trained method is nothing but settings of :class:`eve3d.core.settings.JointSettings` over the
config's ``train`` and ``joint`` sections: the joint stage has one loss whose parts the
settings switch on and off, so a new variant is a few lines of config, not a new branch::

    variants:
      eve3d-no-prior: {method: eve3d, prior_weight: 0}

A variant names the method it starts from and the settings it changes; it gets its own
results folder and summary row. A variant under a registered name (no ``method`` key)
changes that method's settings (the ``cpu`` preset scales ``eve3d-fast`` down this way).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from eve3d.core.errors import Eve3dError
from eve3d.core.settings_fields import deep_merge

GAUSSIAN_DEVICE = "gpu"
"""What a cluster job that trains or renders Gaussians asks for (gsplat on CUDA); the CPU
rasteriser runs anywhere, so a job given no GPU still runs."""


@dataclass(frozen=True)
class Method:
    name: str
    summary: str
    fuses: str | None = None
    """Depth fused as it is, without training: ``oracle`` or ``priors``; None = trained."""
    settings: Mapping[str, Any] = field(default_factory=dict)
    """Joint-stage settings (``eve3d.core.settings.JointSettings`` keys) over the config's sections."""

    @property
    def trains(self) -> bool:
        return self.fuses is None

    @property
    def upper_bound(self) -> bool:
        """It fuses the exact depth: a ceiling for the others, not one of them (the report
        does not rank it)."""
        return self.fuses == "oracle"

    @property
    def device(self) -> str:
        """What a cluster job of the method asks for: trained methods train on a GPU, fusing
        depth made elsewhere needs none."""
        return GAUSSIAN_DEVICE if self.trains else "cpu"

    @property
    def needs_priors(self) -> bool:
        """Whether the method reads the stereo priors (``priors/{stereo.backend}``)."""
        return self.fuses == "priors" or uses_priors(self.settings)


# The PGSR loss with its planar and multi-view parts switched off is 3DGS's L_rgb.
_PHOTOMETRIC_ONLY = {"scale_weight": 0.0, "dn_weight": 0.0, "geo_weight": 0.0, "ncc_weight": 0.0, "exposure": False}

REGISTRY: dict[str, Method] = {m.name: m for m in (
    Method("oracle", "TSDF of the exact depth of the GT mesh (an upper bound; scenes with a GT mesh)",
           fuses="oracle"),
    Method("stereo-tsdf", "TSDF of the stereo priors as they are (the GS2Mesh-style baseline)", fuses="priors"),
    Method("3dgs", "3DGS: isotropic initial Gaussians, L_rgb only, split by the plain 2D-mean gradient, meshed from the"
           " expected depth",
           settings={**_PHOTOMETRIC_ONLY, "depth": "depth_expected", "densify": {"absgrad": False},
                     "init_thickness": 1.0}),  # 3DGS starts from isotropic balls
    Method("pgsr", "PGSR: planar Gaussians, flattening, depth–normal and multi-view (rendered neighbour) losses"),
    Method("prior-fixed", "PGSR + L_prior towards the fixed stereo depth D* (the paper's 'PGSR + FoundationStereo'):"
           " no learnable priors, no LBA", settings={"priors": "fixed", "lba_weight": 0.0}),
    Method("eve3d-paper", "Eve3D as published: Gaussians from the prior depths; L_prior; learnable priors D̂ with"
           " L_pull; the LBA of the depth against K neighbours' D̂ (in place of PGSR's rendered neighbour)",
           settings={"init": "priors", "priors": "learnable", "geo_weight": 0.0, "ncc_weight": 0.0}),
    # Measured on every generated kind (docs/results.md, "Eve3D against PGSR, honestly
    # started"): the LBA costs F with stereo priors, PGSR's rendered-neighbour terms do not;
    # docs/method.md, "Choices", says why. With priors from real photo pairs the prior-point
    # start pays along the whole prior-quality curve (issue 77: docs/results.md, "eve3d on the
    # prior-quality curve"); the SfM points beside the prior points seed what the priors
    # refuse, such as a floor's far edge. The opacity loss runs while densification prunes: it
    # removes the floaters, and stops before it only thins the surfaces (docs/method.md, "Choices").
    Method("eve3d", "Eve3D as measured best here: Gaussians from the prior depths and the SfM points,"
           " PGSR's multi-view terms, L_prior towards learnable priors D̂ (initialised from D*) with L_pull,"
           " an opacity loss while densifying; no LBA (eve3d-paper has it)",
           settings={"init": "both", "priors": "learnable", "lba_weight": 0.0, "opacity_weight": 0.05,
                     "opacity_while_densifying": True}),
)}

# Variants that ship with the code: the paper's fast schedule and its Table 4 ablations (of the
# paper's method).
BUILTIN_VARIANTS: dict[str, dict[str, Any]] = {
    "eve3d-fast": {"method": "eve3d", "iterations": 5000, "joint_from": 1000, "dn_from": 1000,
                   "densify": {"refine_stop": 4000}},
    "eve3d-prior-loss": {"method": "eve3d-paper", "priors": "fixed", "lba_weight": 0.0},  # Table 4: prior loss only
    "eve3d-fixed-lba": {"method": "eve3d-paper", "priors": "fixed"},  # Table 4: prior loss + LBA, fixed priors
}


DEFAULT_METHODS = ("oracle", "stereo-tsdf", "pgsr", "eve3d")
"""A scene's methods when the config names none and ground truth scores the mesh: the
ceiling, the priors fused as they are, the baseline and ours."""
PHOTO_METHODS = ("eve3d",)
"""A scene's methods when the config names none and only held-out photos score it (the
``nvs`` protocol: a user's photos): the one mesh a user wants, without the baseline's
training beside it (``methods: [pgsr, eve3d]`` adds it)."""


def default_methods(scores: str) -> list[str]:
    """The methods of a scene whose config names none, by what its protocol scores
    (``eve3d.evaluate.Protocol.scores``: ``mesh`` or ``model``)."""
    return list(PHOTO_METHODS if scores == "model" else DEFAULT_METHODS)


def uses_priors(settings: Mapping[str, Any]) -> bool:
    """Whether joint settings (all of them, or a method's changes) read the stereo priors."""
    return settings.get("priors", "none") != "none" or settings.get("init") in ("priors", "both")


def methods(variants: Mapping[str, Mapping] | None = None) -> dict[str, Method]:
    """The registry with the config's ``variants`` applied (new names added, registered
    names' settings changed); an error names the variant that is wrong."""
    out = dict(REGISTRY)
    pending = deep_merge(BUILTIN_VARIANTS, dict(variants or {}))
    while pending:  # a variant may start from another variant
        progress = False
        for name, spec in list(pending.items()):
            if not isinstance(spec, Mapping):
                raise Eve3dError(f"variants.{name}: expected a mapping of joint settings, got {spec!r}")
            base_name = spec.get("method", name if name in REGISTRY else None)
            if base_name == name and name not in REGISTRY:
                raise Eve3dError(f"variants.{name}: a variant cannot start from itself")
            if base_name is None:
                raise Eve3dError(f"variants.{name}: say which method it starts from ({{method: NAME, ...}}; "
                                 f"methods: {', '.join(out)})")
            if base_name in pending and base_name != name:
                continue
            if base_name not in out:
                raise Eve3dError(f"variants.{name}.method: unknown method {base_name!r} (methods: {', '.join(out)})")
            base = out[base_name]
            changes = {k: v for k, v in spec.items() if k != "method"}
            if not base.trains and changes:
                raise Eve3dError(f"variants.{name}: {base_name} is not trained, it has no settings to change")
            summary = base.summary if name == base_name else f"{base_name} with {_describe(changes)}"
            out[name] = Method(name, summary, base.fuses, deep_merge(dict(base.settings), changes))
            del pending[name]
            progress = True
        if not progress:
            raise Eve3dError(f"variants: {', '.join(pending)} start from one another in a cycle")
    return out


def _describe(changes: Mapping) -> str:
    return ", ".join(f"{k}={v}" for k, v in changes.items()) or "no changes"


def method(name: str, variants: Mapping[str, Mapping] | None = None, where: str = "method") -> Method:
    """One method by name; an error lists the known ones."""
    known = methods(variants)
    if name not in known:
        raise Eve3dError(f"{where}: unknown method {name!r} (methods: {', '.join(known)}; "
                         f"define others under variants:)")
    return known[name]
