"""The staged fitter: photos -> HACK parameters, appearance, lighting and cameras.

Stages (each with its own iterations, weights and learning rates, see ``config.py``):

1. landmarks: 68 points per photo (dlib or a user file); jawline points are contours.
2. camera: focal length, camera translation and the head's rotation from landmarks; the
   head's rotation is shared over the 8 cervical joints by the anatomical prior
   (:func:`~hack_render.geometry.skeleton.distribute_head_rotation`).
3. shape: beta, psi and a residual theta from landmarks, with a Gaussian prior on beta,
   a sparse prior on psi, E_rot (Eq. 9) and E_sim (Eq. 10); plus the silhouette term
   (``silhouette.py``: the model's outer contour against the person mask) when the view
   has a mask (a file, or a plain background segmented).
4. photometric: renders through Mitsuba (``hack_render.render.bridge``) at low resolution
   and spp, coarse to fine; skin-masked robust (Charbonnier) loss over alpha, lighting
   and refinements of beta, psi, theta, eta, tau.
5. texel (optional): per-texel albedo refinement with smoothness and symmetry terms.
5b. eyes (``eyes.py``): the lids' opening and the eyeballs' gaze from the face mesh's eye
   contours and irises (landmarks only, no renders).
5c. mouth (``mouth.py``): the jaw and lip shapes and the identity moved so the model's
   teeth stand where the photo's are (the face mesh's inner lips, the rows between them
   read as teeth or the mouth's dark inside), the 68 points held (no renders).
6. final (``final.py``, with the photometric stage's lighting): the views at the photo's
   size, the baked skin, the eyes' colours and ``render.png``'s renders.

Structure: the typed state (``state.py``: :class:`FitState`, :class:`View`,
:class:`Level`), the loss terms (``terms.py``, one robust loss in ``robust.py``), and the
stages (``geometric.py``: camera and shape; ``photometric.py``), each a function of the
state and the config that returns its report; :class:`Fitter` builds the state and runs
the stages in order, and its :class:`FitResult` holds the state and the final stage's
renders (``outputs.py`` only writes them). Nothing in ``fit/`` imports this module but
``outputs.py`` and the CLI (``tests/test_fit_structure.py`` checks the import graph has no cycle).

Multi-view: views share beta, alpha, eta and tau; each has its own camera, head rotation,
neck pose and lighting; expression shared unless ``per_view_expression``.

Camera model: OpenCV pinhole with square pixels and the principal point at the photo's
centre; the camera looks along world -Z at the face (R0 = diag(1, -1, -1)); its
translation, focal length and the head's pose are fitted. For rendering, each view uses a
virtual camera rotated to look at the face, and the photo is resampled into it through
the exact homography K' Rv K^-1 (so the crop needs no off-centre principal point).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from appearance.model import AppearanceModel
from hack_render.errors import HackError
from hack_render.fit import eyes as eyes_stage
from hack_render.fit import final as final_stage
from hack_render.fit import geometric, photometric, terms
from hack_render.fit import mouth as mouth_stage
from hack_render.fit.camera import R0, SENSOR_MM, focal_prior_px
from hack_render.fit.config import FitConfig
from hack_render.fit.final import FinalRenders
from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default
from hack_render.fit.landmarks import JawContour, landmark_weights
from hack_render.fit.photo import Photo
from hack_render.fit.silhouette import (
    ModelSilhouette,
    PhotoSilhouette,
    mask_problem,
    segment_plain_background,
)
from hack_render.fit.stages import FitWarning, StageLog, StageReport
from hack_render.fit.state import FitState, Level, View
from hack_render.geometry import load_default_model
from hack_render.vision import segment as vision_segment
from hack_render.vision.detection import Detection

__all__ = ["R0", "SENSOR_MM", "FitResult", "FitState", "Fitter", "Level", "View",
           "init_state"]


@dataclass
class FitResult:
    """Everything a fit produced (see :class:`Fitter`)."""

    model: object
    appearance: object
    config: FitConfig
    views: list
    beta: torch.Tensor
    psi: torch.Tensor
    alpha: torch.Tensor
    eta: torch.Tensor
    tau: torch.Tensor
    albedo_delta: torch.Tensor | None
    reports: list
    timings: dict
    failures: list
    #: the fitted state (model, parameters, views with their levels and lighting): what
    #: outputs and benchmarks evaluate (``state.forward``, ``state.project``, ...)
    state: FitState | None = None
    #: the final stage's renders, bake and eyes (``final.py``), or None where it did not
    #: run (``final.enabled`` off, or no photometric lighting)
    final: FinalRenders | None = None
    #: the eyes' stage's report (``eyes.py``), or None where it did not run
    eyes: dict | None = None
    #: the mouth's stage's report (``mouth.py``), or None where it did not run
    mouth: dict | None = None


#: weight of the 10 brow landmarks beside the others' 1 (dlib's least certain points; the
#: calibrated embedding's per-point weights already hold them at 0.26-0.51)
BROW_WEIGHT = 1.0


def init_state(photos: list[Photo], detections: list[Detection], config: FitConfig,
               model=None, appearance=None, masks: list | None = None) -> FitState:
    """The state a fit starts from: zero identity and expression, the mean larynx, each
    view's camera placed from its landmarks' size and centre at the prior focal length,
    and its person mask (given, or segmented from a plain background)."""
    if len(photos) != len(detections) or not photos:
        raise HackError("fit: expected one detection per photo and at least one photo.")
    if masks is not None and len(masks) != len(photos):
        raise HackError(f"fit: expected one mask per photo ({len(photos)}), found "
                        f"{len(masks)}.")
    torch.manual_seed(config.seed)
    m = model if model is not None else load_default_model()
    appearance = appearance if appearance is not None else _load_appearance()
    n_expr = m.num_expressions
    beta = torch.zeros(1, min(config.shape.n_beta, m.num_shape), requires_grad=True)
    psi = torch.zeros(1, n_expr, requires_grad=True)
    # eta starts at the identity's mean larynx (1) when the model carries one.
    eta = torch.full((1,), 1.0 if getattr(m, "has_larynx", False) else 0.0, requires_grad=True)
    tau = torch.zeros(1, requires_grad=True)
    n_alpha = min(config.photometric.n_alpha, appearance.n_components) \
        if appearance is not None else 0
    alpha = torch.zeros(1, n_alpha, requires_grad=True)
    const_albedo = torch.tensor([0.46, 0.29, 0.22], requires_grad=True)
    lmk_w = landmark_weights(config.landmarks.jaw_weight, BROW_WEIGHT)
    if config.landmarks.point_weights is not None:
        lmk_w = lmk_w * torch.tensor(config.landmarks.point_weights, dtype=torch.float32)
    silhouette = None
    if config.silhouette.mode != "off":
        silhouette = ModelSilhouette(m, scalp=config.silhouette.scalp,
                                     border_depth=config.silhouette.border_depth)
    state = FitState(m, appearance, beta, psi, eta, tau, alpha, const_albedo,
                     JawContour(m.template.numpy(), m.landmark_indices.numpy()),
                     m.landmark_indices.clone(), _landmark_embedding(config.landmarks.embedding, m),
                     lmk_w, silhouette)
    state.views = [_init_view(state, config, p, d, None if masks is None else masks[i])
                   for i, (p, d) in enumerate(zip(photos, detections))]
    return state


def _init_view(state: FitState, cfg: FitConfig, photo: Photo, det: Detection,
               mask=None) -> View:
    w, h = photo.width, photo.height
    f0 = focal_prior_px(cfg.camera, photo)[0]
    with torch.no_grad():
        lm = state.model().landmarks[0]
    iod_model = float(torch.linalg.vector_norm(lm[36] - lm[45]))
    z = f0 * iod_model / max(det.interocular, 1e-3)
    c_px = det.points.mean(0)
    c3 = (R0 @ lm.mean(0)).numpy()
    cam = np.array([(c_px[0] - w / 2) * z / f0, (c_px[1] - h / 2) * z / f0, z])
    t = torch.tensor(cam - c3, dtype=torch.float32, requires_grad=True)
    psi = torch.zeros(1, state.psi.shape[1], requires_grad=True) \
        if cfg.per_view_expression else None
    # dlib's points, the vision package's (face mesh and shape predictors: calibrated
    # and trained on the embedding's points, hack_render.dataset.composites) and landmark
    # files in dlib's convention go through the embedding; files marked as the model's
    # vertices and any other source (e.g. projections of the true landmark vertices,
    # source "truth") through the landmark vertices
    embedded = state.embedding is not None and (
        det.source in ("dlib", "mesh", "ert")
        or (det.source == "file" and cfg.landmarks.files_follow == "detector"))
    view = View(photo, det, torch.tensor([math.log(f0)], requires_grad=True), t,
                torch.zeros(3, requires_grad=True), torch.zeros(8, 3, requires_grad=True),
                torch.zeros(3, requires_grad=True), psi, embedded=embedded)
    _init_silhouette(state, cfg, view, mask)
    return view


def _init_silhouette(state: FitState, cfg: FitConfig, view: View, mask) -> None:
    """The view's person mask: the given one, else a plain background's (or none)."""
    if state.silhouette is None:
        view.silhouette_note = "off (config silhouette.mode)"
        return
    seg, err = _segment(view) if cfg.silhouette.segment else (None, "off")
    if seg is not None:  # skin and occluders whichever mask the silhouette takes (a mask
        # file's too: without them the bake took a fringe, glasses and hands as skin)
        # the skin inside the face mesh's oval: hair of a skin-like colour and the
        # clothes' edges stay out of the bake
        view.occluder, view.skin = seg.occluder, seg.skin & (seg.face > 0.5)
        if cfg.final.neck and seg.neck is not None:  # and the neck's below the jaw
            view.skin = view.skin | seg.neck
        view.hair, view.clothes, view.face = seg.hair, seg.clothes, seg.face > 0.5
    if mask is not None:
        view.silhouette = PhotoSilhouette.from_mask(mask, "file")
        view.silhouette_note = "mask file"
        view.shoulders = shows_shoulders(np.asarray(mask) > 0.5, view.detection.points)
        return
    m, why = segment_plain_background(view.photo.rgb, view.detection.points,
                                      chroma=cfg.silhouette.chroma)
    if m is not None and mask_problem(m) is not None:  # no outline in the photo to fit
        m, why = None, f"the plain background's mask has {mask_problem(m)}"
    if m is None and cfg.silhouette.segment:
        person = seg.person > 0.5 if seg is not None else None
        if person is not None and mask_problem(person) is None:
            view.silhouette = PhotoSilhouette.from_mask(person, "segmentation")
            view.shoulders = shows_shoulders(person, view.detection.points)
            view.silhouette_note = (f"segmented by {seg.source} ({100 * person.mean():.0f} % "
                                    f"of the photo; occluders {100 * seg.occluder.mean():.1f} %)")
            return
        if person is not None:  # a tight face crop: fit on without the outline, and say so
            err = (f"{mask_problem(person)}: no outline to fit (a tight face crop?); "
                   "fitting without the silhouette term")
            warnings.warn(f"{view.photo.name}: the person segmentation found {err}.",
                          FitWarning, stacklevel=2)
        why = f"{why}; segmentation: {err}"
    if m is None:
        view.silhouette_note = f"none: {why}"
        return
    view.silhouette = PhotoSilhouette.from_mask(m, "plain background")
    view.shoulders = shows_shoulders(m, view.detection.points)
    view.silhouette_note = (f"segmented from a plain background "
                            f"({100 * m.mean():.0f} % of the photo)")


def shows_shoulders(mask: np.ndarray, points: np.ndarray) -> bool:
    """Whether a person mask shows the shoulders: at 0.8 face heights below the chin
    (landmark 8) it is at least 1.8 times as wide as the face (landmarks 0-16)."""
    face_w = float(np.ptp(points[:17, 0]))
    face_h = float(points[8, 1] - points[19:25, 1].min())
    row = round(points[8, 1] + 0.8 * face_h)
    if not 0 <= row < mask.shape[0] or face_w <= 0:
        return False
    cols = np.flatnonzero(mask[row])
    return bool(len(cols)) and float(np.ptp(cols)) >= 1.8 * face_w


def _segment(view: View):
    """(Segmentation, None) of the view's photo by the vision package, or (None, why)."""
    try:
        return vision_segment.segment(view.photo.uint8(), name=view.photo.name), None
    except (ImportError, OSError, HackError) as err:
        return None, str(err)


class Fitter:
    """Builds the :class:`FitState` (``self.state``: the model, the parameters and the
    views; read and write them there) and runs the stages in order (:meth:`run`); its
    methods below evaluate the state with the fitter's config."""

    def __init__(self, photos: list[Photo], detections: list[Detection], config: FitConfig,
                 model=None, appearance=None, progress: bool = True, masks: list | None = None):
        self.cfg, self.progress = config, progress
        self.state = init_state(photos, detections, config, model, appearance, masks)
        self.log = StageLog(progress=progress)
        self.eyes_report: dict | None = None   # the eyes' stage's (fit/eyes.py)
        self.mouth_report: dict | None = None   # the mouth's stage's (fit/mouth.py)

    @property
    def reports(self) -> list[StageReport]:
        return self.log.reports

    @property
    def timings(self) -> dict[str, float]:
        return self.log.timings

    # --- the state's evaluation ---------------------------------------------------------
    def forward(self, v: View):
        return self.state.forward(v)

    def theta(self, v: View) -> torch.Tensor:
        return self.state.theta(v)

    def project(self, v: View, X: torch.Tensor) -> torch.Tensor:
        return self.state.project(v, X)

    def maps(self, with_delta: bool = True, height: int | None = None) -> dict:
        return self.state.maps(with_delta, height)

    def model_landmarks(self, v: View, verts: torch.Tensor, it: int) -> torch.Tensor:
        return terms.model_landmarks(self.state, self.cfg, v, verts, it)

    def view_landmark_weights(self, v: View) -> torch.Tensor:
        return terms.view_landmark_weights(self.state, self.cfg, v)

    def focal_prior_px(self, photo: Photo) -> tuple[float, float, str]:
        return focal_prior_px(self.cfg.camera, photo)

    def focal_prior(self, v: View) -> torch.Tensor:
        return terms.focal_prior(self.cfg, v)

    # --- the stages ---------------------------------------------------------------------
    def fit_camera(self) -> StageReport:
        return geometric.fit_camera(self.state, self.cfg, self.log)

    def fit_shape(self) -> StageReport:
        return geometric.fit_shape_checked(self.state, self.cfg, self.log)

    def photometric(self, texel: bool = False) -> list[StageReport]:
        return photometric.run(self.state, self.cfg, self.log, texel)

    def final(self) -> FinalRenders | None:
        """The final stage at the photo's size (``final.py``), timed as ``final``; None
        where it does not run (:func:`~hack_render.fit.final.wanted`)."""
        if not final_stage.wanted(self.state, self.cfg):
            return None
        t0 = time.perf_counter()
        out = final_stage.run(self.state, self.cfg, self.progress)
        self.log.timings["final"] = self.log.timings.get("final", 0.0) + (
            time.perf_counter() - t0)
        return out

    def run(self) -> FitResult:
        self.fit_camera()
        self.fit_shape()
        if self.cfg.photometric.enabled:
            self.photometric(texel=False)
            if self.cfg.texel.enabled and self.state.appearance is not None:
                self.photometric(texel=True)
        if self.cfg.eyes.enabled:
            self.eyes_report = eyes_stage.fit_eyes(self.state, self.cfg, self.log)
        if self.cfg.mouth.enabled:
            self.mouth_report = mouth_stage.fit_mouth(self.state, self.cfg, self.log)
        final = self.final()
        s = self.state
        return FitResult(s.model, s.appearance, self.cfg, s.views, s.beta, s.psi, s.alpha,
                         s.eta, s.tau, s.albedo_delta, self.log.reports, self.log.timings,
                         [r.failure for r in self.log.reports if r.failure], s, final,
                         self.eyes_report, self.mouth_report)


def _landmark_embedding(name: str, model):
    """The landmark embedding of ``landmarks.embedding`` ("dlib", "vertices" or a path), or
    None for the model's vertices. The shipped "dlib" file falls back to the vertices with
    a warning when it is missing or does not fit the model; a named file must load."""
    if name == "vertices":
        return None
    if name == "dlib":
        return load_default(model)
    return LandmarkEmbedding.load(name, model)


def _load_appearance():
    """The appearance PCA model, or None (constant albedo) when it is unavailable."""
    try:
        return AppearanceModel.load()
    except (ImportError, OSError, HackError):
        return None
