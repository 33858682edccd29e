"""Every stage's settings, declared once: each field with its default, its bounds and its
documentation. Importable without torch, so that planning the workflow does not load it.

A field's bounds live in its metadata (``setting``), its documentation in the string under
it; :mod:`eve3d.core.settings_fields` checks the bounds whenever a settings object is made
(from a config section or by a direct call) and reads the documentation. Registries of
names that settings choose from (rasterisers, SGM modes, baseline modes, matchers) are
declared here and imported by the modules that implement them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera
from eve3d.core.settings_fields import Checked, setting

RENDER_BACKENDS = ("auto", "cpu", "torch", "gsplat")
"""Rasterisers: ``cpu`` (our C++ tiles), ``torch`` (pure PyTorch reference), ``gsplat``
(CUDA); ``auto`` = gsplat on a CUDA tensor when installed, else cpu."""
SGM_MODES = {"hh": "STEREO_SGBM_MODE_HH", "hh4": "STEREO_SGBM_MODE_HH4", "3way": "STEREO_SGBM_MODE_SGBM_3WAY",
             "sgbm": "STEREO_SGBM_MODE_SGBM"}
"""``stereo.sgm_mode`` → OpenCV's StereoSGBM mode: 8 directions in two passes (``hh``), 4
(``hh4``), or the single-pass variants (``3way``, ``sgbm``)."""
BASELINE_MODES = ("disparity", "radius")
MATCHERS = ("exhaustive", "sequential")
GROUND_TRUTH_CHECKS = ("error", "warn", "off")
"""What a failed ground-truth check does (``evaluate.ground_truth_check``): stop the run,
warn and go on, or the check is skipped."""
TNT_POINTS = ("vertices", "sampled")
"""What of a mesh the tnt protocol scores (``evaluate.tnt_points``): its vertices, as the
official toolbox reads a mesh PLY, or the vertices plus area samples."""


@dataclass(frozen=True)
class PriorBackend:
    """A source of the stereo priors (``stereo.backend``): one row of :data:`PRIOR_BACKENDS`."""

    name: str
    module: str
    """Where it lives. A backend that reads the virtual stereo pairs has ``matcher(settings)``
    there (the ``stereo`` settings in, ``matcher(left, right, (min, max))`` → disparity and
    confidence out, for :func:`eve3d.stereo.stereo_priors`); one that reads the GT mesh has
    ``priors_from_mesh(scene, out, mesh, preview)``."""
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


# --------------------------------------------------------------------------- data

@dataclass
class SyntheticSettings(Checked):
    """A generated scene (``eve3d synth``); the ``synthetic`` section holds defaults for every
    generated scene, a scene's own ``synthetic:`` mapping overrides them and names its kind."""

    SECTION: ClassVar[str] = "synthetic"
    views: int = setting(32, ge=2)
    """Cameras of a generated scene."""
    width: int = setting(320, ge=16)
    """Image width in pixels."""
    height: int = setting(240, ge=16)
    """Image height in pixels."""
    seed: int = 0
    """Seed of the texture noise and the cameras' random placement."""
    arc: float = setting(360.0, gt=0, le=360)
    """Azimuth range of the cameras in degrees (a DTU-like front arc for object scenes)."""
    surface_samples: int = setting(0, ge=0)
    """0: the sparse points are SIFT features of the photos triangulated with the known poses,
    as a user's SfM gives them. > 0: that many exact surface samples instead, for scenes too
    small for SIFT (the tests' tiny ones); never a benchmark's input."""


@dataclass
class SfmSettings(Checked):
    SECTION: ClassVar[str] = "sfm"
    matcher: str = setting("exhaustive", choices=MATCHERS)
    """'exhaustive' for small unordered sets, 'sequential' for ordered captures (video)."""
    camera_model: str = "SIMPLE_RADIAL"
    """COLMAP model estimated for the images (undistorted to PINHOLE afterwards)."""
    single_camera: bool = True
    """All images share one camera (one device, fixed zoom)."""
    max_image_size: int = setting(3200, ge=64)
    """Longest side of the photos SfM imports (larger ones are downscaled once, before SIFT):
    the size of the posed dataset's images, the stages' full size."""
    min_registered_fraction: float = setting(0.9, ge=0, le=1)
    """Fail when fewer than this fraction of the images are registered."""
    seed: int = 0
    """Random seed of the mapper."""
    ransac_trials: int = setting(2000, ge=100)
    """Most RANSAC trials of the two-view check of each matched pair (COLMAP: 10,000), in SfM
    and in the generator's triangulation. Pairs that do not overlap spend them all, and around
    an object most pairs do not: the check is most of exhaustive matching's time. A pair with
    30 % inliers is still verified 99 % of the time (docs/results.md, "Training", on SfM)."""
    threads: int = setting(1, nonzero=True)
    """Threads for extraction, matching and mapping. 1 makes SfM bit-reproducible (pycolmap's
    multi-threaded matching and mapping are not: the cameras move between runs); -1 uses every
    core, faster (docs/results.md, "Training", on SfM)."""


# --------------------------------------------------------------------------- training

@dataclass
class LearningRates(Checked):
    """Adam step sizes of 3DGS. ``means`` is multiplied by the scene scale and decays
    exponentially to ``means_final`` × scene scale over the run."""

    SECTION: ClassVar[str] = "train.lr"
    means: float = setting(1.6e-4, gt=0)
    """Step of the centres at the start (× scene radius)."""
    means_final: float = setting(1.6e-6, gt=0)
    """Step of the centres at the end (× scene radius; exponential decay)."""
    quats: float = setting(1e-3, ge=0)
    """Step of the rotations."""
    log_scales: float = setting(5e-3, ge=0)
    """Step of the log-scales."""
    logit_opacities: float = setting(5e-2, ge=0)
    """Step of the opacity logits."""
    sh0: float = setting(2.5e-3, ge=0)
    """Step of the base colour (SH degree 0)."""
    shN: float = setting(2.5e-3 / 20, ge=0)
    """Step of the higher SH coefficients."""


@dataclass
class DensifySettings(Checked):
    """The densification policy (``eve3d.gaussians.densify.Densifier``); defaults are 3DGS's, with
    AbsGS's split threshold."""

    SECTION: ClassVar[str] = "train.densify"
    grow_grad2d: float = setting(0.0002, gt=0)
    """Clone when the mean gradient of the 2D mean (NDC units) exceeds this."""
    grow_absgrad2d: float = setting(0.0008, gt=0)
    """Split when the AbsGS absolute gradient exceeds this (with ``absgrad``)."""
    absgrad: bool = True
    """Split by the absolute gradient (AbsGS, PGSR); ``3dgs`` uses the plain one."""
    grow_scale3d: float = setting(0.01, gt=0)
    """Clone below, split above this largest scale (× scene radius)."""
    prune_opa: float = setting(0.005, ge=0, le=1)
    """Prune below this opacity."""
    prune_scale3d: float = setting(0.1, gt=0)
    """Prune above this largest scale (× scene radius; after the first opacity reset)."""
    prune_min_views: int = setting(0, ge=0)
    """Prune Gaussians seen by fewer views (judged after two passes over the views); 0 = off."""
    refine_start: int = setting(500, ge=0)
    """First step of densification."""
    refine_stop: int = setting(15_000, ge=0)
    """Last step of densification."""
    refine_every: int = setting(100, ge=1)
    """Steps between densifications."""
    reset_every: int = setting(3000, ge=0)
    """Opacity reset period; 0 = never (short CPU runs)."""
    max_gaussians: int = setting(3_000_000, ge=1)
    """Growth budget: when the candidates would exceed it, those with the largest gradient
    (relative to their threshold) grow first. A memory and time guard; pruning goes on."""


@dataclass
class RenderSettings(Checked):
    """How a model is rasterised: by the training stages, and by every stage that renders a
    trained model (the stereo pairs' right views, the nvs protocol) the way it was trained."""

    SECTION: ClassVar[str] = "train"
    resolution: float = setting(1.0, gt=0)
    """Image size factor for training (0.5 = half width and height)."""
    max_side: int = setting(1600, ge=0)
    """Cap on the training images' longest side in pixels (3DGS caps at 1.6k); 0 = none.
    A model renders other stages' views (right views, held-out views) at this size too."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """RGB behind the Gaussians."""
    backend: str = setting("auto", choices=RENDER_BACKENDS)
    """Rasteriser (``RENDER_BACKENDS``)."""
    antialiased: bool = True
    """Opacity compensation for the 0.3 px² screen-space dilation (gsplat's antialiased mode).
    Without it, the dilation widens edge-on and sub-pixel Gaussians and the optimiser shrinks
    every surface by about a pixel footprint to match the photos' silhouettes."""

    def scale(self, cam: Camera) -> float:
        """The training size's factor of ``cam``: ``resolution``, less where the longest
        side would exceed ``max_side``."""
        if self.max_side:
            return min(self.resolution, self.max_side / max(cam.width, cam.height))
        return self.resolution

    MIN_SIDE: ClassVar[int] = 8
    """Smallest training image side in pixels (below it the rasteriser, SSIM and NCC have
    nothing to work on; at 0 px OpenCV's resize asserts)."""

    def sized(self, cam: Camera) -> Camera:
        """``cam`` at the training size (:meth:`scale`); an error naming ``resolution`` and
        ``max_side`` when that size is below :attr:`MIN_SIDE`."""
        factor = self.scale(cam)
        small = cam if factor == 1 else cam.scaled(factor)
        if min(small.width, small.height) < self.MIN_SIDE:
            raise Eve3dError(f"{self.SECTION}.resolution {self.resolution:g} (max_side {self.max_side}): view "
                             f"{cam.name} ({cam.width}×{cam.height}) would be trained at {small.width}×{small.height} "
                             f"px; the training size needs at least {self.MIN_SIDE} px a side")
        return small


@dataclass
class TrainSettings(RenderSettings):
    """What every training stage shares. Defaults are the paper's (GPU, full schedule);
    the presets in ``config/presets`` set the CPU ones."""

    SECTION: ClassVar[str] = "train"
    iterations: int = setting(30_000, ge=0)
    """Optimisation steps."""
    sh_degree: int = setting(3, ge=0, le=3)
    """Spherical-harmonics degree of the colours."""
    sh_degree_interval: int = setting(1000, ge=1)
    """Raise the active SH degree by one every this many steps."""
    ssim_weight: float = setting(0.2, ge=0, le=1)
    """L_rgb = (1 − w)·L1 + w·(1 − SSIM)."""
    init_thickness: float = setting(0.1, gt=0, le=1)
    """Initial Gaussians from points on a surface (sparse points, prior or rendered depth)
    are discs in the plane of their 8 nearest points, this thin along its normal (a
    fraction of the in-plane scale); 1 = 3DGS's isotropic balls. Balls, split in 3D while
    they are still round, leave a cloud in front of and behind each surface whose front
    layer is what renders: depth 0.2–0.7 % too near (docs/method.md, Choices)."""
    init_random_points: int = setting(100_000, ge=1)
    """Random initial points when the scene has no sparse points (``init: sparse``)."""
    init_drop_isolated: bool = False
    """``init: sparse`` leaves out the sparse points seen in two images only that lie far
    from every point seen in more (:meth:`eve3d.core.scene.Scene.isolated`): SfM's outliers."""
    device: str = "auto"
    """``auto`` = CUDA when present, else CPU."""
    seed: int = 0
    """Seeds every random draw (view order, splits, NCC pixels)."""
    checkpoint_every: int = setting(1000, ge=0)
    """Steps between checkpoints (a killed job resumes from the last); 0 = none."""
    holdout: int = setting(0, ge=0)
    """Hold out every ``holdout``-th view (index % holdout == 0) for evaluation; 0 = none."""
    previews: int = setting(3, ge=0)
    """Views whose RGB, depth and normals are written as PNG at the end."""
    lr: LearningRates = setting(factory=LearningRates)
    densify: DensifySettings = setting(factory=DensifySettings)


@dataclass
class PretrainSettings(TrainSettings):
    SECTION: ClassVar[str] = "pretrain"
    iterations: int = setting(7000, ge=0)
    holdout: int = setting(8, ge=0)
    reinit_at: tuple[int, ...] = (2000,)
    """Steps at which the Gaussians are re-initialised from rendered depth."""
    reinit_points: int = setting(0, ge=0)
    """Points sampled at a re-initialisation; 0 = as many as there are Gaussians then."""
    simplify_at: tuple[int, ...] = (5000,)
    """Steps at which only the highest-weight Gaussians are kept."""
    simplify_keep: float = setting(0.6, gt=0, le=1)
    """Fraction of Gaussians (highest blending weight first) a simplification keeps."""
    equalize: float = setting(3.0, ge=0)
    """The photos are fitted through one tone curve of the whole scene: contrast-limited
    histogram equalisation of every photo's grey levels, the histogram clipped at this × its
    mean bin count (``eve3d.core.photos.scene_tone_curve``); 0 = the photos as they are. Faint
    texture (a dark, low-contrast wall) then weighs in the loss as much as bright texture, so
    the model fits it, and its geometry there. The curve is written beside the PLY
    (``tone_curve.json``) and the stereo stage matches the photos through it."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.equalize != 0 and self.equalize < 1:
            raise Eve3dError(f"pretrain.equalize: must be 0 (off) or at least 1 (the histogram's clip limit), "
                             f"got {self.equalize}")


@dataclass
class JointSettings(TrainSettings):
    SECTION: ClassVar[str] = "joint"
    method: str = "pgsr"
    """The method's name (``eve3d.core.methods``): recorded, and names the progress bar."""
    depth: str = setting("depth", choices=("depth", "depth_expected"))
    """Depth rendered for meshing: ``depth`` (PGSR's unbiased depth) or ``depth_expected``."""
    scale_weight: float = setting(100.0, ge=0)
    """Flattening loss: weight × mean(min scale of the visible Gaussians)."""
    opacity_weight: float = setting(0.0, ge=0)
    """Opacity loss: weight × mean opacity of the visible Gaussians (3DGS-MCMC's regulariser).
    A Gaussian whose colour matches what lies behind it (black on a black background) gets no
    photometric gradient, and this lowers its opacity until it is pruned; any Gaussian the
    photos need outweighs it. 0 = off."""
    opacity_while_densifying: bool = False
    """Stop the opacity loss where densification stops (``densify.refine_stop``): it lowers
    the floaters while pruning can still remove them; later it would only thin the surfaces
    (against a black background the colour makes up for the lost alpha)."""
    opacity_spare: float = setting(0.0, ge=0)
    """Methods with priors: the opacity loss spares the Gaussians whose centre lies within this
    relative depth of the confident prior at its pixel (on a measured surface), so it lowers
    only the others: floaters, and the Gaussians behind a surface or inside an object that
    would show through a surface it made semi-transparent. 0 = spares none. Experimental: no
    method, preset or config turns it on (docs/results.md, "Sparing the measured surface")."""
    dn_weight: float = setting(0.015, ge=0)
    """Weight of the depth–normal consistency loss (PGSR)."""
    dn_from: int = setting(7000, ge=0)
    """First step of the depth–normal consistency loss."""
    mv_from: int = setting(7000, ge=0)
    """First step of the multi-view losses."""
    geo_weight: float = setting(0.03, ge=0)
    """Weight of the multi-view geometric loss (PGSR)."""
    ncc_weight: float = setting(0.15, ge=0)
    """Weight of the multi-view NCC loss (PGSR)."""
    mv_threshold: float = setting(1.0, gt=0)
    """Pixels whose forward–backward reprojection error φ is this large (px) are left out."""
    ncc_patch: int = setting(7, ge=3)
    """NCC patch size (px)."""
    ncc_pixels: int = setting(4096, ge=1)
    """Reference pixels per step whose patches enter the NCC loss."""
    neighbours: int = setting(4, ge=1)
    """Neighbour views per view (DESIGN §3 score)."""
    exposure: bool = False
    """Learn a 3×4 colour transform per training image (PGSR's exposure compensation)."""
    exposure_lr: float = setting(1e-3, ge=0)
    """Adam step of the exposure transforms."""
    init: str = setting("sparse", choices=("sparse", "priors"))
    """Initial Gaussians: ``sparse`` (the SfM points; random points without them) or
    ``priors`` (points back-projected from confident prior depths, Eve3D)."""
    init_prior_points: int = setting(500_000, ge=1)
    """Points drawn for ``init: priors`` (the paper: 500k on DTU, 1M on T&T)."""
    priors: str = setting("none", choices=("none", "fixed", "learnable"))
    """Stereo priors: ``none``; ``fixed`` (D* is the target of L_prior and the neighbours'
    depth in the LBA); ``learnable`` (D̂ per view, initialised from D*: Eve3D)."""
    prior_weight: float = setting(0.05, ge=0)
    """λ_prior: |D_prior − D| + ``prior_normal_weight`` · (1 − N_prior·N) on confident pixels."""
    prior_normal_weight: float = setting(1.0, ge=0)
    """Weight w of the normal term in L_prior."""
    prior_normal_span: int = setting(1, ge=1)
    """N_prior from central differences of the prior depth over ±span pixels (1 = adjacent
    pixels; wider averages out the per-pixel noise of a matcher like SGBM)."""
    prior_from: int = setting(500, ge=0)
    """First step of every prior term."""
    joint_from: int = setting(7000, ge=0)
    """T_joint: L_prior switches from D* to D̂, L_pull starts, the LBA's reference becomes the
    rendered depth."""
    pull_weight: float = setting(0.05, ge=0)
    """λ_pull: |D̂ − sg(D)| on pixels M^c does not trust."""
    lba_weight: float = setting(0.15, ge=0)
    """λ_lba: (geometric + photometric) averaged over the ``neighbours`` best views."""
    prior_lr: float = setting(1e-4, ge=0)
    """Adam step of log D̂ (a relative change of depth: the same for every scene scale)."""
    consistent_views: int = setting(2, ge=1)
    """M^c: a prior depth counts where at least this many neighbours confirm it geometrically
    (``confirm_depth``), besides the stereo's own confidence and the photos (``confirm_ncc``)."""
    confirm_depth: float = setting(0.01, gt=0)
    """M^c: a neighbour confirms a prior depth where the point lands on its *confident* prior
    pixels within this relative depth difference (a tolerance that stays the same at every
    training size, where PGSR's 1 px does not)."""
    confirm_ncc: float = setting(0.5, ge=-1, le=1)
    """M^c: the real photos confirm a prior depth where the NCC (7×7) between the view's photo
    and at least ``confirm_photos`` neighbours' photos warped by that depth reaches this;
    a window without texture can neither confirm nor refute and passes."""
    confirm_photos: int = setting(1, ge=0)
    """M^c: neighbours whose photos must agree (``confirm_ncc``); 0 = no photometric check."""


# --------------------------------------------------------------------------- stereo

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
    min_light: float = setting(1.0, ge=0, le=255)
    """Not confident where the photo (as matched, 0–255) has a grey level below this within
    a pixel: no light came from there, so there is nothing to match, and a network that
    answers everywhere carries its neighbours' depth into it (HITNet: the table's depth a
    few pixels into the black background beyond its edge). 0 = off."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ncc_window % 2 == 0:
            raise Eve3dError(f"stereo.ncc_window: expected an odd integer ≥ 3, got {self.ncc_window}")
        if self.mv_views > self.mv_neighbours:
            raise Eve3dError(f"stereo.mv_views: expected at most stereo.mv_neighbours ({self.mv_neighbours}), "
                             f"got {self.mv_views}")


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
class StereoSettings(BaselineSettings, SgbmSettings, MatchCheck):
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


# --------------------------------------------------------------------------- mesh and evaluation

@dataclass
class MeshSettings(Checked):
    SECTION: ClassVar[str] = "mesh"
    voxel: float | None = setting(None, gt=0)
    """Voxel size in scene units; None = DESIGN §3 default (object 0.002 normalised units,
    scene max extent / 2048) times ``coarsen``."""
    coarsen: float = setting(1.0, gt=0)
    """Multiplier on the default voxel (the CPU preset uses a coarser grid)."""
    trunc_factor: float = setting(4.0, gt=0)
    """sdf_trunc = trunc_factor × voxel."""
    depth_max: float | None = setting(None, gt=0)
    """Ignore depth beyond this (scene units); None = keep all (within ``region``)."""
    region: float = setting(2.0, ge=0)
    """The region of interest: the box of the sparse points' 5–95 % percentiles, scaled by
    this about its centre. Only depths that land in it are fused (a sky or a far background
    never becomes a wall), the voxel of an open scene comes from its size, and the mesh is
    cropped to it. 0 = no region (fuse every depth)."""
    min_confidence: float = setting(0.5, ge=0, le=1)
    """Pixels whose confidence M^c is below this are not fused."""
    weight_threshold: float = setting(1.0, ge=0)
    """Minimum accumulated TSDF weight for a surface to be extracted."""
    largest_cluster: bool | None = None
    """Keep the largest connected component (and see ``min_cluster_fraction``); None = for
    object scenes only."""
    min_cluster_fraction: float = setting(0.01, ge=0, le=1)
    """With ``largest_cluster``, also keep components with at least this fraction of the
    largest one's triangles: a part of an object that touches the table in a thin crease
    may fuse as its own component, while floaters are orders of magnitude smaller."""


@dataclass
class EvalSettings(Checked):
    """The ``evaluate`` section of the config."""

    SECTION: ClassVar[str] = "evaluate"
    tau: float | None = setting(None, gt=0)
    """Distance threshold of precision/recall; None = the protocol's rule (synthetic: a
    fraction of the visible GT's bounding-box diagonal; tnt: the toolbox's per-scene table)."""
    tau_fraction: float = setting(0.0025, gt=0)
    """Synthetic τ = this × the diagonal of the bounding box of the GT surface the cameras see."""
    min_views: int = setting(2, ge=1)
    """Synthetic: a GT surface point counts as visible when this many cameras see it (2:
    what a multi-view reconstruction can triangulate; TSDF fusion with the default
    ``mesh.weight_threshold`` also drops surfaces fused from a single view)."""
    samples: int = setting(500_000, ge=1000)
    """Synthetic: surface samples scored on each of the reconstruction (inside the crop) and
    the visible GT; with exact point-to-triangle distances the count sets only the sampling
    noise and the memory. tnt with ``tnt_points: sampled``: at most this many area samples
    beside the mesh's vertices."""
    tnt_points: str = setting("vertices", choices=TNT_POINTS)
    """tnt: the points of a mesh that are scored: ``vertices`` (as the official toolbox, which
    reads a mesh PLY as a point cloud) or ``sampled`` (the vertices plus about one area sample
    per (τ/2)², so a mesh coarser than τ/2 is not charged for its vertex spacing)."""
    ground_truth_check: str = setting("error", choices=GROUND_TRUTH_CHECKS)
    """dtu, tnt: the check, before any training, that the ground truth lines up with the
    cameras: ``error`` stops the run, ``warn`` prints what it found and goes on, ``off`` skips
    it. Its bounds were set on miniature downloads, not yet on the real ones."""
    dtu_density: float = setting(0.2, gt=0)
    """DTU: sampling density and thinning radius in mm."""
    dtu_max_dist: float = setting(20.0, gt=0)
    """DTU: distances at or above this (mm) are left out of the means."""


SECTIONS: dict[str, type] = {"synthetic": SyntheticSettings, "sfm": SfmSettings, "stereo": StereoSettings,
                             "mesh": MeshSettings, "evaluate": EvalSettings}
"""The config's sections read as one settings object each. ``train``, ``pretrain`` and
``joint`` are merged per stage (``eve3d.config.stage_settings``)."""
