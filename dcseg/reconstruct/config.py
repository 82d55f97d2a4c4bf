"""Parameters of stage 1 (reconstruction): a stdlib dataclass, never importing torch.

The defaults are the ``paper`` values (close to 3D Gaussian Splatting); :data:`PRESETS` holds the
named variants. Learning rates follow 3DGS; the position rate is multiplied by the scene extent.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from dcseg.fields import option


@dataclass(frozen=True)
class ReconstructConfig:
    """How Gaussians are initialised from depth and optimised against the training views."""

    iterations: int = option(30_000, bounds=(0, 100000), flag="--iterations")
    """Optimisation steps; one random training view per step. At the reference size (35
    training views): runs grow it with their training views, and the step schedule
    (``sh_degree_interval``, ``full_res_from``, ``densify_*``, ``opacity_reset_every``) with
    it (:func:`dcseg.sizes.grown_steps`)."""

    sh_degree: int = option(3, bounds=(0, 3), flag="--sh-degree")
    """Largest spherical-harmonic degree of the colour (0-3)."""

    sh_degree_interval: int = option(1000, bounds=(1, 100000))
    """Raise the active SH degree by one every this many steps (3DGS schedule)."""

    holdout: int = option(8, bounds=(0, 1000), flag="--holdout")
    """Every ``holdout``-th frame (index 0, k, 2k, ...) is held out for evaluation; 0 = none."""

    seed: int = option(0, fixed=True)
    """Seed of every random choice (view order, pixel subsampling, split samples)."""

    train_downscale: int = option(1, bounds=(1, 16), flag="--train-downscale")
    """Train on views downscaled by this integer factor (evaluation is at full resolution)."""

    full_res_from: int | None = option(None, bounds=(0, 100000), flag="--full-res-from")
    """From this step on, train on full-resolution views (coarse to fine); None = never."""

    full_res_crop: float = option(1.0, bounds=(0.05, 1.0))
    """Full-resolution steps train on a random window of this fraction of the width and height
    (1 = whole views); the coarse steps always see whole (downscaled) views."""

    backend: str | None = option(None, choices=("cpu", "reference", "gsplat"), flag="--backend")
    """Renderer backend (``"cpu"``, ``"reference"``, ...); None = the renderer's default."""

    # --- sensor depth ---
    depth_filter_window: int = option(5, bounds=(1, 15))
    """Edge (odd, pixels) of the median window that denoises the training frames' depth before
    initialisation and the depth loss (:mod:`dcseg.reconstruct.depth_filter`); 1 = off.
    Held-out frames are evaluated against the unfiltered sensor depth. Noise-free depth is
    left as it is (its measured noise is 0). Chosen on the noise-free depth of synthetic
    layouts 0-2 (12 views) with the synth levels' z-squared noise added, mean error against
    the true depth: 1.5 mm at 1 m (default level) 8.35 mm raw, window 3 / 5 / 7 with k = 5:
    4.34 / 3.61 / 3.66 mm; 4 mm at 1 m (heavy) 22.4 mm raw, 9.66 / 6.75 / 6.02 mm. 7 x 7
    helps only the heavy noise and costs twice the time."""

    depth_filter_k: float = option(5.0, bounds=(0.1, 100.0))
    """A pixel takes its window median only where the two differ by at most this many times
    the view's measured noise at that depth. Same views, window 5, k = 3 / 5 / 8: 3.75 /
    3.61 / 3.68 mm (default level), 7.24 / 6.75 / 6.76 mm (heavy)."""

    drop_flying_pixels: bool = True
    """Drop the flying pixels at depth edges (samples between the two sides of a jump, on no
    surface: :mod:`dcseg.reconstruct.flying`) from the training frames' depth before
    initialisation and the depth loss. Held-out frames are scored against the sensor depth as
    it is. ``reconstruction.json`` reports their share (``sensor.depth.flying_pixels``)."""

    # --- camera poses (dcseg.reconstruct.poses, dcseg.reconstruct.pose_check) ---
    pose_refinement: str = option(
        "auto",
        choices=("auto", "on", "off"),
        flag="--pose-refinement",
        help="fit a pose correction per frame with the Gaussians: auto = when consecutive "
        "frames' depth disagrees more than the noise explains (tracked, handheld poses)",
    )
    """A rigid correction per training view fitted with the Gaussians from step ``pose_from``
    (:mod:`dcseg.reconstruct.poses`); held-out views are aligned to the fit before they are
    scored and the refined poses replace the capture's for every later stage. ``auto``: on
    when consecutive training frames' depth, projected with the capture's poses, disagrees by
    more than :data:`dcseg.reconstruct.pose_check.THRESHOLD` times what the measured depth
    noise explains (``sensor.poses`` in ``reconstruction.json``); RGB-only captures are
    refined only with ``on``. Measured with ``benchmarks/bench_handheld.py`` on 40-view
    320x240 synthetic scenes (benchmarks/README "Handheld captures"): poses off by 0.5
    degrees and 1 cm per frame, held-out PSNR 19.0 -> 25.0 dB, depth MAE against the true
    depth 40.8 -> 16.6 mm; exact poses refined anyway (``on``) 27.95 -> 25.90 dB (the
    corrections also absorb some of the fit's own error), which ``auto`` leaves alone."""

    pose_lr: float = option(1e-3, bounds=(0.0, 0.1))
    """Learning rate (radians and metres per step) of the pose corrections, decaying
    log-linearly to a tenth of it; 0 = never refine (whatever ``pose_refinement`` says).
    A third of it recovered less under pose error (22.8 instead of 25.0 dB, one scene)."""

    pose_from: int = option(500, bounds=(0, 100000))
    """Step from which poses are refined (the scene first fits the capture's poses).
    Refining from step 0 cost exact poses more (24.9 dB) for 0.3 dB more under pose error."""

    pose_align_steps: int = option(30, bounds=(0, 10000))
    """With ``pose_lr`` > 0, steps that align each held-out view's pose to the fitted
    Gaussians (frozen) before it is scored, at the training resolution: held-out poses carry
    the same error as the trained ones, and the score should measure the scene, not them.
    On four held-out views of a 200-frame 640x480 handheld stand-in, 30 steps at rate 2e-3
    left the same error as 60 at 1e-3 (0.08-0.23 deg against 0.09-0.20) in half the time;
    at quarter resolution they left more (0.10-0.35 deg)."""

    pose_align_lr: float = option(2e-3, bounds=(1e-06, 0.1))
    """Starting rate of those alignment steps (decaying to a tenth)."""

    # --- intrinsics (dcseg.reconstruct.calibration) ---
    intrinsics_refinement: str = option(
        "auto",
        choices=("auto", "off"),
        flag="--intrinsics-refinement",
        help="wrong intrinsics (nominal values given for a calibrated sensor): auto = find "
        "the focal length and principal point under which the frames' depth agrees across "
        "views and use them when they clearly agree better",
    )
    """``auto``: the common focal scale and principal point shift under which pairs of training
    frames viewing a few degrees apart agree best in depth
    (:func:`dcseg.reconstruct.calibration.estimate`) correct every frame's intrinsics (trained,
    held out and in the later stages) when they lower the disagreement by more than
    :data:`~dcseg.reconstruct.calibration.MIN_GAIN`; ``off``: not estimated. Captures with a
    calibrated lens (distortion given) and RGB-only captures keep theirs.
    ``reconstruction.json`` reports it (``sensor.intrinsics``)."""

    # --- colour/depth registration (dcseg.reconstruct.registration) ---
    depth_registration: str = option(
        "auto",
        choices=("auto", "off"),
        flag="--depth-registration",
        help="colour/depth misregistration (separate depth and colour cameras): auto = "
        "estimate the pixel shift between depth and colour edges and move the depth by it "
        "when clearly non-zero",
    )
    """``auto``: the shift that lays the training frames' depth edges onto their colour edges
    (:func:`dcseg.reconstruct.registration.estimate`) moves every frame's depth (trained and
    held out) when it is non-zero and raises the edges' colour contrast by more than
    :data:`~dcseg.reconstruct.registration.MIN_GAIN`; ``off``: not estimated. A shift given
    in ``depth_shift_x`` / ``depth_shift_y`` is applied instead, without estimation.
    ``reconstruction.json`` reports it (``sensor.registration``)."""

    depth_shift_x: int = option(
        0,
        bounds=(-32, 32),
        flag="--depth-shift-x",
        help="a known colour/depth misregistration: move every depth map this many pixels "
        "right (negative: left) onto its colour, without estimation (default 0)",
    )
    """A known colour/depth misregistration: move every depth map this many pixels right
    (negative: left) onto its colour image; 0 with ``depth_shift_y`` 0 = none given."""

    depth_shift_y: int = option(
        0,
        bounds=(-32, 32),
        flag="--depth-shift-y",
        help="likewise, pixels down (negative: up)",
    )
    """Likewise, pixels down (negative: up)."""

    # --- exposure and white balance (dcseg.reconstruct.exposure) ---
    exposure: str = option("auto", choices=("auto", "on", "off"), flag="--exposure")
    """A per-channel gain and bias per training view, fitted with the Gaussians and pulled
    towards identity (auto exposure / white balance). ``auto``: on when consecutive frames'
    colours at corresponding pixels change by more than 3 %."""

    exposure_lr: float = option(0.02, bounds=(0.0, 1.0))
    """Starting learning rate of the per-view transforms (decaying log-linearly to a tenth)."""

    exposure_reg: float = option(0.01, bounds=(0.0, 100.0))
    """Weight of the squared distance of each view's transform (log gains, biases) to identity
    in the loss."""

    # --- initialisation from depth ---
    init_pixel_stride: int = option(2, bounds=(1, 64))
    """Back-project every ``stride``-th pixel along both axes of every training frame."""

    voxel_size: float | None = option(None, bounds=(0.0001, 1.0))
    """Voxel edge (metres) of the downsampled init cloud; None = ``extent * voxel_fraction``."""

    voxel_fraction: float = option(1.0 / 200.0, bounds=(1e-05, 0.1))
    """Automatic voxel size as a fraction of the scene extent."""

    voxel_min: float = option(0.005, bounds=(0.0001, 1.0))
    """Lower clip of the automatic voxel size (metres)."""

    voxel_max: float = option(0.05, bounds=(0.0001, 1.0))
    """Upper clip of the automatic voxel size (metres)."""

    max_init_points: int = option(200_000, bounds=(1, 5000000))
    """Cap on initial Gaussians; the voxel size grows until the cloud fits. At the reference
    size: runs grow it with their training pixels (:func:`dcseg.sizes.gaussian_growth`)."""

    init_opacity: float = option(0.3, bounds=(0.0001, 0.9999))
    """Opacity of every initial Gaussian."""

    init_thickness: float | None = option(0.1, bounds=(0.001, 1.0))
    """Start every Gaussian as a disc in the plane of its neighbours, this fraction as thick
    as it is wide (:func:`dcseg.reconstruct.surface.disc_frames`); None = isotropic blobs."""

    # --- surface priors (dcseg.reconstruct.surface); on by default: opaque centres ~1 cm from
    # the surfaces instead of ~2 cm, held-out segmentation kept (benchmarks/README "Surfaces") ---
    thickness_weight: float = option(1.0, bounds=(0.0, 1000.0))
    """Weight of the mean smallest scale (metres) in the loss: keeps Gaussians thin discs."""

    centre_weight: float = option(10.0, bounds=(0.0, 1000.0))
    """Weight of the mean distance (metres) of the Gaussian centres to the observed depth of
    the step's view, counting the centres within ``centre_band`` of it."""

    centre_band: float = option(4.0, bounds=(0.0, 100.0))
    """The band of ``centre_weight``, in initial voxel sizes (see ``voxel_size``): how far in
    front of the observed depth a centre is pulled onto it."""

    centre_behind: float | None = option(None, bounds=(0.0, 100.0))
    """How far behind the observed depth a centre is pulled onto it, in initial voxel sizes;
    None = ``centre_band``. Narrower keeps the far side of a small object, hidden behind its
    near side, where it is (:func:`dcseg.reconstruct.surface.centre_depth_grad`)."""

    centre_from: int | None = option(None, bounds=(0, 1000000))
    """First iteration of the ``centre_weight`` pull; None = ``densify_until``. From there on,
    the pull only moves the Gaussians densification made; earlier, it also decides which ones
    are made and kept (on discs it halves the opaque Gaussians of small objects, which then
    merge into their supports' clusters)."""

    centre_window: int = option(1, bounds=(1, 15))
    """Edge (odd, pixels) of the window around a centre's pixel whose valid observed depth
    nearest the centre is its target; 1 = the pixel's. Wider keeps centres on silhouettes, whose
    pixel sees the surface behind, on their object."""

    opacity_weight: float = option(0.1, bounds=(0.0, 1000.0))
    """Weight of the mean transparency of the Gaussians more than 0.25 opaque, from
    ``centre_from`` on: walls and floors drawn by stacked half-transparent discs become opaque
    discs on them (:func:`dcseg.reconstruct.surface.opacity_grad`); 0 = off."""

    planar_depth: bool = False
    """Render depth (the depth loss and the held-out depth error) as each flat Gaussian's
    ray-plane depth instead of its centre's over its whole footprint
    (:func:`dcseg.render.render_planar`)."""

    # --- loss ---
    ssim_lambda: float = option(0.2, bounds=(0.0, 1.0))
    """Weight of ``1 - SSIM`` in the RGB loss ``(1 - l) * L1 + l * (1 - SSIM)``."""

    depth_weight: float = option(0.5, bounds=(0.0, 100.0))
    """Weight of the L1 loss on expected depth at valid depth pixels (metres)."""

    blurred_frames: str = option(
        "weight",
        choices=("weight", "skip", "off"),
        flag="--blurred-frames",
        help="motion-blurred training frames: weight their colour loss by their sharpness, "
        "skip it where sharp neighbours see them, or train them as they are",
    )
    """Training frames far less sharp than their neighbours along the trajectory are
    motion-blurred (:mod:`dcseg.reconstruct.sharpness`): ``weight`` scales their colour loss
    by their relative sharpness, ``skip`` drops their colour loss where sharp neighbours see
    what they see (weights it elsewhere), ``off`` trains them as they are. Depth is trained
    either way. Sharp captures are unaffected (every weight stays 1). ``reconstruction.json``
    reports the scores (``sensor.motion_blur``)."""

    # --- optimiser (Adam, eps 1e-15) ---
    means_lr_init: float = option(1.6e-4, bounds=(0.0, 1.0))
    """Initial position learning rate, times the scene extent."""

    means_lr_final: float = option(1.6e-6, bounds=(0.0, 1.0))
    """Final position learning rate, times the scene extent (log-linear decay)."""

    sh_dc_lr: float = option(2.5e-3, bounds=(0.0, 1.0))
    """Learning rate of the SH DC coefficients."""

    sh_rest_lr: float = option(1.25e-4, bounds=(0.0, 1.0))
    """Learning rate of the higher-order SH coefficients."""

    opacity_lr: float = option(0.05, bounds=(0.0, 1.0))
    """Learning rate of the opacity logits."""

    scales_lr: float = option(5e-3, bounds=(0.0, 1.0))
    """Learning rate of the log scales."""

    quats_lr: float = option(1e-3, bounds=(0.0, 1.0))
    """Learning rate of the quaternions."""

    # --- densification and pruning ---
    densify_from: int = option(500, bounds=(0, 100000))
    """First step at which densification runs."""

    densify_until: int = option(15_000, bounds=(0, 100000))
    """Last step at which densification runs."""

    densify_every: int = option(100, bounds=(1, 100000))
    """Densify and prune every this many steps."""

    grad_threshold: float = option(2e-4, bounds=(0.0, 1.0))
    """Mean view-space (NDC) position-gradient norm above which a Gaussian is densified."""

    clone_scale_fraction: float = option(0.01, bounds=(0.0, 1.0))
    """Gaussians whose largest scale is at most this times the extent are cloned, else split."""

    prune_opacity: float = option(0.005, bounds=(0.0, 1.0))
    """Gaussians with a lower opacity are pruned."""

    prune_scale_fraction: float = option(0.1, bounds=(0.0, 10.0))
    """Gaussians whose largest world scale exceeds this times the extent are pruned."""

    opacity_reset_every: int = option(3000, bounds=(0, 100000))
    """Reset opacities to at most 0.01 every this many steps during densification; 0 = never."""

    max_gaussians: int = option(1_000_000, bounds=(1, 10000000))
    """Densification stops adding Gaussians beyond this count. At the reference size: runs
    grow it with their training pixels (:func:`dcseg.sizes.gaussian_growth`)."""

    @property
    def pull_start(self) -> int:
        """The first iteration of the ``centre_weight`` pull (``centre_from``, default
        ``densify_until``)."""
        return self.densify_until if self.centre_from is None else self.centre_from

    def __post_init__(self) -> None:
        if self.iterations < 0:
            raise ValueError(f"iterations must be >= 0, got {self.iterations}")
        if not 0 <= self.sh_degree <= 3:
            raise ValueError(f"sh_degree must be between 0 and 3, got {self.sh_degree}")
        if self.holdout < 0 or self.holdout == 1:
            raise ValueError(f"holdout must be 0 or >= 2, got {self.holdout}")
        for name in ("sh_degree_interval", "train_downscale", "init_pixel_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.full_res_from is not None and self.full_res_from < 0:
            raise ValueError(f"full_res_from must be >= 0, got {self.full_res_from}")
        if not 0.0 < self.full_res_crop <= 1.0:
            raise ValueError(f"full_res_crop must be in (0, 1], got {self.full_res_crop}")
        if self.densify_every < 1:
            raise ValueError(f"densify_every must be >= 1, got {self.densify_every}")
        if self.voxel_size is not None and self.voxel_size <= 0:
            raise ValueError(f"voxel_size must be > 0, got {self.voxel_size}")
        if not 0.0 < self.init_opacity < 1.0:
            raise ValueError(f"init_opacity must be in (0, 1), got {self.init_opacity}")
        if not 0.0 <= self.ssim_lambda <= 1.0:
            raise ValueError(f"ssim_lambda must be in [0, 1], got {self.ssim_lambda}")
        if self.init_thickness is not None and not 0.0 < self.init_thickness <= 1.0:
            raise ValueError(f"init_thickness must be in (0, 1], got {self.init_thickness}")
        for name in ("thickness_weight", "centre_weight", "centre_band", "opacity_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("centre_behind", "centre_from"):
            if getattr(self, name) is not None and not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.centre_window < 1 or self.centre_window % 2 == 0:
            raise ValueError(f"centre_window must be an odd number >= 1, got {self.centre_window}")
        if self.depth_filter_window < 1 or self.depth_filter_window % 2 == 0:
            raise ValueError(
                f"depth_filter_window must be an odd number >= 1, got {self.depth_filter_window}"
            )
        if not self.depth_filter_k > 0:
            raise ValueError(f"depth_filter_k must be > 0, got {self.depth_filter_k}")
        if self.intrinsics_refinement not in ("auto", "off"):
            raise ValueError(
                f"intrinsics_refinement must be auto or off, got {self.intrinsics_refinement!r}"
            )
        if self.depth_registration not in ("auto", "off"):
            raise ValueError(
                f"depth_registration must be auto or off, got {self.depth_registration!r}"
            )
        for name in ("depth_shift_x", "depth_shift_y"):
            if abs(getattr(self, name)) > 32:
                raise ValueError(f"{name} must be within +-32 pixels, got {getattr(self, name)}")
        if self.exposure not in ("auto", "on", "off"):
            raise ValueError(f"exposure must be auto, on or off, got {self.exposure!r}")
        if self.pose_refinement not in ("auto", "on", "off"):
            raise ValueError(
                f"pose_refinement must be auto, on or off, got {self.pose_refinement!r}"
            )
        if self.pose_lr < 0:
            raise ValueError(f"pose_lr must be >= 0, got {self.pose_lr}")
        if self.pose_from < 0:
            raise ValueError(f"pose_from must be >= 0, got {self.pose_from}")
        if self.pose_align_lr <= 0:
            raise ValueError(f"pose_align_lr must be > 0, got {self.pose_align_lr}")
        if self.pose_align_steps < 0:
            raise ValueError(f"pose_align_steps must be >= 0, got {self.pose_align_steps}")
        if self.blurred_frames not in ("weight", "skip", "off"):
            raise ValueError(
                f"blurred_frames must be weight, skip or off, got {self.blurred_frames!r}"
            )
        if self.max_init_points < 1:
            raise ValueError(f"max_init_points must be >= 1, got {self.max_init_points}")


PAPER = ReconstructConfig()
"""Close to 3DGS: 30k steps, SH degree 3, full resolution."""

FAST = replace(
    PAPER,
    iterations=1500,
    sh_degree=0,
    train_downscale=2,
    full_res_from=900,
    densify_from=300,
    densify_until=1200,
    densify_every=100,
    opacity_reset_every=0,
    means_lr_init=1.6e-4,
    means_lr_final=1.6e-5,
    max_init_points=60_000,
    max_gaussians=120_000,
    full_res_crop=0.5,
)
"""Minutes on a CPU: 1500 steps, SH degree 0; whole views at half resolution until step 900,
then full-resolution windows of half the width and height. The windows replaced whole
full-resolution views (same hour, 40-view 320x240 synthetic scene): a window step costs 139 ms
instead of 446 ms at 120k Gaussians; held-out PSNR 27.96 -> 27.10 dB, depth MAE 1.50 -> 1.59 cm
(README, Performance, for times). Switching to windows at step 600 saved no time (26.80 dB).
A variant that does less work (0.4 windows from step 600, at most 100k Gaussians: 26.49 dB,
1.66 cm, 180 s where this preset then took 229 s) lost 9 segmentation mIoU points at default
mask noise (78.3 vs 87.4, mean over four clustering seeds; the duck merges with its tray,
blocks and dominoes suffer). So did 1300
steps (windows from step 700, densification until 1000): 26.52 dB, segmentation means 83.7
instead of 87.4 at default and 65.4 instead of 73.1 at heavy mask noise."""

SURFACE_PRIORS: dict[str, float | bool] = {"planar_depth": True, "centre_from": 0}
"""The overrides of ``--surface-priors`` (tight surfaces, off by default): the centre pull from
the first step, not only after densification, and each flat Gaussian's depth rendered as its
plane's. The default already reconstructs discs (``init_thickness``) kept thin
(``thickness_weight``) and pulled onto the observed depth after densification
(``centre_weight``, ``centre_from``): centres ~1 cm from the surfaces. These overrides bring them
within a few mm (noise-free 40-view 320x240 scene, fast preset, ``benchmarks/surface_priors.py``:
median 1.4 mm, held-out depth MAE 7.7 mm) but cost segmentation: pulled during densification,
small objects keep fewer opaque Gaussians and merge into their supports' clusters (heavy layout
4: -7.9 mIoU, benchmarks/README "Surface priors and segmentation"). Without ``planar_depth``
thin discs render their centre depth over their whole footprint, which misses slanted surfaces
(the floor at a grazing angle). Cost: 1.25x the reconstruction's wall time."""

REFINE_POSES: dict[str, str] = {"pose_refinement": "on"}
"""The override of ``--refine-poses``: poses are refined whatever the detection says (the same
as ``--pose-refinement on``; the default ``auto`` refines when it detects misaligned poses)."""

PRESETS: dict[str, ReconstructConfig] = {"fast": FAST, "paper": PAPER}
"""Named configurations, selectable with ``dcseg reconstruct --preset``."""
