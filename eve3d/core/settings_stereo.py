"""The ``stereo`` section's settings, declared once (as :mod:`eve3d.core.settings` declares the
other sections'): the sources of the priors, the virtual baseline, SGBM's settings, the
confidence checks and each network's options. Importable without torch."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera
from eve3d.core.settings_fields import Checked, setting

SGM_MODES = {"hh": "STEREO_SGBM_MODE_HH", "hh4": "STEREO_SGBM_MODE_HH4", "3way": "STEREO_SGBM_MODE_SGBM_3WAY",
             "sgbm": "STEREO_SGBM_MODE_SGBM"}
"""``stereo.sgm_mode`` → OpenCV's StereoSGBM mode: 8 directions in two passes (``hh``), 4
(``hh4``), or the single-pass variants (``3way``, ``sgbm``)."""
BASELINE_MODES = ("disparity", "radius")
PAIR_SOURCES = ("virtual", "real", "both")


@dataclass(frozen=True)
class PriorBackend:
    """A source of the stereo priors (``stereo.backend``): one row of :data:`PRIOR_BACKENDS`."""

    name: str
    module: str
    """Where it lives. A backend that reads the virtual stereo pairs has ``matcher(settings)``
    there (the ``stereo`` settings in, ``matcher(left, right, (min, max))`` → disparity and
    confidence out, for :func:`eve3d.stereo.stereo_priors`); one that reads the GT mesh has
    ``priors_from_mesh(scene, out, mesh, preview, settings)``."""
    device: str
    """What its cluster job asks for: ``cpu``, or ``gpu`` for a network (onnxruntime's CUDA
    provider where it has one; the CPU otherwise)."""
    label: str
    """Its name on the progress bar."""
    summary: str
    reads: str = "pairs"
    """``pairs``: the virtual stereo pairs of ``stereo-render``; ``gt_mesh``: the scene's GT mesh."""


PRIOR_BACKENDS: dict[str, PriorBackend] = {b.name: b for b in (
    PriorBackend("sgbm", "eve3d.priors.sgbm", "cpu", "SGBM",
                 "OpenCV's semi-global block matching, left–right checked and gated by texture (no weights)"),
    PriorBackend("mccnn", "eve3d.priors.mccnn", "cpu", "MC-CNN",
                 "MC-CNN fast's learned matching costs (the mccnn wheel's Middlebury weights) with SGM"),
    PriorBackend("onnx", "eve3d.priors.onnx", "gpu", "ONNX stereo",
                 "any stereo network exported to ONNX, described by stereo.onnx (PSMNet: eve3d export-stereo)"),
    PriorBackend("hitnet", "eve3d.priors.hitnet", "gpu", "HITNet",
                 "HITNet's ONNX export, run by the path in stereo.hitnet.model (the ETH3D weights)"),
    PriorBackend("oracle", "eve3d.priors.oracle", "cpu", "oracle depth",
                 "the exact depth of a scene with a GT mesh, by ray casting (an upper bound)", reads="gt_mesh"),
)}
"""Every source of the stereo priors, declared once: the stage, the workflow (a job's device
and inputs), the CLI's help and the config check read it. A new backend is its module in
``eve3d/priors/`` and a row here (and, if it takes options, a settings class below and its
field on :class:`StereoSettings`)."""


@dataclass
class BaselineSettings(Checked):
    """Each view's baseline B (DESIGN §2); the fields are the ``stereo.*`` config keys.
    ``baseline: radius``: the paper's B = ``baseline_factor`` × the scene radius, one B for
    every view. ``baseline: disparity``: B per view, so that a point at the view's median
    rendered depth Z has the disparity ``target_disparity`` × image width, bounded by
    B ≤ ``max_baseline`` × Z (a vergence of at most 2·atan(max_baseline / 2), so occlusions
    stay small). A radius-based B gives an inside-out capture, whose camera radius is far
    smaller than the distance to the walls, disparities of a few pixels."""

    SECTION: ClassVar[str] = "stereo"
    baseline: str = setting("disparity", choices=BASELINE_MODES)
    """How each view's virtual baseline B is set: ``disparity`` = per view, for ``target_disparity`` at its median rendered depth Z, at most ``max_baseline`` × Z; ``radius`` = the paper's B = ``baseline_factor`` × scene radius for every view."""
    baseline_factor: float = setting(0.07, gt=0)
    """radius mode: B = factor × scene radius."""
    target_disparity: float = setting(0.08, gt=0)
    """disparity mode: disparity at the view's median depth, fraction of the image width."""
    max_baseline: float = setting(0.15, gt=0)
    """disparity mode: B at most this fraction of the view's median depth."""

    def of_view(self, cam: Camera, radius: float, median_depth: float) -> float:
        if self.baseline == "radius":
            return self.baseline_factor * radius
        return min(self.target_disparity * cam.width / cam.fx, self.max_baseline) * median_depth


@dataclass
class SgbmSettings(Checked):
    """OpenCV StereoSGBM (P1 = 8·3·b², P2 = 32·3·b², DESIGN §6)."""

    SECTION: ClassVar[str] = "stereo"
    sgm_mode: str = setting("hh", choices=tuple(SGM_MODES))
    """Cost aggregation (``SGM_MODES``). ``hh`` aggregates along 8 directions in two
    passes; the single-pass modes (``3way``, ``sgbm``) only along the directions a pass from
    the top can see, none from below, and on a surface slanted from top to bottom they
    carry one end's disparity into the other: on exact right views of the object scene the
    depth comes out 0.19 % (``3way``) and 0.61 % (``sgbm``) too far, −0.04 % with ``hh``.
    ``hh`` keeps two costs per pixel and disparity (W·H·D·4 bytes: 2.1 GB at 1080×1920 with
    256 disparities)."""
    block_size: int = setting(5, ge=1)
    """SGBM block size b (P1 = 8·3·b², P2 = 32·3·b²)."""
    uniqueness: int = setting(10, ge=0)
    """SGBM uniqueness ratio (%)."""
    speckle_window: int = setting(100, ge=0)
    """SGBM speckle filter: largest connected region of similar disparity treated as noise (px; 0 = off)."""
    speckle_range: int = setting(2, ge=0)
    """SGBM speckle filter: disparity variation within a connected region."""
    lr_threshold: float = setting(1.0, gt=0)
    """Left–right check: keep pixels whose two disparities differ by at most this (px)."""
    min_texture: float = setting(0.5, ge=0)
    """Pixels whose grey-level standard deviation over the block (0–255 scale) is below this
    are not confident: SGM's path aggregation fills flat regions (an empty black background)
    with disparities that pass the left–right check but mean nothing."""
    wls: bool = False
    """Edge-aware WLS filtering of the disparity (dense); the confidence becomes the filter's
    own confidence map / 255 (its left–right check, lowered near depth edges)."""
    wls_lambda: float = setting(8000.0, gt=0)
    """WLS smoothness weight (OpenCV's default)."""
    wls_sigma: float = setting(1.5, gt=0)
    """WLS colour sensitivity (OpenCV's default)."""


@dataclass
class MatchCheck(Checked):
    """Checks every backend's confidence passes through, independent of the matcher agreeing
    with itself (a left–right check passes a consistent but wrong match)."""

    SECTION: ClassVar[str] = "stereo"
    ncc_threshold: float = setting(0.5, ge=0, le=1)
    """Confident only where the photo and the right view warped back by the disparity agree:
    their NCC over ``ncc_window``² pixels is at least this (0 = off)."""
    ncc_window: int = setting(7, ge=3)
    """Window of both NCC checks in pixels (odd)."""
    range_margin: float = setting(1.0, ge=0)
    """Not confident within this many px of either end of the disparity range searched: a
    disparity pinned there is the matcher running out of range, not a match."""
    mv_ncc_threshold: float = setting(0.5, ge=0, le=1)
    """Confident only where at least ``mv_views`` of the view's ``mv_neighbours`` best
    neighbours (``eve3d.gaussians.neighbours``) agree with the photo: NCC ≥ this between the photo and
    the neighbour's photo warped by the prior depth (0 = off). Real photos on both sides,
    so it catches a depth the pretrained model got wrong, which the right view inherits."""
    mv_views: int = setting(1, ge=1)
    """Neighbours that must agree (a view with fewer neighbours skips the check)."""
    mv_neighbours: int = setting(4, ge=1)
    """Best neighbours tried (``eve3d.gaussians.neighbours``)."""
    min_alpha: float = setting(0.5, ge=0, le=1)
    """Confident only where the pretrained model renders a surface: its alpha in the left
    view (``stereo/alpha/``) is at least this over the whole ``edge_window`` around the
    pixel (0 = off). Where it renders nothing (an empty background, the sky) the right view
    is empty too, and whatever the matcher finds there is no surface."""
    edge_window: int = setting(5, ge=0)
    """Not confident within this window (px, about the matcher's: ``block_size`` for
    ``sgbm``) of a disparity jump (``jump`` px between adjacent pixels, or a matched pixel
    beside an unmatched one): a window that straddles a silhouette matches the foreground's
    texture and gives the background beside it the foreground's disparity (0 = off)."""
    jump: float = setting(1.0, gt=0)
    """Disparity difference between adjacent pixels that counts as a jump (px)."""
    flat_level: float = setting(1.0, ge=0)
    """A pixel is flat where the photo's grey level (0–255) varies less than this over 5×5
    pixels within 5 px of it. A flat pixel is confident only where textured pixels enclose it
    on two opposite sides (left and right, or above and below): there a matcher interpolates
    a plain wall between its edges; elsewhere it extrapolates (HITNet carries the table a
    band into a plain sky beyond its edge). 0 = off."""
    min_light: float = setting(0.0, ge=0, le=255)
    """Not confident where the photo (as matched, 0–255) has a grey level below this within
    a pixel: no light came from there, so there is nothing to match. Off (0) by default: a
    photo's background is never black, and ``flat_level`` covers a black one as a sky."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ncc_window % 2 == 0:
            raise Eve3dError(f"stereo.ncc_window: expected an odd integer ≥ 3, got {self.ncc_window}")
        if self.mv_views > self.mv_neighbours:
            raise Eve3dError(f"stereo.mv_views: expected at most stereo.mv_neighbours ({self.mv_neighbours}), "
                             f"got {self.mv_views}")


@dataclass
class RealPairSettings(Checked):
    """Which stereo pairs a backend matches (``eve3d.priors.real_pairs``)."""

    SECTION: ClassVar[str] = "stereo"
    pairs: str = setting("real", choices=PAIR_SOURCES)
    """``real``: the photo and its real neighbours, rectified with the known poses (the
    default: its errors are the matcher's, not the pretrained model's, docs/priors.md; a view
    that no neighbour rectifies with, as in a capture walking forward, takes its virtual prior);
    ``virtual``: the photo and a right view the pretrained model renders (the paper's);
    ``both``: the virtual prior where the real pairs' depth witnesses it (within ``real_tolerance``)."""
    real_neighbours: int = setting(3, ge=1)
    """Real neighbours matched per view: the best ranked (``eve3d.gaussians.neighbours``) that
    rectify well."""
    real_views: int = setting(1, ge=1)
    """Real pairs whose depths must agree (within ``real_tolerance`` of their median) for a
    confident real prior; more than half of the pairs that match a pixel must agree in any case."""
    real_tolerance: float = setting(0.01, gt=0)
    """Relative depth difference within which two depths agree."""
    real_max_disparity: float = setting(128.0, gt=0)
    """A real pair whose nearest depth would have a larger disparity (px) is matched at the
    scale that brings it to this: a matcher's cost grows with the range, and a phone capture's
    neighbours stand several virtual baselines apart (monstree: 135–500 px at 384×512)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.real_views > self.real_neighbours:
            raise Eve3dError(f"stereo.real_views: expected at most stereo.real_neighbours ({self.real_neighbours}), "
                             f"got {self.real_views}")


@dataclass
class OnnxSpec(Checked):
    """A stereo network exported to ONNX (the ``stereo.onnx`` mapping)."""

    SECTION: ClassVar[str] = "stereo.onnx"
    model: str = ""
    """Path of the .onnx file."""
    left: str = "left"
    """Name of the network's left-image input."""
    right: str = "right"
    """Name of the right-image input."""
    output: str = "disp"
    """Name of the disparity output."""
    layout: str = setting("NCHW", choices=("NCHW", "NHWC"))
    """Input layout, ``NCHW`` or ``NHWC`` (batch 1, RGB)."""
    scale: float = setting(255.0, gt=0)
    """Pixel values are fed as image / 255 × scale (255 = 0..255, 1 = 0..1), before ``mean`` and ``std``."""
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Per-channel mean subtracted from the fed values."""
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-channel divisor: the fed values are (image / 255 × scale − mean) / std."""
    size: tuple[int, int] | None = None
    """Fixed network input (height, width): images are resized to it, disparity rescaled."""
    divisor: int = setting(1, ge=1)
    """Otherwise, pad height and width up to a multiple of this (edge values), crop the output."""
    min_size: int = setting(1, ge=1)
    """With ``divisor``: pad height and width up to at least this too (a network's smallest input, e.g. PSMNet's 256)."""
    channel: int = setting(0, ge=0)
    """Channel of the output that holds the disparity (for outputs with a channel axis)."""
    sign: float = setting(1.0, nonzero=True)
    """Multiply the output by this (−1 for networks that output x_right − x_left)."""
    lr_threshold: float = setting(1.0, gt=0)
    """Left–right check tolerance (px)."""


@dataclass
class MccnnSettings(Checked):
    """MC-CNN fast's costs with SGM (the ``stereo.mccnn`` mapping; ``eve3d.priors.mccnn``)."""

    SECTION: ClassVar[str] = "stereo.mccnn"
    weights: str = ""
    """MC-CNN fast weights (.pt); empty = the Middlebury ones the ``mccnn`` wheel ships."""
    p1: float = setting(0.2, ge=0)
    """SGM's penalty for a 1 px disparity change between neighbours, in cost units (1 − cos)."""
    p2: float = setting(1.0, ge=0)
    """SGM's penalty for a larger change."""
    lr_threshold: float = setting(1.0, gt=0)
    """Left–right check tolerance (px)."""


@dataclass
class HitnetSettings(Checked):
    """HITNet exported to ONNX at a fixed input size (the ``stereo.hitnet`` mapping;
    ``eve3d.priors.hitnet``)."""

    SECTION: ClassVar[str] = "stereo.hitnet"
    model: str = ""
    """Path of the .onnx file (``hitnet_eth3d_HxW.onnx``: the file fixes the size each pair is resized to)."""
    max_disparity: float = setting(120.0, gt=0)
    """Largest disparity the network handles, in px at its input size (a shifted-texture
    pair fails from 150 px): a pair whose search range is wider is told in a warning."""
    lr_threshold: float = setting(1.0, gt=0)
    """Left–right check tolerance, in px at the pair's size."""


@dataclass
class Degradation(Checked):
    """Errors the ``oracle`` backend puts into the exact depth (the ``stereo.oracle`` mapping;
    ``eve3d.priors.oracle``), each as a stereo prior makes it, so that a method is measured
    against a prior of known quality (``eve3d bench degrade``). All 0: the exact depth."""

    SECTION: ClassVar[str] = "stereo.oracle"
    noise: float = setting(0.0, ge=0)
    """Relative depth noise: a smooth random field (correlated over ``scale`` px) of this
    standard deviation multiplies the depth."""
    scale: int = setting(5, ge=1)
    """Size of the errors in px: the noise's correlation length, the outliers' and the holes'
    patches. A matcher's window correlates its errors over its block (5); a network's on a plain
    wall over much of the view (HITNet's on the rooms keep two thirds of their spread averaged
    over 45×45 px)."""
    outliers: float = setting(0.0, ge=0, le=1)
    """Share of the surface pixels, in patches, whose depth is off by 5–15 % (confident and wrong)."""
    empty: float = setting(0.0, ge=0, le=1)
    """Share of the empty pixels (no surface) given a confident depth: those nearest a surface,
    each that surface's depth continued, as a network carries a table past its edge."""
    weak_bias: float = setting(0.0, ge=-0.5, le=0.5)
    """Relative bias on the weakly textured pixels (the photo's grey level varies by less than
    2 over 5×5 px): their depth × (1 + this); negative = too near."""
    holes: float = setting(0.0, ge=0, le=1)
    """Share of the surface pixels, in patches, left without confidence."""
    weak_holes: float = setting(0.0, ge=0, le=1)
    """Share of the weakly textured surface pixels, in patches, left without confidence: where
    a matcher finds nothing, the same in every view (a plain wall), so other views cannot fill it."""
    seed: int = 0
    """Seed of the random fields (the same errors for every method)."""


@dataclass
class StereoSettings(BaselineSettings, SgbmSettings, MatchCheck, RealPairSettings):
    """The ``stereo`` section: the prior source, the virtual baseline, SGBM's settings and
    the confidence checks (each stage reads its part with :func:`pick`)."""

    SECTION: ClassVar[str] = "stereo"
    backend: str = setting("sgbm", choices=tuple(PRIOR_BACKENDS))
    """Priors that ``stereo-tsdf`` and the prior methods use (``PRIOR_BACKENDS``)."""
    onnx: OnnxSpec = setting(factory=OnnxSpec)
    """The ``onnx`` backend's model spec."""
    mccnn: MccnnSettings = setting(factory=MccnnSettings)
    """The ``mccnn`` backend's settings."""
    hitnet: HitnetSettings = setting(factory=HitnetSettings)
    """The ``hitnet`` backend's settings."""
    oracle: Degradation = setting(factory=Degradation)
    """The ``oracle`` backend's errors (none: the exact depth)."""
