"""Every stage's settings, declared once: each field with its default, its bounds and its
documentation. Importable without torch, so that planning the workflow does not load it.

A field's bounds live in its metadata (``setting``), its documentation in the string under
it; :mod:`eve3d.core.settings_fields` checks the bounds whenever a settings object is made
(from a config section or by a direct call) and reads the documentation. Registries of
names that settings choose from (rasterisers, matchers) are declared here and imported by the
modules that implement them. The ``stereo`` section, with its registries of prior sources,
SGM modes and baseline modes, is :mod:`eve3d.core.settings_stereo`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from eve3d.core.errors import Eve3dError
from eve3d.core.scene import Camera
from eve3d.core.settings_fields import Checked, setting
from eve3d.core.settings_stereo import StereoSettings

RENDER_BACKENDS = ("auto", "cpu", "torch", "gsplat")
"""Rasterisers: ``cpu`` (our C++ tiles), ``torch`` (pure PyTorch reference), ``gsplat``
(CUDA); ``auto`` = gsplat on a CUDA tensor when installed, else cpu."""
MATCHERS = ("auto", "exhaustive", "sequential")
GROUND_TRUTH_CHECKS = ("error", "warn", "off")
"""What a failed ground-truth check does (``evaluate.ground_truth_check``): stop the run,
warn and go on, or the check is skipped."""
BACKGROUNDS = ("black", "sky", "backdrop")
"""What a generated scene shows where a ray meets no surface (``synthetic.background``): black,
a plain sky (a pale blue with a faint gradient by elevation), or a far textured backdrop
(value noise on the sphere of directions, at infinity: no parallax). Such pixels stay empty
(no depth) whatever they show."""
TNT_POINTS = ("vertices", "sampled")
"""What of a mesh the tnt protocol scores (``evaluate.tnt_points``): its vertices, as the
official toolbox reads a mesh PLY, or the vertices plus area samples."""


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
    background: str = setting("black", choices=BACKGROUNDS)
    """What the photos show where no surface is (``BACKGROUNDS``): ``black``, a plain ``sky``
    or a far textured ``backdrop``, as photos have them. The ground truth is the same."""
    surface_samples: int = setting(0, ge=0)
    """0: the sparse points are SIFT features of the photos triangulated with the known poses,
    as a user's SfM gives them. > 0: that many exact surface samples instead, for scenes too
    small for SIFT (the tests' tiny ones); never a benchmark's input."""


def job_threads() -> int | None:
    """The threads the workflow gives a job (``OMP_NUM_THREADS``, a positive count), or None
    where nothing says (a command run by hand: the library's own default, every core)."""
    import os

    given = os.environ.get("OMP_NUM_THREADS", "")
    return int(given) if given.isdigit() and int(given) > 0 else None


@dataclass
class SfmSettings(Checked):
    SECTION: ClassVar[str] = "sfm"
    matcher: str = setting("auto", choices=MATCHERS)
    """Which photos SfM matches: 'exhaustive' every pair, in any order; 'sequential' each photo
    with the next ones in the order of their file names (COLMAP's pairs: the next 10 and those
    2^k ahead), for photos named in the order they were taken, as phones and videos name them
    (COLMAP's loop detection needs a vocabulary tree, a download, so a loop closes only through
    those pairs); 'auto' exhaustive up to ``exhaustive_up_to`` photos, sequential above."""
    exhaustive_up_to: int = setting(64, ge=2)
    """The most photos ``auto`` matches exhaustively. Exhaustive pairs grow as the square of the
    photos, sequential's as the photos: on 2 cores, phone photos at 1280 px, 64 photos take
    about 200 s exhaustively (2016 pairs, a third of a 10-minute run) and 70 s in sequence,
    which registers less surely (docs/results.md, "Coarse to fine", on matching)."""
    camera_model: str = "SIMPLE_RADIAL"
    """COLMAP model estimated for the images (undistorted to PINHOLE afterwards)."""
    single_camera: bool = True
    """All images share one camera (one device, fixed zoom)."""
    affine_features: bool = False
    """SIFT estimates each feature's affine shape (COLMAP's ``estimate_affine_shape``), so a
    surface seen at a slant from one view and square from another still matches. On the
    generated scenes (320 px) it gives a fifth more points within 0.02 of the surface, twice the
    points on a floor's rim before a backdrop and +0.008 F (`eve3d`), +0.003 (`pgsr`) over two
    seeds; on monstree's phone photos 14 % fewer points, SfM 92 s against 83 s and held out
    20.11–20.20 dB against 20.67: off (docs/results.md, "The vase before the backdrop")."""
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
    threads: int = setting(-1, nonzero=True)
    """Threads for extraction, matching and mapping: -1 = every core the job has (the
    workflow's ``OMP_NUM_THREADS``, else the machine's: a shell that sets
    ``OMP_NUM_THREADS`` sets this too). 1 makes SfM bit-reproducible, about
    twice as slow on 2 cores (pycolmap's multi-threaded matching and mapping are not: the
    cameras move between runs by up to 1 % of the scene; docs/results.md, "Training", on SfM):
    the generator and the tests that compare two runs use it."""

    def matcher_for(self, photos: int) -> str:
        """``exhaustive`` or ``sequential``: the matcher for a set of ``photos``."""
        if self.matcher != "auto":
            return self.matcher
        return "exhaustive" if photos <= self.exhaustive_up_to else "sequential"


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
    environment: float = setting(1e-2, ge=0)
    """Step of the environment's texels (their colours' logits; it starts from the photos)."""


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
    """RGB behind the Gaussians of a model without an environment (``train.environment`` 0)."""
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
    coarse_until: float = setting(0.0, ge=0, le=1)
    """Coarse to fine, as fast 3DGS trainers do: this fraction of the steps, the first, see
    every view at most ``coarse_side`` px on its longest side (the priors too, one pixel of
    each block, a different one each step), a step at half the size for about a third of
    the time. Views trained no larger than that have no coarse steps. Settings in pixels
    (``ncc_patch``, ``prior_normal_span``, ``mv_threshold``) keep their values there, so
    they span more of the scene. 0 = off (docs/results.md, "Coarse to fine")."""
    coarse_side: int = setting(256, ge=8)
    """The coarse steps' longest image side in pixels."""
    environment: int = setting(256, ge=0)
    """Height in texels of the environment at infinity behind the Gaussians (an
    equirectangular map twice as wide, learnt with them: ``eve3d.gaussians.environment``),
    which explains a sky or a far background so that no Gaussian paints it; 0 = none, the
    constant ``background`` (the paper's and PGSR's)."""
    sky_weight: float = setting(0.1, ge=0)
    """Weight of the loss on the rendered alpha beyond the measured scene: mean(α · beyond)
    over the pixels, ``beyond`` the pixels past the measured scene (``sky_margin``,
    ``sky_tolerance``), where only the environment is to be seen (no Gaussian paints the sky
    there)."""
    sky_margin: float = setting(0.1, ge=0)
    """The measured scene: the sparse points' hull grown by this share of its size
    (``eve3d.core.hull.measured_hull``)."""
    sky_tolerance: float = setting(0.03, ge=0, le=1)
    """The depth maps a method exports mark as sky (``sky``, which no mesh fuses) the pixels
    whose photo the environment at infinity explains: within this of its colour, the largest
    channel's difference over 3×3 pixels, in a direction a training photo showed beyond the
    measured scene. Inside the scene's hull too, where the sky loss does not reach and
    Gaussians paint the sky above a floor's far edge. Training tests the same where only
    the hull with SfM's two-view points meets a ray: beyond there is what the map explains
    (``eve3d.gaussians.environment.scene_environment``). 0 = off."""
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
    init: str = setting("sparse", choices=("sparse", "priors", "both"))
    """Initial Gaussians: ``sparse`` (the SfM points; random points without them),
    ``priors`` (points back-projected from confident prior depths, Eve3D) or ``both``
    (the prior points and the SfM points, where the scene has them)."""
    init_prior_points: int = setting(500_000, ge=1)
    """Points drawn for ``init: priors`` and ``both`` (the paper: 500k on DTU, 1M on T&T)."""
    priors: str = setting("none", choices=("none", "fixed", "learnable"))
    """Stereo priors: ``none``; ``fixed`` (D* is the target of L_prior and the neighbours'
    depth in the LBA); ``learnable`` (D̂ per view, initialised from D*: Eve3D)."""
    prior_weight: float = setting(0.05, ge=0)
    """λ_prior: |D_prior − D| + ``prior_normal_weight`` · (1 − N_prior·N) on confident pixels."""
    prior_flat_weight: float = setting(0.0, ge=0)
    """λ_prior where the photo has no texture (beyond the paper; 0 = ``prior_weight``
    everywhere): the photos pin a textured surface's depth through the multi-view terms, but
    say little of a blank wall, where the prior is the only witness. The weight goes from
    ``prior_weight`` at ``FLAT_LEVELS`` grey levels of standard deviation over 5×5 pixels to
    this at none (``eve3d.joint.prior_weights``)."""
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
    max_incidence: float = setting(90.0, gt=0, le=90)
    """Pixels whose rendered normal is more than this many degrees from their ray are not
    fused (PGSR: 80); 90 = every pixel."""
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
