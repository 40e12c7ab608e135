"""Fit configuration: stages, iterations, weights and learning rates, with defaults.

A config file (TOML or YAML) overrides any subset of :class:`FitConfig`'s fields by
section, e.g.::

    [camera]
    iterations = 150
    [photometric]
    resolutions = [64, 128]
    iterations = [40, 30]

Unknown sections or keys are errors (a misspelt key must not be silently ignored); so are
the keys that are no longer settings (:data:`REMOVED`), unless set to the value they are
now fixed at (a config copied from an older fit's report), which is ignored with a warning.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hack_render.errors import HackError
from hack_render.fit.config_final import FinalConfig

DETECTORS = ("dlib", "auto", "both")  # landmarks.detector (fit --detector)

# Each field's comment says what moving it trades. The fitter's internal constants (learning
# rates, robust-loss scales, re-match intervals, the priors' inner weights) are no config
# keys: they live beside their use (``REMOVED`` below lists the former keys and where).


@dataclass
class LandmarkConfig:
    """Stage 1: landmark detection and the landmark loss."""

    # the smallest face fitted (box side, pixels; dlib's and the fallback detector's). Lower:
    # smaller, more distant faces are fitted, from fewer pixels (points that scatter more),
    # and dlib's small false faces (on clothes) become candidates; higher: such faces stop
    # the fit (exit 2) instead of fitting badly
    min_face_px: int = 64
    # weight of the 17 jawline (contour) landmarks: higher, the fitted outline follows dlib's
    # jawline, which scatters most (3.4 % NME against the truth vs 2.7 % for points 18-68);
    # lower, the jaw is left to the inner points, the priors and the silhouette. On 8
    # synthetic subjects (landmark stages only) 0.2 gave 2.32 mm vertex error, 0.5 2.58 mm,
    # 1.0 2.87 mm; with the refined inner points, on subjects 20-39 (disjoint from the
    # benchmark's 0-19): 0.1 1.69 mm (15 of 20 better), 0.05 1.72, 0.2 1.75, 0.3 1.79
    # (bench/results/fit_tune_jaw_20_39.json)
    jaw_weight: float = 0.1
    # 68 per-landmark multipliers on top of jaw_weight (None: all 1): how far each point is
    # trusted, e.g. 0 for the points of a --landmarks file that hair or a hand hides. A point
    # weighted up pulls the fit toward it at the others' expense
    point_weights: list | None = None
    # which surface points the 68 detected points are fitted to: "dlib" (the embedding
    # calibrated to dlib, hack_render/data/landmark_embedding_dlib.npz; the model's
    # landmark vertices, with a warning, if it is missing), "vertices" (ICT's 68 landmark
    # vertices), or the path of an embedding file (hack-render learn landmark-embedding).
    # The calibrated points are where dlib puts them (held out, inner points: dlib 2.68 %
    # of the inter-ocular distance from them, 5.26 % from ICT's vertices; docs/fit.md);
    # "vertices" suits points placed on those vertices; a file, another detector's
    embedding: str = "dlib"
    # dlib's inner points (and chin) refined toward the embedding's points by a regressor
    # of the image trained on synthetic renders (landmark_refiner.py): "dlib" (the shipped
    # hack_render/data/landmark_refiner_dlib.npz; dlib's points, with a warning, if it is
    # missing), "off" (--no-refine), or the path of a refiner file (hack-render learn
    # landmark-refiner). Landmark files are never refined. It halves dlib's error on held-out
    # renders (3.93 -> 1.86 % rms) but moved dlib's points away from hand-placed ones on 4 of
    # 5 real views; the fits barely move either way (docs/fit.md, "Landmark refiner")
    refiner: str = "dlib"
    # --landmarks files follow "detector" (dlib's convention: through the embedding, the
    # jawline re-matched to the contour) or "vertices" (ICT's own: points projected from the
    # model's landmark vertices). The wrong one shifts the brows by ~10 % of the eyes' distance
    files_follow: str = "detector"
    # the 68 points' detector, one of DETECTORS: "dlib" (refined as above; the fallback
    # below where it finds no face), "auto" (the vision package's), "both" (averaged).
    # "dlib" fits the synthetic benchmark best (1.67 vs 2.06 mm with "auto") and is the
    # fastest; "auto" fitted most real portraits better (face region up to +1.1 dB, one
    # 1.0 dB worse) and took up to 38 s longer a fit (docs/fit.md, "The detectors")
    detector: str = "dlib"
    # where dlib finds no face: "auto" (the vision package's auto detector, any angle: the
    # face mesh near frontal, the yaw-ranged shape predictors past 40 degrees), "mesh"
    # (the face mesh alone: near frontal only) or "off" (the fit stops, exit 2, rather than
    # fit the less sure points of profiles); hidden points get no weight
    fallback: str = "auto"


@dataclass
class CameraConfig:
    """Stage 2: focal length, camera translation and head rotation from landmarks."""

    # fewer: a faster stage (each iteration a model forward and backward per view; Grace
    # Hopper's 150 took 5.1-5.7 s, docs/fit.md), the pose and focal less converged before
    # the shape stage takes over (the tests run 40-80)
    iterations: int = 150
    # prior centre, 36 mm sensor width equivalent, where the photo has no focal length of its
    # own: 85 mm, the classic portrait focal length. A single view barely constrains the
    # focal length, so the prior sets it, and a wrong one goes into the shape (at 50 mm the
    # synthetic subjects' shapes absorbed the wrong perspective, CHANGELOG.md): lower for
    # close-up phone photos, higher for telephoto portraits
    focal_mm_prior: float = 85.0
    # a photo's own focal length (EXIF FocalLengthIn35mmFilm, or --focal-mm) replaces the
    # prior centre above, held within ~5 %. False ignores EXIF (a cropped photo's EXIF
    # focal is the uncropped frame's). Synthetic subjects 0-7, landmark stages: 1.74 mm with
    # the 85 mm prior, 1.64 mm at the true focal (CHANGELOG.md)
    use_photo_focal: bool = True
    # false: the focal length stays at the prior's centre (the photo's own when it has one):
    # no trade between focal length and face depth, but an error in it goes into the shape
    fit_focal: bool = True
    # what turns to face the camera: "head" (the neck's joints: a frontal body with the
    # head turned) or "torso" (global_orient: head, neck and chest together, so a
    # three-quarter camera is a turned body, not a twisted neck). The landmarks cannot tell
    # the two apart; "torso" is not the default yet: on subjects whose head turns on a
    # frontal body it costs neck accuracy (benchmark subject, neck joint error 0.06 -> 0.34
    # deg) and the silhouette's identity gain (tests/test_fit_silhouette.py), and the
    # shoulders in a person mask do not yet decide between the two (docs/fit.md)
    rotate: str = "head"


@dataclass
class ShapeConfig:
    """Stage 3: beta, psi, theta (with priors, E_rot, E_sim) from landmarks."""

    # fewer: a faster stage (as the camera stage's iterations), identity and expression
    # less converged (the tests run 40-150)
    iterations: int = 150
    # identity components fitted: more, finer identity, but 68 points pin down few of them
    # and the rest fit the detector's scatter; fewer, a smoother face nearer the mean and
    # faster forwards (the tests run 10-20)
    n_beta: int = 40
    # priors on beta (Gaussian, N(0, I)) and psi, relative to the landmark term, whose
    # unit is 1 % of the face size: higher, faces nearer the mean and the neutral, less of
    # the detector's scatter fitted as identity or expression; lower, more of what the
    # points say (noiseless points: 0.02 each, tests/test_fit_views_texel.py). With a weak psi
    # prior (L2, 0.02) the 53 expressions explained the landmarks instead of the identity
    # (fitted |beta| 0.5 for a true 3-5 on neutral synthetic faces); w_beta 0.05 damps
    # dlib's scatter
    w_beta: float = 0.05
    w_psi: float = 0.3
    # "l1": w_psi * sum(psi) (psi is in [0, 1]): sparse, a smile's two or three strong
    # units cost less than the many weak ones that would mimic an identity; "l2":
    # w_psi * sum(psi^2), which prefers exactly those many weak ones. Landmark stages on
    # 8 synthetic subjects, l1 w_psi 0.1 / 0.2 / 0.3: 2.71 / 2.37 / 2.34 mm; whole fit of
    # the smiling astronaut, landmark NME 3.83 % (l2, w_psi 2) vs 2.89 % (l1 0.3), CHANGELOG.md
    psi_prior: str = "l1"


@dataclass
class SilhouetteConfig:
    """The silhouette term (``silhouette.py``) of the shape stage (and, scaled with the
    shape objective, of the photometric stage): model contour vs the photo's person mask."""

    # "auto": a mask file (--mask) when given, else a mask segmented from a plain
    # background or by the person segmentation (below); "off" (--no-silhouette): no term,
    # the face's and neck's outline from the landmarks alone (the term's identity gain,
    # tests/test_fit_silhouette.py, is lost), no segmentation and no checked second stage
    mode: str = "auto"
    # also fit the scalp's outline: for bald heads or skin-only masks; with hair in the mask
    # it would pull the scalp out to the hair's outline
    scalp: bool = False
    # contour crossings at most this deep inside the model's own footprint (footprint
    # pixels, ~face size / 60) count as its outline (silhouette.select_contour): deeper,
    # more of the model's contour is pulled to the mask's border, folds inside the outline
    # too. Landmark stages on synthetic subjects 20-39 under random presets, chroma masks:
    # 2.5 (the previous default) median 1.90 mm, 1.0 1.62 mm (CHANGELOG.md)
    border_depth: float = 1.0
    # give back shadowed skin the colour key dropped (as dark as the backdrop, but of the
    # skin's chromaticity: silhouette._grow_by_chroma); false, the colour key alone: a
    # backdrop as dark as shadowed skin cuts that skin out of the mask
    chroma: bool = True
    # on a background that is not plain: the person mask of the vision package's
    # segmentation (hack_render.vision.segment; MediaPipe selfie segmentation); on any
    # background and with a mask file: its occluders (hair, hands over the face) left out
    # of the bake, its hair read as the hair layer's style. False: no mask there (no
    # silhouette term) and no occluders left out, and the segmentation's time saved
    segment: bool = True
    # where a view has a mask, run the shape stage once more without it and drop a mask that
    # pulls the points off (an object before the face; geometric.fit_shape_checked). False
    # saves that second shape stage (3-12 s, docs/fit.md) and trusts every mask
    check: bool = True


@dataclass
class PhotometricConfig:
    """Stage 4: photometric refinement through Mitsuba, coarse to fine."""

    # false (--no-photometric): the landmark stages only: no fitted skin, lighting or baked
    # texture, the geometry from landmarks and silhouette alone; minutes faster
    enabled: bool = True
    # the levels' image sizes (--levels) and iterations (--iterations): finer and more, the
    # render closer to the photo, each iteration slower (~ pixels x spp; at 128 px, 4 spp,
    # 0.23-0.25 s on a 2-core CPU, CHANGELOG.md)
    resolutions: list = field(default_factory=lambda: [64, 128])
    iterations: list = field(default_factory=lambda: [40, 30])
    # finer levels after those, each run only where every photo's face crop (twice the
    # landmarks' size, the level's field of view) has at least that many pixels: the fit
    # goes up to the photo's own resolution, never past it (photometric.levels). [] stops at
    # the levels above: faster on large photos, the finer detail unfitted
    fine_resolutions: list = field(default_factory=lambda: [256, 512])
    fine_iterations: list = field(default_factory=lambda: [12, 6])
    # samples per pixel (--spp): more, less Monte Carlo noise in the renders and their
    # gradients, each iteration slower in proportion
    spp: int = 4
    # "sg" (order-2 spherical harmonics plus `lobes` spherical Gaussians on a map of
    # sg_height rows, started from the photo: lighting.py), "sh" (the SH alone) or "env"
    # (free texels: any light, the most unknowns for one photo). Synthetic 20 under random
    # presets: sg 1.60 mm, sh 1.71 mm (window 1.48 vs 1.72, overcast_sun 1.86 vs 1.97);
    # under light_stage within the spread (CHANGELOG.md)
    lighting: str = "sg"
    # rows of the "env" lighting's map: more, sharper lights representable, and more
    # unknowns for the photo to pin down
    env_height: int = 16
    # spherical-Gaussian lobes of "sg": more, several distinct lights representable, and
    # more for one photo to tell apart (a run with two: docs/benchmarks.md)
    lobes: int = 1
    # rows of the "sg" lighting's map: more, sharper lobes rendered, a slower start (its
    # directions' least squares) and renders
    sg_height: int = 32
    # appearance (alpha) components fitted: more, a skin colour closer to the photo, and
    # more of the light's and the shading's error taken into the skin (the tests run 4-6)
    n_alpha: int = 20
    # the lighting's Adam step: higher, the light follows the photo sooner and noisier;
    # 0 holds it as started (bench/bench_fit.py --oracle-lighting)
    lr_light: float = 0.05
    # the step of beta, eta and psi (the head's and joints' at 0.2 x, tau's at 0.01 x):
    # higher, the photo moves the shape sooner and further from where the landmarks put it
    # (a run at 0.01: docs/benchmarks.md); 0 keeps the landmark stages' shape
    lr_geometry: float = 0.005
    # A prior on the light's colour: its colour cast (lighting.Lighting.colour_cast, the
    # squared log-chromaticity of the light on the skin) costs photometric.W_ALPHA / sigma^2
    # times it, i.e. a Gaussian of std sigma per chromaticity axis in the units of alpha's
    # N(0, I) prior (0: none). The skin's colour and the light's are one ambiguity in a
    # photo (the appearance model's leading components are per-channel scales of the skin,
    # which the light's colour undoes), which the two priors settle: higher, a tinted light
    # (warm studio, cool window) is kept in the light, but under grey light the skin's
    # colour goes into the light; lower, the skin keeps its colour and a tinted light lends
    # it its tint. sigma = 0.06: the spread of the benchmark's lighting presets (rms cast on
    # a frontal face: studio 0.057, overcast_sun 0.097, window 0.128, light_stage 0; rms
    # 0.085 over 2 axes), about 2.8 deg rms of white-balance error. Synthetic skin alpha
    # (1.5, -1.0, 0.8) under grey light, whole fit at 128 px: albedo CIEDE2000 5.6-5.8
    # against the mean skin's 13.8 (13.2 without the prior; sigma 0.1: 8.2, 0.05: 4.9;
    # tests/test_fit_alpha.py, CHANGELOG.md)
    light_cast_sigma: float = 0.06
    # the shape stage's objective (landmarks + priors), scaled by this beside the photo
    # term, for dlib's points or a file's: higher, the fit holds to the points and the
    # photo term moves the face less; at 0.001 the photo term tipped the astronaut's head
    # 2.4 deg, her features 5.6-6.3 % of the eyes' distance off dlib's points (2.2 % at
    # 0.01; the face mesh's points: 4.4-4.6 -> 3.4-3.6 %; docs/fit.md)
    w_landmarks: float = 0.01
    # the same for the shape predictors' less sure points (profiles), where the photo's
    # pull is worth more (the cameraman at 0.01: 14.2 -> 18.3 % off the mesh's)
    w_landmarks_fallback: float = 0.001
    # torch's intra-op threads during this stage: more, torch's own ops faster, but its
    # OpenMP workers spin-wait after each parallel op and take cores from Mitsuba's render
    # threads: at 128 px an iteration took 0.27-0.29 s with 2 torch threads vs 0.23-0.25 s
    # with 1 (2-core CPU, CHANGELOG.md); a machine with many cores may gain from more
    torch_threads: int = 1
    # leave the segmentation's occluders (silhouette.segment) out of the photo term: the
    # model is not asked to explain hair or hands, but the segmentation's skin-colour test
    # also flags strongly shadowed skin (a window-lit synthetic face: 10 % of the face
    # mask, and the light's lobe then explained less of the photo, residual ratio 0.67 vs
    # 0.54 without); off by default. The bake always leaves them out
    occluders: bool = False


@dataclass
class TexelConfig:
    """Stage 5 (optional): per-texel albedo refinement beyond the PCA."""

    # (--texel) a per-texel albedo delta at the last level's resolution: skin detail the
    # appearance model lacks, at the cost of this stage's iterations; tuned on synthetic
    # subjects, not yet on real photos
    enabled: bool = False
    iterations: int = 30             # more: a closer delta, each a full-atlas render
    # measured on a synthetic subject (tests/test_fit_views_texel.py): lr 0.02-0.05 makes
    # Adam's sign-like steps on per-texel gradients from a few spp a random walk that
    # raises the photometric loss; 0.005 lowers it. Smoothness and symmetry weights: higher,
    # a smoother, more symmetric delta with less of the photo's detail; 1 / 0.5 left the
    # delta as rough and asymmetric as no regulariser at all; 20 / 20 act measurably
    lr: float = 0.005
    w_smooth: float = 20.0
    w_symmetry: float = 20.0


@dataclass
class EyesConfig:
    """The eyes' stage (``fit/eyes.py``): the lids' opening (``eyeBlink``, ``eyeSquint``,
    ``eyeWide`` per eye) and the eyeballs' gaze from the face mesh's eye contours and
    irises on the photo, after the photometric stage."""

    # false: the eyes as the landmark and photometric stages left them, looking ahead.
    # Off by default: on Grace Hopper it narrows the eyes to her squint, yet the eyes'
    # figure drops (16.51 -> 15.19 dB); the gaze alone costs obama 0.66 dB (docs/fit.md)
    enabled: bool = False
    iterations: int = 60
    # Adam's step for the lid shapes' change and the gaze (radians)
    lr: float = 0.03
    # the lids' weight (0: the lids as they were) and the iris centre's (its two measures,
    # the same unit)
    w_lids: float = 1.0
    # the lower lid's share of the lids' weight (0: the upper lid and the gaze only)
    w_lower: float = 1.0
    w_iris: float = 1.0
    # the face mesh's points read in the landmark embedding's convention (eyes.MESH_OFFSET)
    mesh_offset: bool = True
    # false: the lids only (the eyeballs look ahead)
    gaze: bool = True


@dataclass
class MouthConfig:
    """The mouth's stage (``fit/mouth.py``): the jaw and lip shapes and the identity
    moved so the model's teeth stand where the photo's are, the 68 points held, after
    the photometric stage (and the eyes')."""

    # false: the jaw as the landmark and photometric stages left it. On whole fits of six
    # real photos the face oval's median rose 22.18 -> 24.02 dB (with the teeth's bake
    # inside the mouth's opening), most on a smile with the teeth meeting (obama) and a
    # closed mouth the fit had parted (einstein); the eyes' 19.64 -> 19.33 dB; with the
    # teeth's drop (below) 24.14-24.36 dB (docs/fit.md)
    enabled: bool = True
    # Adam's steps (about 20 ms each on a 2-core machine)
    iterations: int = 60
    # Adam's step for the shapes' and beta's changes
    lr: float = 0.02
    # the teeth term's weight and the 68 points' hold (higher: the lips and chin stay
    # closer to where the stages before put them, the teeth move less). On the kept fits
    # of obama, obama_speech and einstein, hold 1: oval +2.85 / -0.32 / +2.2 dB; 3: +2.68 /
    # +0.11 / +1.97 dB (docs/fit.md)
    w_teeth: float = 1.0
    w_hold: float = 3.0
    # true: the upper teeth's drop under the upper lip (fit/teeth.py) is fitted too where
    # the photo's mouth shows a dark gap (the upper tips at its top where teeth are seen
    # just above it, else not inside it), or their teeth meet (the upper tips at the end
    # of the teeth's rows); false: the teeth where the model places them. Kept fits, the
    # stage run again without / with it: obama_speech 23.54 / 23.69 dB, obama 24.95 /
    # 25.06 dB (docs/fit.md)
    teeth: bool = True


#: config keys that were settings and are now constants beside their use (issue 64):
#: section -> key -> (the constant, its value). A config that sets one to that value (a
#: config copied from an older fit's fit_report.json) is accepted with a warning; any other
#: value is an error, since it would no longer be applied.
REMOVED: dict[str, dict[str, tuple[str, Any]]] = {
    "landmarks": {
        "detector_upsample": ("hack_render.fit.landmarks.detect_landmarks(upsample=1)", 1),
        "max_side_px": ("hack_render.fit.photo.MAX_SIDE_PX", 8000),
        "working_side_px": ("hack_render.fit.photo.WORKING_SIDE_PX", 2048),
        "brow_weight": ("hack_render.fit.fitter.BROW_WEIGHT", 1.0),
        "calibrated_weights": ("hack_render.fit.terms.CALIBRATED_WEIGHTS", True),
        "contour_every": ("hack_render.fit.terms.JAW_REMATCH_EVERY", 10),
        "huber_px": ("hack_render.fit.terms.HUBER_KNEE", 0.01),
    },
    "camera": {
        "lr": ("hack_render.fit.geometric.CAMERA_LR", 0.03),
        "focal_log_sigma": ("hack_render.fit.camera.FOCAL_LOG_SIGMA", 0.35),
        "photo_focal_log_sigma": ("hack_render.fit.camera.PHOTO_FOCAL_LOG_SIGMA", 0.05),
    },
    "shape": {
        "lr": ("hack_render.fit.geometric.SHAPE_LR", 0.02),
        "lr_head": ("hack_render.fit.geometric.HEAD_LR", 0.002),
        "lr_joints": ("hack_render.fit.geometric.JOINTS_LR", 0.0004),
        "lr_torso": ("hack_render.fit.geometric.TORSO_LR", 0.005),
        "w_rot": ("hack_render.fit.terms.W_ROT", 1.0),
        "w_sim": ("hack_render.fit.terms.W_SIM", 0.1),
        "w_dtheta": ("hack_render.fit.terms.W_DTHETA", 0.5),
        "w_global": ("hack_render.fit.terms.W_GLOBAL", 1.0),
        "w_global_torso": ("hack_render.fit.terms.W_GLOBAL_TORSO", 0.01),
        "w_neck": ("hack_render.fit.terms.W_NECK", 0.5),
    },
    "silhouette": {
        "weight": ("hack_render.fit.terms.SILHOUETTE_CONTOUR_WEIGHT", 1.0),
        "w_inside": ("hack_render.fit.terms.SILHOUETTE_INSIDE_WEIGHT", 1.0),
        "contour_every": ("hack_render.fit.terms.SILHOUETTE_CONTOUR_EVERY", 10),
        "max_spread": ("hack_render.fit.silhouette.MAX_SPREAD", 0.06),
    },
    "photometric": {
        "integrator": ("hack_render.fit.photometric.INTEGRATOR", "prb"),
        "lr_alpha": ("hack_render.fit.photometric.LR_ALPHA", 0.05),
        "lr_psi_scale": ("hack_render.fit.photometric.PSI_LR_SCALE", 1.0),
        "w_alpha": ("hack_render.fit.photometric.W_ALPHA", 1e-3),
        "balance_albedo": ("hack_render.fit.photometric.BALANCE_ALBEDO", True),
        "w_silhouette": ("hack_render.fit.photometric.W_SILHOUETTE", 0.001),
        "charbonnier_eps": ("hack_render.fit.photometric.CHARBONNIER_EPS", 0.01),
        "refine_geometry": ("hack_render.fit.photometric.REFINE_GEOMETRY", True),
        "mask_erode_px": ("hack_render.fit.photometric.MASK_ERODE_PX", 1),
        "coarse_maps": ("hack_render.fit.photometric.COARSE_MAPS", True),
    },
    "texel": {
        "w_magnitude": ("hack_render.fit.photometric.TEXEL_W_MAGNITUDE", 0.1),
    },
    "final": {
        "denoise": ("hack_render.fit.texture.DENOISE", "auto"),
        "spp_denoised": ("hack_render.fit.texture.SPP_DENOISED", 64),
        "max_depth": ("hack_render.fit.texture.MAX_DEPTH", 2),
        "edge_px": ("hack_render.fit.bake_weights.EDGE_PX", 2.0),
    },
}


class ConfigWarning(UserWarning):
    """A config sets a key that is no longer a setting, to the value it is fixed at."""


@dataclass
class FitConfig:
    """Everything the fitter reads; see the section classes for the fields."""

    landmarks: LandmarkConfig = field(default_factory=LandmarkConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    shape: ShapeConfig = field(default_factory=ShapeConfig)
    silhouette: SilhouetteConfig = field(default_factory=SilhouetteConfig)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    texel: TexelConfig = field(default_factory=TexelConfig)
    eyes: EyesConfig = field(default_factory=EyesConfig)
    mouth: MouthConfig = field(default_factory=MouthConfig)
    final: FinalConfig = field(default_factory=FinalConfig)
    # (--per-view-expression) multi-view: one expression per photo instead of one shared:
    # photos of different expressions fit, but each view's expression is pinned by its own
    # points only, and the identity no longer gains from the expression being common
    per_view_expression: bool = False
    # the Monte Carlo samples' and the starting draws' seed: another seed gives the same fit
    # with other noise (the spread between seeds is the fit's own noise)
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
        if not float(c.focal_mm_prior) > 0:
            raise HackError(f"config camera.focal_mm_prior: expected > 0, found "
                            f"{c.focal_mm_prior}.")
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
        for key in ("w_landmarks", "w_landmarks_fallback"):
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
        if self.final.eye_colours not in ("pixels", "opening"):
            raise HackError(f"config final.eye_colours: expected 'pixels' or 'opening', "
                            f"found {self.final.eye_colours!r}.")
        if self.shape.psi_prior not in ("l1", "l2"):
            raise HackError(f"config shape.psi_prior: expected 'l1' or 'l2', found "
                            f"{self.shape.psi_prior!r}.")
        mc = self.mouth
        if isinstance(mc.iterations, bool) or not isinstance(mc.iterations, int) \
                or mc.iterations < 0:
            raise HackError(f"config mouth.iterations: expected a whole number >= 0, found "
                            f"{mc.iterations!r}.")
        if not isinstance(mc.teeth, bool):
            raise HackError(f"config mouth.teeth: expected true or false, found {mc.teeth!r}.")
        for key, low in (("lr", 0.0), ("w_teeth", None), ("w_hold", None)):
            x = getattr(mc, key)
            ok = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) \
                and (x > low if low is not None else x >= 0)
            if not ok:
                raise HackError(f"config mouth.{key}: expected a finite number "
                                f"{'> 0' if low is not None else '>= 0'}, found {x!r}.")
        self.final.check()
        for name in ("camera", "shape", "texel"):
            if getattr(self, name).iterations < 0:
                raise HackError(f"config {name}.iterations: expected >= 0.")
        return self


def _removed_key(where: str, section: str, key: str, value) -> bool:
    """A key of :data:`REMOVED`: True (skip it, with a :class:`ConfigWarning`) when set to
    the value it is now fixed at; an error naming it for any other value."""
    const, fixed = REMOVED[section][key]
    if isinstance(fixed, bool) or isinstance(value, bool):
        same = type(value) is type(fixed) and value == fixed
    elif isinstance(fixed, (int, float)):
        same = isinstance(value, (int, float)) and float(value) == float(fixed)
    else:
        same = value == fixed
    if same:
        warnings.warn(f"{where}.{key}: no longer a setting (fixed at {fixed!r}, {const}); "
                      f"ignored, delete it from the config.", ConfigWarning, stacklevel=2)
        return True
    raise HackError(f"{where}.{key}: no longer a setting; it is fixed at {fixed!r} "
                    f"({const}), found {value!r}. Delete it from the config (the value would "
                    f"not be applied).")


def _merge(obj, data: dict, where: str, section: str | None = None):
    if not isinstance(data, dict):
        raise HackError(f"{where}: expected a table/mapping, found {type(data).__name__}.")
    names = {f.name: f for f in dataclasses.fields(obj)}
    for key, value in data.items():
        if key not in names and key in REMOVED.get(section, {}) \
                and _removed_key(where, section, key, value):
            continue
        if key not in names:
            raise HackError(f"{where}: unknown key {key!r}; known keys: {', '.join(names)}.")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            _merge(current, value, f"{where}.{key}", key)
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
                data = tomllib.loads(text)
            elif path.suffix.lower() in (".yaml", ".yml"):
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
