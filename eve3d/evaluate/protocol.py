"""What a protocol is (:class:`Protocol`) and what one evaluation job is given
(:class:`EvalInputs`). Each protocol module declares its ``PROTOCOL``; the package collects
them into :data:`eve3d.evaluate.PROTOCOLS`."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Scene
from eve3d.core.settings import EvalSettings
from eve3d.core.settings_fields import flag

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
    entry: Callable[[EvalInputs], dict]
    """:class:`EvalInputs` → the metrics."""
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
    check: Callable[[EvalInputs], dict] | None = None
    """Checks, before any training, that the ground truth lines up with the scene's cameras
    (raises :class:`Eve3dError` naming the file; returns what it measured); None: nothing to
    check."""

    def run(self, inputs: EvalInputs) -> dict:
        """Score ``inputs.reconstruction``."""
        return self._call(self.entry, inputs)

    def check_ground_truth(self, inputs: EvalInputs) -> dict:
        """The :attr:`check` of ``inputs`` (no reconstruction needed)."""
        return self._call(self.check, inputs) if self.check else {"protocol": self.name}

    def _call(self, entry: Callable[[EvalInputs], dict], inputs: EvalInputs) -> dict:
        missing = [name for name in self.config_inputs if getattr(inputs, name) is None]
        if missing:
            flags = ", ".join(map(flag, missing))
            raise Eve3dError(f"the {self.name} protocol needs {', '.join(missing)} (eve3d evaluate {flags})")
        fmt = inputs.scene.extras.get("format")
        if self.formats and fmt not in self.formats:
            raise Eve3dError(f"{inputs.scene.root}: the {self.name} protocol needs a {' or '.join(self.formats)} "
                             f"dataset, this one is {fmt}")
        metrics = entry(inputs)
        return {"protocol": self.name, "unit": self.unit, **metrics,
                "evaluator": f"{entry.__module__}.{entry.__qualname__}", "versions": library_versions()}


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
