"""Fit configuration: stages, iterations, weights and learning rates, with defaults.

A config file (TOML or YAML) overrides any subset of :class:`FitConfig`'s fields by
section, e.g.::

    [camera]
    iterations = 150
    [photometric]
    resolutions = [64, 128]
    iterations = [40, 30]

Unknown sections or keys are errors (a misspelt key must not be silently ignored).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hack_render.errors import HackError

DETECTORS = ("dlib", "auto", "both")  # landmarks.detector (fit --detector)


@dataclass
class LandmarkConfig:
    """Stage 1: landmark detection and the landmark loss."""

    detector_upsample: int = 1       # dlib pyramid upsampling (finds faces >= ~40 px)
    min_face_px: int = 64            # refuse faces smaller than this (box side, pixels)
    max_side_px: int = 8000          # larger photos are downscaled to working_side_px
    working_side_px: int = 2048
    # weight of the 17 jawline (contour) landmarks; dlib's jawline scatters most (3.4 %
    # NME against the truth vs 2.7 % for points 18-68), and on 8 synthetic subjects
    # (landmark stages only) 0.2 gave 2.32 mm vertex error, 0.5 2.58 mm, 1.0 2.87 mm.
    # With the refined inner points (refiner, below) the unrefined jaw is relatively
    # noisier still: on synthetic subjects 20-39 (disjoint from the benchmark's 0-19),
    # landmark stages, 0.1 gave 1.69 mm (15 of 20 better), 0.05 1.72, 0.2 1.75, 0.3 1.79
    jaw_weight: float = 0.1
    brow_weight: float = 1.0   # of the 10 brow points (dlib's least certain: CHANGELOG.md)
    # 68 per-landmark multipliers on top of the two weights above (None: all 1), e.g.
    # inverse variances of the detector's scatter (CHANGELOG.md, fitting history)
    point_weights: list | None = None
    # also weigh each point by the embedding file's inverse variance of the detector's
    # scatter (landmark_embedding.detector_weights; dlib's points through the embedding
    # only). Synthetic subjects 0-7, landmark stages: 1.66 mm against 1.74 mm unweighted
    calibrated_weights: bool = True
    contour_every: int = 10          # re-match jawline contour vertices every k iterations
    huber_px: float = 0.01           # robust loss knee, as a fraction of the face size
    # which surface points the 68 detected points are fitted to: "dlib" (the embedding
    # calibrated to dlib, hack_render/data/landmark_embedding_dlib.npz; the model's
    # landmark vertices, with a warning, if it is missing), "vertices" (ICT's 68 landmark
    # vertices), or the path of an embedding file (hack-render learn landmark-embedding)
    embedding: str = "dlib"
    # dlib's inner points (and chin) refined toward the embedding's points by a regressor
    # of the image trained on synthetic renders (landmark_refiner.py): "dlib" (the shipped
    # hack_render/data/landmark_refiner_dlib.npz; dlib's points, with a warning, if it is
    # missing), "off", or the path of a refiner file (hack-render learn landmark-refiner).
    # Landmark files are never refined
    refiner: str = "dlib"
    # --landmarks files follow "detector" (dlib's convention) or "vertices" (ICT's own)
    files_follow: str = "detector"
    # the 68 points' detector, one of DETECTORS: "dlib" (refined as above; the fallback
    # below where it finds no face), "auto" (the vision package's), "both" (averaged)
    detector: str = "dlib"
    # where dlib finds no face: "auto" (the vision package's auto detector, any angle: the
    # face mesh near frontal, the yaw-ranged shape predictors past 40 degrees), "mesh"
    # (the face mesh alone) or "off" (the fit stops, exit 2); hidden points get no weight
    fallback: str = "auto"


@dataclass
class CameraConfig:
    """Stage 2: focal length, camera translation and head rotation from landmarks."""

    iterations: int = 150
    lr: float = 0.03
    # prior centre, 36 mm sensor width equivalent: 85 mm, the classic portrait focal
    # length (a single view barely constrains focal length, so the prior sets it; at
    # 50 mm the synthetic subjects' shapes absorbed the wrong perspective, CHANGELOG.md)
    focal_mm_prior: float = 85.0
    focal_log_sigma: float = 0.35    # prior std of log focal length
    # a photo's own focal length (EXIF FocalLengthIn35mmFilm, or --focal-mm) replaces the
    # prior centre above, with this std of log focal length (0.05: ~5 %, a zoom lens's
    # rounding); use_photo_focal false ignores it. Synthetic subjects 0-7, landmark
    # stages: 1.74 mm with the 85 mm prior, 1.64 mm at the true focal (CHANGELOG.md)
    use_photo_focal: bool = True
    photo_focal_log_sigma: float = 0.05
    fit_focal: bool = True
    # what turns to face the camera: "head" (the neck's joints: a frontal body with the
    # head turned) or "torso" (global_orient: head, neck and chest together, so a
    # three-quarter camera is a turned body, not a twisted neck; with shape.w_global_torso
    # and shape.w_neck). The landmarks cannot tell the two apart; "torso" is not the
    # default yet: on subjects whose head turns on a frontal body it costs neck accuracy
    # (benchmark subject, neck joint error 0.06 -> 0.34 deg) and the silhouette's
    # identity gain (tests/test_fit_silhouette.py), and the shoulders in a person mask do
    # not yet decide between the two (docs/fit.md)
    rotate: str = "head"


@dataclass
class ShapeConfig:
    """Stage 3: beta, psi, theta (with priors, E_rot, E_sim) from landmarks."""

    iterations: int = 150
    lr: float = 0.02
    n_beta: int = 40
    # priors on beta (Gaussian, N(0, I)) and psi, relative to the landmark term, whose
    # unit is 1 % of the face size. With a weak psi prior (L2, 0.02) the 53 expressions
    # explained the landmarks instead of the identity (fitted |beta| 0.5 for a true 3-5
    # on neutral synthetic faces); w_beta 0.05 damps dlib's scatter
    w_beta: float = 0.05
    w_psi: float = 0.3
    # "l1": w_psi * sum(psi) (psi is in [0, 1]): sparse, a smile's two or three strong
    # units cost less than the many weak ones that would mimic an identity; "l2":
    # w_psi * sum(psi^2), which prefers exactly those many weak ones. Landmark stages on
    # 8 synthetic subjects, l1 w_psi 0.1 / 0.2 / 0.3: 2.71 / 2.37 / 2.34 mm; whole fit of
    # the smiling astronaut, landmark NME 3.83 % (l2, w_psi 2) vs 2.89 % (l1 0.3), CHANGELOG.md
    psi_prior: str = "l1"
    lr_head: float = 0.002           # head and torso rotation (radians)
    lr_joints: float = 0.0004        # residual per-joint rotations (radians)
    w_rot: float = 1.0               # E_rot (paper Eq. 9)
    w_sim: float = 0.1               # E_sim (paper Eq. 10, normalised by joint ranges)
    w_dtheta: float = 0.5            # residual joint rotations beyond the anatomical share
    w_global: float = 1.0            # torso (global) rotation prior (camera.rotate "head")
    # camera.rotate "torso": a weak torso prior (the camera may stand anywhere about the
    # body) and the neck's rotation (head_angles) costing w_neck per rad^2, so a turn the
    # landmarks cannot place goes to the torso (synthetic: camera yaw 30 deg, neck 3 deg
    # -> fitted neck yaw ~7 deg, 32 deg in "head" mode; tests/test_fit_views.py)
    w_global_torso: float = 0.01
    w_neck: float = 0.5
    lr_torso: float = 0.005          # torso rotation (radians), "torso" mode


@dataclass
class SilhouetteConfig:
    """The silhouette term (``silhouette.py``) of the shape stage (and, scaled with the
    shape objective, of the photometric stage): model contour vs the photo's person mask."""

    # "auto": a mask file (--mask) when given, else a mask segmented from a plain
    # background (none, and no term, on a cluttered one); "off": no silhouette term
    mode: str = "auto"
    weight: float = 1.0              # contour points on the mask's border
    w_inside: float = 1.0            # skin vertices projected outside the mask
    scalp: bool = False              # also fit the scalp's outline (bald or skin-only masks)
    contour_every: int = 10          # re-select the model's outer contour every k iterations
    # contour crossings at most this deep inside the model's own footprint (footprint
    # pixels, ~face size / 60) count as its outline (silhouette.select_contour); landmark
    # stages on synthetic subjects 20-39 under random presets, chroma masks: 2.5 (the
    # previous default) median 1.90 mm, 1.0 1.62 mm (CHANGELOG.md)
    border_depth: float = 1.0
    # a border pixel within this colour distance (sRGB) of the border median is background;
    # under 60 % of the border so: a cluttered background, no automatic mask
    max_spread: float = 0.06
    # give back shadowed skin the colour key dropped (as dark as the backdrop, but of the
    # skin's chromaticity: silhouette._grow_by_chroma)
    chroma: bool = True
    # on a background that is not plain: the person mask of the vision package's
    # segmentation (hack_render.vision.segment; MediaPipe selfie segmentation), and its
    # occluders (hair, hands over the face) left out of the photometric term
    segment: bool = True
    check: bool = True   # a mask pulling the points off is dropped (fit_shape_checked)


@dataclass
class PhotometricConfig:
    """Stage 4: photometric refinement through Mitsuba, coarse to fine."""

    enabled: bool = True
    resolutions: list = field(default_factory=lambda: [64, 128])
    iterations: list = field(default_factory=lambda: [40, 30])
    # finer levels after those, each run only where every photo's face crop (twice the
    # landmarks' size, the level's field of view) has at least that many pixels: the fit
    # goes up to the photo's own resolution, never past it (photometric.levels)
    fine_resolutions: list = field(default_factory=lambda: [256, 512])
    fine_iterations: list = field(default_factory=lambda: [12, 6])
    spp: int = 4
    integrator: str = "prb"
    # "sg" (order-2 spherical harmonics plus `lobes` spherical Gaussians on a map of
    # sg_height rows, started from the photo: lighting.py), "sh" (the SH alone) or "env"
    # (free texels). Synthetic 20 under random presets: sg 1.60 mm, sh 1.71 mm (window
    # 1.48 vs 1.72, overcast_sun 1.86 vs 1.97); under light_stage within the spread (CHANGELOG.md)
    lighting: str = "sg"
    env_height: int = 16
    lobes: int = 1
    sg_height: int = 32
    n_alpha: int = 20
    lr_alpha: float = 0.05
    lr_light: float = 0.05
    lr_geometry: float = 0.005
    # the expressions' step, relative to lr_geometry; 0 holds them where the landmark
    # stages left them (random-preset benchmark: median 1.73 vs 1.71 mm, mean 1.66 vs
    # 1.69 mm on neutral subjects; CHANGELOG.md)
    lr_psi_scale: float = 1.0
    w_alpha: float = 1e-3
    # A prior on the light's colour: its colour cast (lighting.Lighting.colour_cast, the
    # squared log-chromaticity of the light on the skin) costs w_alpha / sigma^2 times it,
    # i.e. a Gaussian of std sigma per chromaticity axis in the units of alpha's N(0, I)
    # prior (0: none). The skin's colour and the light's are one ambiguity in a photo (the
    # appearance model's leading components are per-channel scales of the skin, which the
    # light's colour undoes), which the two priors settle. sigma = 0.06: the spread of the
    # benchmark's lighting presets (rms cast on a frontal face: studio 0.057, overcast_sun
    # 0.097, window 0.128, light_stage 0; rms 0.085 over 2 axes), about 2.8 deg rms of
    # white-balance error. Synthetic skin alpha (1.5, -1.0, 0.8) under grey light, whole
    # fit at 128 px: albedo CIEDE2000 5.6-5.8 against the mean skin's 13.8 (13.2 without the
    # prior; sigma 0.1: 8.2, 0.05: 4.9; tests/test_fit_alpha.py, CHANGELOG.md)
    light_cast_sigma: float = 0.06
    # start the photometric stage at the two priors' optimum along that ambiguity, which
    # Adam's noisy steps barely move along (photometric.balance_albedo)
    balance_albedo: bool = True
    # the shape stage's objective (landmarks + priors), scaled by this beside the photo
    # term, for dlib's points or a file's: at 0.001 the photo term tipped the astronaut's
    # head 2.4 deg, her features 5.6-6.3 % of the eyes' distance off dlib's points (2.2 %
    # at 0.01; the face mesh's points: 4.4-4.6 -> 3.4-3.6 %; docs/fit.md)
    w_landmarks: float = 0.01
    # the same for the shape predictors' less sure points (profiles), where the photo's
    # pull is worth more (the cameraman at 0.01: 14.2 -> 18.3 % off the mesh's)
    w_landmarks_fallback: float = 0.001
    # the silhouette term's scale in this stage (the shape stage's weights times this)
    w_silhouette: float = 0.001
    charbonnier_eps: float = 0.01    # robust loss scale (linear RGB)
    refine_geometry: bool = True     # beta, psi, theta, eta, tau refinement
    mask_erode_px: int = 1
    # render each level with the coarsest mip of the skin maps that still has a texel per
    # pixel (photometric.level_map_height: 128 rows at 128 px); the torch maps' forward and
    # backward cost falls with the texel count (CHANGELOG.md, the bridge's overhead)
    coarse_maps: bool = True
    # torch's intra-op threads during this stage. Its OpenMP workers spin-wait after each
    # parallel op and take cores from Mitsuba's render threads: at 128 px an iteration
    # took 0.27-0.29 s with 2 torch threads vs 0.23-0.25 s with 1 (2-core CPU, CHANGELOG.md)
    torch_threads: int = 1
    # leave the segmentation's occluders (silhouette.segment) out of the photo term. Off
    # by default: its skin-colour test also flags strongly shadowed skin (a window-lit
    # synthetic face: 10 % of the face mask, and the light's lobe then explained less of
    # the photo, residual ratio 0.67 vs 0.54 without); the bake always leaves them out
    occluders: bool = False


@dataclass
class TexelConfig:
    """Stage 5 (optional): per-texel albedo refinement beyond the PCA."""

    enabled: bool = False
    iterations: int = 30
    # measured on a synthetic subject (tests/test_fit_views_texel.py): lr 0.02-0.05 makes
    # Adam's sign-like steps on per-texel gradients from a few spp a random walk that
    # raises the photometric loss; 0.005 lowers it. Weights 1 / 0.5 left the delta as
    # rough and asymmetric as no regulariser at all; 20 / 20 act measurably.
    lr: float = 0.005
    w_smooth: float = 20.0
    w_symmetry: float = 20.0
    w_magnitude: float = 0.1


@dataclass
class FinalConfig:
    """After the stages: the fit re-rendered at the photo's size (``render.png``) and the
    photo(s) baked into a per-texel diffuse map (``texture.py``)."""

    enabled: bool = True
    # samples per pixel of render.png (and of the render the bake divides the photo by)
    # without a denoiser; with Intel OIDN (the denoise extra, render/denoise.py) and
    # denoise "auto": spp_denoised samples, denoised with the render's albedo and normals
    spp: int = 256
    denoise: str = "auto"
    spp_denoised: int = 64
    max_depth: int = 2               # path depth: the photometric stage's (direct light)
    max_side: int = 1024             # render.png's long side at most (the photo's size below)
    atlas_height: int = 1024         # the baked diffuse map: atlas_height x 2 atlas_height
    edge_px: float = 2.0             # photo pixels dropped inside the render's silhouette
    # robust rejection of pixels the render cannot explain (occluders, clothes): the log
    # ratio photo / render and the chromaticity beyond this many MADs of the skin's
    reject_sigma: float = 3.0
    # bake the brows, lips and lids (bands about their landmarks) as the photo has them:
    # the skin test and the robust rejection would drop them (their colour is not the
    # skin's), leaving the model's browless mean skin there
    features: bool = True
    # passes that bake the photo over the re-render once more (render.png's own light
    # transport, pixel filter and denoiser divided out): 0 bakes against the fitted maps'
    # render only
    refine: int = 1
    # the eyes left out of the bake: their landmark rings scaled by this about their
    # centres; with features, the lids' band from bake_weights.LID_INNER to it is baked
    eye_hole: float = 1.8
    # the fallback map (A(alpha)) where the photo does not see, tone-matched to the baked
    # skin by a smooth gain field (texture.tone_matched_prior): "outside" the seen face
    # (scalp, neck, ears: no seam at the face's edge), "all" (the holes inside too: eyes,
    # mouth, nostrils) or "off" (A(alpha) as it is)
    tone_match: str = "outside"
    # the occluders (hair, hands, glasses) grown by this share of the eyes' outer-corner
    # distance before the bake leaves them out (a fringe's strands and shadow). 0: 0.08
    # costs the astronaut's face region 0.4 dB, Grace Hopper's 1.1 dB (docs/fit.md)
    occluder_margin: float = 0.0
    # the shadow the occluders and the hair cast on the skin beside them (a fringe's on
    # the forehead), looked for up to this share of the eyes' outer-corner distance and
    # divided out of the bake (fit/occluder_shadow.py): the hairless render has no such
    # shadow, so baked it is a dark rim along the fringe; 0 bakes it as the photo has it
    # (the same view's PSNR is higher so: docs/fit.md)
    occluder_shadow: float = 0.1
    # the bake's confidence at its edges faded (min with itself blurred by a Gaussian of this
    # many pixel footprints): the skin meets the fallback softly, not along a jagged edge
    edge_feather: float = 4.0
    # the specular map times a gain per region where the photo's highlights identify it
    # (fit/specular_bake.py). Off: the fitted light's error is read as gloss (docs/fit.md)
    specular: bool = False


@dataclass
class FitConfig:
    """Everything the fitter reads; see the section classes for the fields."""

    landmarks: LandmarkConfig = field(default_factory=LandmarkConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    shape: ShapeConfig = field(default_factory=ShapeConfig)
    silhouette: SilhouetteConfig = field(default_factory=SilhouetteConfig)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    texel: TexelConfig = field(default_factory=TexelConfig)
    final: FinalConfig = field(default_factory=FinalConfig)
    per_view_expression: bool = False
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def validate(self) -> FitConfig:
        lm = self.landmarks
        if lm.point_weights is not None:
            w = np.asarray(lm.point_weights, dtype=float)
            if w.shape != (68,) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
                raise HackError("config landmarks.point_weights: expected 68 finite weights "
                                f">= 0 with a positive sum, found shape {w.shape}, min "
                                f"{w.min() if w.size else 'n/a'}.")
        for key, ok in (("detector", DETECTORS),
                        ("fallback", ("auto", "mesh", "off")),
                        ("files_follow", ("detector", "vertices"))):
            if getattr(lm, key) not in ok:
                raise HackError(f"config landmarks.{key}: expected one of "
                                f"{', '.join(map(repr, ok))}, found {getattr(lm, key)!r}.")
        if not isinstance(lm.embedding, str) or not lm.embedding:
            raise HackError(f"config landmarks.embedding: expected 'dlib', 'vertices' or an "
                            f"embedding file path, found {lm.embedding!r}.")
        if not isinstance(lm.refiner, str) or not lm.refiner or (
                lm.refiner not in ("dlib", "off") and not Path(lm.refiner).is_file()):
            raise HackError(f"config landmarks.refiner: expected 'dlib', 'off' or the path of "
                            f"a refiner file (hack-render learn landmark-refiner), found "
                            f"{lm.refiner!r}.")
        c = self.camera
        for key in ("focal_log_sigma", "photo_focal_log_sigma", "focal_mm_prior"):
            if not float(getattr(c, key)) > 0:
                raise HackError(f"config camera.{key}: expected > 0, found {getattr(c, key)}.")
        p = self.photometric
        if len(p.resolutions) != len(p.iterations):
            raise HackError(f"config photometric: expected as many iterations as resolutions, "
                            f"found {len(p.iterations)} and {len(p.resolutions)}.")
        if len(p.fine_resolutions) != len(p.fine_iterations):
            raise HackError(f"config photometric: expected as many fine_iterations as "
                            f"fine_resolutions, found {len(p.fine_iterations)} and "
                            f"{len(p.fine_resolutions)}.")
        if any(not 16 <= int(r) <= 1024 for r in list(p.resolutions) + list(p.fine_resolutions)):
            raise HackError(f"config photometric.resolutions: expected 16..1024 px, found "
                            f"{p.resolutions}.")
        if p.lighting not in ("sh", "env", "sg"):
            raise HackError(f"config photometric.lighting: expected 'sh', 'env' or 'sg', "
                            f"found {p.lighting!r}.")
        if not 1 <= p.lobes <= 4:
            raise HackError(f"config photometric.lobes: expected 1..4, found {p.lobes}.")
        for key in ("env_height", "sg_height"):
            if not 4 <= getattr(p, key) <= 256:
                raise HackError(f"config photometric.{key}: expected 4..256 rows, found "
                                f"{getattr(p, key)}.")
        if not (math.isfinite(p.light_cast_sigma) and p.light_cast_sigma >= 0):
            raise HackError(f"config photometric.light_cast_sigma: expected a finite number "
                            f">= 0 (0: no prior on the light's colour), found "
                            f"{p.light_cast_sigma}.")
        for key in ("w_landmarks", "w_landmarks_fallback", "w_silhouette"):
            x = getattr(p, key)
            if not (math.isfinite(x) and x >= 0):
                raise HackError(f"config photometric.{key}: expected a finite number >= 0, "
                                f"found {x}.")
        if p.torch_threads < 1:
            raise HackError(f"config photometric.torch_threads: expected >= 1, found "
                            f"{p.torch_threads}.")
        if not 1 <= p.spp <= 1024:
            raise HackError(f"config photometric.spp: expected 1..1024, found {p.spp}.")
        if self.silhouette.mode not in ("auto", "off"):
            raise HackError(f"config silhouette.mode: expected 'auto' or 'off', found "
                            f"{self.silhouette.mode!r}.")
        bd = self.silhouette.border_depth
        if isinstance(bd, bool) or not isinstance(bd, (int, float)) or not 0 < bd < 100:
            raise HackError(f"config silhouette.border_depth: expected a number of footprint "
                            f"pixels in (0, 100), found {bd!r}.")
        if not isinstance(self.silhouette.chroma, bool):
            raise HackError(f"config silhouette.chroma: expected true or false, found "
                            f"{self.silhouette.chroma!r}.")
        if self.camera.rotate not in ("torso", "head"):
            raise HackError(f"config camera.rotate: expected 'torso' or 'head', found "
                            f"{self.camera.rotate!r}.")
        if self.shape.psi_prior not in ("l1", "l2"):
            raise HackError(f"config shape.psi_prior: expected 'l1' or 'l2', found "
                            f"{self.shape.psi_prior!r}.")
        fc = self.final
        if fc.denoise not in ("auto", "off"):
            raise HackError(f"config final.denoise: expected 'auto' or 'off', found "
                            f"{fc.denoise!r}.")
        if not 1 <= fc.spp <= 4096 or not 1 <= fc.max_depth <= 16:
            raise HackError(f"config final: expected spp 1..4096 and max_depth 1..16, found "
                            f"{fc.spp} and {fc.max_depth}.")
        if not 64 <= fc.atlas_height <= 4096 or not 16 <= fc.max_side <= 8192:
            raise HackError(f"config final: expected atlas_height 64..4096 and max_side "
                            f"16..8192, found {fc.atlas_height} and {fc.max_side}.")
        if isinstance(fc.refine, bool) or not isinstance(fc.refine, int) or not 0 <= fc.refine <= 4:
            raise HackError(f"config final.refine: expected 0..4 passes, found {fc.refine!r}.")
        if not (isinstance(fc.eye_hole, (int, float)) and math.isfinite(fc.eye_hole)
                and 0 < fc.eye_hole <= 4):
            raise HackError(f"config final.eye_hole: expected a scale in (0, 4], found "
                            f"{fc.eye_hole!r}.")
        for key, hi, unit in (("edge_feather", 32, "photo pixels' footprints"),
                              ("occluder_shadow", 1, "of the eyes' corner distance"),
                              ("occluder_margin", 1, "of the eyes' corner distance")):
            x = getattr(fc, key)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and 0 <= x <= hi):
                raise HackError(f"config final.{key}: expected 0..{hi} ({unit}), found {x!r}.")
        if fc.tone_match not in ("outside", "all", "off"):
            raise HackError(f"config final.tone_match: expected 'outside', 'all' or 'off', "
                            f"found {fc.tone_match!r}.")
        for name in ("camera", "shape", "texel"):
            if getattr(self, name).iterations < 0:
                raise HackError(f"config {name}.iterations: expected >= 0.")
        if not (math.isfinite(self.photometric.lr_psi_scale)
                and self.photometric.lr_psi_scale >= 0):
            raise HackError(f"config photometric.lr_psi_scale: expected a finite number "
                            f">= 0, found {self.photometric.lr_psi_scale}.")
        return self


def _merge(obj, data: dict, where: str):
    if not isinstance(data, dict):
        raise HackError(f"{where}: expected a table/mapping, found {type(data).__name__}.")
    names = {f.name: f for f in dataclasses.fields(obj)}
    for key, value in data.items():
        if key not in names:
            raise HackError(f"{where}: unknown key {key!r}; known keys: {', '.join(names)}.")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            _merge(current, value, f"{where}.{key}")
            continue
        if isinstance(current, bool) and not isinstance(value, bool):
            raise HackError(f"{where}.{key}: expected true/false, found {value!r}.")
        if isinstance(current, (int, float)) and not isinstance(current, bool):
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise HackError(f"{where}.{key}: expected a number, found {value!r}.")
            value = type(current)(value) if isinstance(current, float) else value
        if isinstance(current, list) and not isinstance(value, list):
            raise HackError(f"{where}.{key}: expected a list, found {value!r}.")
        setattr(obj, key, value)


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> FitConfig:
    """Defaults, then a TOML/YAML/JSON file's sections, then ``overrides`` (same shape)."""
    cfg = FitConfig()
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise HackError(f"--config {path}: file not found.")
        text = path.read_text()
        try:
            if path.suffix.lower() == ".toml":
                import tomllib

                data = tomllib.loads(text)
            elif path.suffix.lower() in (".yaml", ".yml"):
                import yaml

                data = yaml.safe_load(text) or {}
            else:
                data = json.loads(text)
        except Exception as err:  # parser errors differ per format
            raise HackError(f"--config {path}: not valid {path.suffix.lstrip('.').upper()}: "
                            f"{err}") from err
        _merge(cfg, data, str(path))
    if overrides:
        _merge(cfg, overrides, "overrides")
    return cfg.validate()


def tiny_overrides() -> dict:
    """Settings for tests and CI (tests/test_fit_e2e.py; timed by
    ``bench/bench_fit.py --astronaut --tiny``): tiny resolution, few samples and iterations."""
    return {"camera": {"iterations": 40}, "shape": {"iterations": 40, "n_beta": 20},
            "photometric": {"resolutions": [24], "iterations": [4], "spp": 2, "n_alpha": 6,
                            "fine_resolutions": [], "fine_iterations": []},
            "texel": {"iterations": 3},
            "final": {"spp": 8, "atlas_height": 128, "max_side": 128}}
