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
from dataclasses import dataclass, field

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.fit.config import FitConfig
from hack_render.fit.landmarks import Detection, JawContour, landmark_weights
from hack_render.fit.lighting import Lighting
from hack_render.fit.photo import Photo
from hack_render.fit.stages import StageReport, run_stage
from hack_render.geometry.larynx import ETA_RANGE, TAU_RANGE_M
from hack_render.geometry.skeleton import (adjacent_similarity_penalty, distribute_head_rotation,
                                           rotation_limit_penalty)

R0 = torch.tensor([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
SENSOR_MM = 36.0


@dataclass
class View:
    """One photo and its own parameters (torch leaves)."""

    photo: Photo
    detection: Detection
    log_focal: torch.Tensor
    transl: torch.Tensor          # camera t (3,), metres: x_cam = R0 X + t
    head_angles: torch.Tensor     # (3,) whole-head Euler angles, radians
    dtheta: torch.Tensor          # (8, 3) residual per-joint axis-angle
    global_orient: torch.Tensor   # (3,) torso rotation
    psi: torch.Tensor | None      # (1, E) when expressions are per view
    lighting: Lighting | None = None
    lighting_init: list = field(default_factory=list)  # init_lobes' report ("sg" lighting)
    renderer: object = None       # DiffRenderer of the current photometric level
    silhouette: object = None     # PhotoSilhouette (person mask), or None: no silhouette term
    silhouette_note: str = ""     # where the mask came from, or why there is none
    embedded: bool = False        # landmarks are the embedding's points (else vertices)
    level: dict = field(default_factory=dict)

    @property
    def focal(self) -> torch.Tensor:
        return torch.exp(self.log_focal)


@dataclass
class FitResult:
    """Everything a fit produced (see :func:`fit`)."""

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


class Fitter:
    """Holds the model, appearance model and parameters; runs the stages in order."""

    def __init__(self, photos: list[Photo], detections: list[Detection], config: FitConfig,
                 model=None, appearance=None, progress: bool = True, masks: list | None = None):
        from hack_render.geometry import load_default_model

        if len(photos) != len(detections) or not photos:
            raise HackError("fit: expected one detection per photo and at least one photo.")
        torch.manual_seed(config.seed)
        self.cfg, self.progress = config, progress
        self.model = model if model is not None else load_default_model()
        self.appearance = appearance if appearance is not None else _load_appearance()
        m = self.model
        self.n_expr = m.num_expressions
        self.beta = torch.zeros(1, min(config.shape.n_beta, m.num_shape), requires_grad=True)
        self.psi = torch.zeros(1, self.n_expr, requires_grad=True)
        # eta starts at the identity's mean larynx (1) when the model carries one.
        self.eta = torch.full((1,), 1.0 if getattr(m, "has_larynx", False) else 0.0, requires_grad=True)
        self.tau = torch.zeros(1, requires_grad=True)
        n_alpha = min(config.photometric.n_alpha, self.appearance.n_components) \
            if self.appearance is not None else 0
        self.alpha = torch.zeros(1, n_alpha, requires_grad=True)
        self.const_albedo = torch.tensor([0.46, 0.29, 0.22], requires_grad=True)
        self.albedo_delta: torch.Tensor | None = None
        self.jaw = JawContour(m.template.numpy(), m.landmark_indices.numpy())
        self.lmk_idx = m.landmark_indices.clone()
        self.embedding = _landmark_embedding(config.landmarks.embedding, m)
        self.lmk_w = landmark_weights(config.landmarks.jaw_weight, config.landmarks.brow_weight)
        if config.landmarks.point_weights is not None:
            self.lmk_w = self.lmk_w * torch.tensor(config.landmarks.point_weights,
                                                   dtype=torch.float32)
        self.faces = m.faces
        if masks is not None and len(masks) != len(photos):
            raise HackError(f"fit: expected one mask per photo ({len(photos)}), found "
                            f"{len(masks)}.")
        self.silhouette = None
        if config.silhouette.mode != "off":
            from hack_render.fit.silhouette import ModelSilhouette

            self.silhouette = ModelSilhouette(m, scalp=config.silhouette.scalp,
                                              border_depth=config.silhouette.border_depth)
        self.views = [self._init_view(p, d, None if masks is None else masks[i])
                      for i, (p, d) in enumerate(zip(photos, detections))]
        self.reports: list[StageReport] = []
        self.timings: dict[str, float] = {}
        self._coarse_appearance: dict = {}  # (height, n_alpha) -> downsampled model

    # --- parameters -----------------------------------------------------------------
    def _init_view(self, photo: Photo, det: Detection, mask=None) -> View:
        w, h = photo.width, photo.height
        f0 = self.focal_prior_px(photo)[0]
        with torch.no_grad():
            lm = self.model().landmarks[0]
        iod_model = float(torch.linalg.vector_norm(lm[36] - lm[45]))
        z = f0 * iod_model / max(det.interocular, 1e-3)
        c_px = det.points.mean(0)
        c3 = (R0 @ lm.mean(0)).numpy()
        cam = np.array([(c_px[0] - w / 2) * z / f0, (c_px[1] - h / 2) * z / f0, z])
        t = torch.tensor(cam - c3, dtype=torch.float32, requires_grad=True)
        psi = torch.zeros(1, self.n_expr, requires_grad=True) if self.cfg.per_view_expression \
            else None
        # dlib's points, and landmark files in dlib's convention, go through the embedding;
        # files marked as the model's vertices and any other source (e.g. projections of
        # the true landmark vertices, source "truth") through the landmark vertices
        embedded = self.embedding is not None and (
            det.source == "dlib"
            or (det.source == "file" and self.cfg.landmarks.files_follow == "detector"))
        view = View(photo, det, torch.tensor([math.log(f0)], requires_grad=True), t,
                    torch.zeros(3, requires_grad=True), torch.zeros(8, 3, requires_grad=True),
                    torch.zeros(3, requires_grad=True), psi, embedded=embedded)
        self._init_silhouette(view, mask)
        return view

    def _init_silhouette(self, view: View, mask) -> None:
        """The view's person mask: the given one, else a plain background's (or none)."""
        from hack_render.fit.silhouette import PhotoSilhouette, segment_plain_background

        if self.silhouette is None:
            view.silhouette_note = "off (config silhouette.mode)"
            return
        if mask is not None:
            view.silhouette = PhotoSilhouette.from_mask(mask, "file")
            view.silhouette_note = "mask file"
            return
        m, why = segment_plain_background(view.photo.rgb, view.detection.points,
                                          max_spread=self.cfg.silhouette.max_spread,
                                          chroma=self.cfg.silhouette.chroma)
        if m is None:
            view.silhouette_note = f"none: {why}"
            return
        view.silhouette = PhotoSilhouette.from_mask(m, "plain background")
        view.silhouette_note = (f"segmented from a plain background "
                                f"({100 * m.mean():.0f} % of the photo)")

    def view_psi(self, v: View) -> torch.Tensor:
        return v.psi if v.psi is not None else self.psi

    def theta(self, v: View) -> torch.Tensor:
        """(1, 8, 3) neck pose: the head rotation's anatomical share plus the residual."""
        return (distribute_head_rotation(v.head_angles, clamp=False) + v.dtheta)[None]

    def forward(self, v: View):
        return self.model(beta=self.beta, psi=self.view_psi(v), theta=self.theta(v),
                          global_orient=v.global_orient[None], eta=self.eta,
                          tau=self.tau)

    # --- projection and landmark loss -------------------------------------------------
    def project(self, v: View, X: torch.Tensor) -> torch.Tensor:
        """World points (..., 3) -> photo pixels (..., 2) (continuous coordinates)."""
        cam = X @ R0.T + v.transl
        f = v.focal
        uv = f * cam[..., :2] / cam[..., 2:3].clamp_min(1e-4)
        return uv + torch.tensor([v.photo.width / 2.0, v.photo.height / 2.0])

    def camera_centre(self, v: View) -> np.ndarray:
        return (-R0.T @ v.transl.detach()).numpy()

    def model_landmarks(self, v: View, verts: torch.Tensor, it: int) -> torch.Tensor:
        """(68, 3) landmark points with the jawline re-matched to the contour: the
        calibrated embedding's surface points (barycentric interpolation, differentiable)
        when the view uses it, else the model's landmark vertices."""
        if it % max(1, self.cfg.landmarks.contour_every) == 0:
            from hack_render.render.bridge import vertex_normals_torch

            with torch.no_grad():
                vv = verts.detach()
                n = vertex_normals_torch(vv, self.faces).numpy()
                tgt = v.detection.points
                self.jaw.match(vv.numpy(), n, self.camera_centre(v),
                               lambda p: self.project(v, torch.as_tensor(p)).numpy(), tgt)
                v.level["jaw"] = self.jaw.current.copy()
        if v.embedded:
            pts = self.embedding.points(verts)
            if "jaw" in v.level:  # contour points; a fixed jaw point (the chin) stays embedded
                fixed = torch.tensor([len(c) == 1 for c in self.jaw.candidates])[:, None]
                pts = torch.cat([torch.where(fixed, pts[:17],
                                             verts[torch.as_tensor(v.level["jaw"])]),
                                 pts[17:]])
            return pts
        idx = self.lmk_idx.clone()
        if "jaw" in v.level:
            idx[:17] = torch.as_tensor(v.level["jaw"])
        return verts[idx]

    def landmark_loss(self, v: View, verts: torch.Tensor, it: int) -> torch.Tensor:
        pred = self.project(v, self.model_landmarks(v, verts, it))
        tgt = torch.as_tensor(v.detection.points, dtype=pred.dtype)
        # residuals in units of the robust knee (a fraction of the face size), so the
        # term is O(1) at a typical misfit and the priors' weights read naturally
        r = torch.linalg.vector_norm(pred - tgt, dim=-1) / (v.detection.size
                                                             * self.cfg.landmarks.huber_px)
        rob = torch.where(r < 1.0, 0.5 * r ** 2, r - 0.5)
        w = self.view_landmark_weights(v)
        return (w * rob).sum() / w.sum()

    def view_landmark_weights(self, v: View) -> torch.Tensor:
        """(68,) the landmark loss's weights for a view: the configured ones, times the
        detector's weights when the view's points go through the embedding
        (``landmarks.calibrated_weights``): the refiner's for refined points, else the
        embedding file's."""
        emb = self.embedding
        if not (v.embedded and self.cfg.landmarks.calibrated_weights and emb is not None):
            return self.lmk_w
        # refined points: the refiner's weights (its scatter about the embedding)
        w = v.detection.weights if v.detection.weights is not None else emb.weights
        if w is None:
            return self.lmk_w
        return self.lmk_w * torch.as_tensor(w, dtype=self.lmk_w.dtype)

    def focal_prior_px(self, photo: Photo) -> tuple[float, float, str]:
        """(centre in pixels, std of log focal, source) of a photo's focal-length prior:
        the photo's own 35 mm-equivalent focal (EXIF or --focal-mm) when it has one and
        ``camera.use_photo_focal``, else ``camera.focal_mm_prior``; 36 mm spans the long
        side."""
        c = self.cfg.camera
        side = max(photo.width, photo.height) / SENSOR_MM
        if c.use_photo_focal and photo.focal_mm:
            return photo.focal_mm * side, c.photo_focal_log_sigma, photo.focal_source or "photo"
        return c.focal_mm_prior * side, c.focal_log_sigma, "prior"

    def focal_prior(self, v: View) -> torch.Tensor:
        f0, sigma, _ = self.focal_prior_px(v.photo)
        return ((v.log_focal - math.log(f0)) / sigma).pow(2).sum()

    def silhouette_loss(self, v: View, verts: torch.Tensor, it: int) -> torch.Tensor:
        """The silhouette term (``silhouette.py``): skin vertices outside the person mask
        (one-sided) plus the model's outer contour points off the mask's border, robust,
        in the landmark term's units; the contour set is re-selected every
        ``silhouette.contour_every`` iterations."""
        from hack_render.fit.silhouette import huber

        sc, sil = self.cfg.silhouette, v.silhouette
        if it % max(1, sc.contour_every) == 0 or "sil_contour" not in v.level:
            from hack_render.render.bridge import vertex_normals_torch

            with torch.no_grad():
                vv = verts.detach()
                n = vertex_normals_torch(vv, self.faces).numpy()
                pairs, t = self.silhouette.select_contour(
                    vv.numpy().astype(np.float64), n.astype(np.float64), self.camera_centre(v),
                    lambda p: self.project(v, torch.as_tensor(p, dtype=vv.dtype)).numpy(),
                    sil.shape, max(v.detection.size / 60.0, 0.5))
            v.level["sil_contour"] = (torch.as_tensor(pairs, dtype=torch.long),
                                      torch.as_tensor(t, dtype=verts.dtype))
        knee = v.detection.size * self.cfg.landmarks.huber_px
        pairs, t = v.level["sil_contour"]
        n_c = max(len(t), 1)
        d, ok = sil.distance(self.project(v, verts.index_select(0, self.silhouette.inside)))
        inside = (huber(torch.relu(d) / knee) * ok).sum() / n_c
        if len(t):
            d, ok = sil.distance(self.project(v, self.silhouette.points(verts, pairs, t)))
            contour = (huber(d / knee) * ok).sum() / n_c
        else:
            contour = inside * 0.0
        return sc.w_inside * inside + sc.weight * contour

    def pose_priors(self, v: View) -> dict[str, torch.Tensor]:
        s = self.cfg.shape
        th = self.theta(v)
        return {"E_rot": s.w_rot * rotation_limit_penalty(th).sum(),
                "E_sim": s.w_sim * adjacent_similarity_penalty(th, normalized=True).sum(),
                "dtheta": s.w_dtheta * (v.dtheta ** 2).sum(),
                "global": s.w_global * (v.global_orient ** 2).sum()}

    # --- stages 2 and 3 -----------------------------------------------------------------
    def fit_camera(self) -> StageReport:
        c = self.cfg.camera
        groups = []
        for v in self.views:
            groups += [{"params": [v.transl], "lr": c.lr * 0.1},
                       {"params": [v.head_angles], "lr": c.lr}]
            if c.fit_focal:
                groups.append({"params": [v.log_focal], "lr": c.lr})
        # the rigid stage first fits translation and rotation at the prior focal length;
        # it scales the landmark term so Adam's steps are in sensible units

        def loss(it):
            total, terms = 0.0, {"landmarks": 0.0, "focal_prior": 0.0}
            for v in self.views:
                verts = self.forward(v).vertices[0]
                lm = self.landmark_loss(v, verts, it)
                fp = 0.01 * self.focal_prior(v)
                rot = rotation_limit_penalty(self.theta(v)).sum()
                total = total + lm + fp + rot
                terms["landmarks"] += float(lm.detach())
                terms["focal_prior"] += float(fp.detach())
            return total, terms

        return self._run("camera", groups, loss, c.iterations)

    def psi_prior(self, v: View) -> torch.Tensor:
        """w_psi times the expression prior: sum(psi) ("l1", psi is in [0, 1], so this is
        the L1 norm: a sparse prior, a few strong FACS units cost less than many weak
        ones) or sum(psi^2) ("l2")."""
        s = self.cfg.shape
        psi = self.view_psi(v)
        return s.w_psi * (psi.sum() if s.psi_prior == "l1" else (psi ** 2).sum())

    def shape_terms(self, v: View, verts: torch.Tensor, it: int) -> dict[str, torch.Tensor]:
        """One view's part of the shape objective: landmarks, focal prior, pose priors
        and the expression prior (the photometric stage keeps it, scaled)."""
        terms = {"landmarks": self.landmark_loss(v, verts, it),
                 "focal_prior": 0.01 * self.focal_prior(v), **self.pose_priors(v),
                 "psi_prior": self.psi_prior(v)}
        if v.silhouette is not None:
            terms["silhouette"] = self.silhouette_loss(v, verts, it)
        return terms

    def beta_prior(self) -> torch.Tensor:
        return self.cfg.shape.w_beta * (self.beta ** 2).sum()

    def shape_objective(self, it: int) -> tuple[torch.Tensor, dict]:
        """Sum of :meth:`shape_terms` over the views plus the identity prior, and its
        terms as floats (the shape stage's loss)."""
        total, terms = 0.0, {}
        for v in self.views:
            for k, x in self.shape_terms(v, self.forward(v).vertices[0], it).items():
                total = total + x
                terms[k] = terms.get(k, 0.0) + float(x.detach())
        bp = self.beta_prior()
        terms["beta_prior"] = float(bp.detach())
        return total + bp, terms

    def fit_shape(self) -> StageReport:
        s = self.cfg.shape
        groups = [{"params": [self.beta], "lr": s.lr}, {"params": [self.psi], "lr": s.lr}]
        for v in self.views:
            # the joints' residuals take small steps: Adam's first steps move every
            # coordinate by about its lr, and 8 joints' residuals add up (at 0.5 x lr the
            # first step turned the head by ~5 degrees and the landmark loss rose 20-fold)
            groups += [{"params": [v.dtheta], "lr": s.lr_joints},
                       {"params": [v.head_angles, v.global_orient], "lr": s.lr_head},
                       {"params": [v.transl], "lr": s.lr * 0.05},
                       {"params": [v.log_focal], "lr": s.lr * 0.5}]
            if v.psi is not None:
                groups.append({"params": [v.psi], "lr": s.lr})
        return self._run("shape", groups, self.shape_objective, s.iterations,
                         after_step=self._project_psi)

    def _project_psi(self):
        with torch.no_grad():
            self.psi.clamp_(0.0, 1.0)
            for v in self.views:
                if v.psi is not None:
                    v.psi.clamp_(0.0, 1.0)
            # the anatomical ranges (larynx.py); E_larynx penalises the excess before this
            self.eta.clamp_(*ETA_RANGE)
            self.tau.clamp_(*TAU_RANGE_M)

    def _run(self, name, groups, loss, iterations, after_step=None, keep="best") -> StageReport:
        t0 = time.perf_counter()
        rep = run_stage(name, groups, loss, iterations, self.progress, after_step, keep)
        self.reports.append(rep)
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0
        return rep

    # --- stage 4 and 5: photometric ----------------------------------------------------
    def maps(self, with_delta: bool = True, height: int | None = None):
        """Current skin maps: torch (H, 2H, C) diffuse, specular, roughness, normal
        (``with_delta``: the per-texel albedo refinement added, when there is one).
        ``height``: a coarser atlas (the appearance model's height / 2^k, see
        :meth:`~appearance.model.AppearanceModel.downsampled`) for coarse photometric
        levels; None: the model's own."""
        if self.appearance is None:
            h = 16
            d = self.const_albedo.clamp(0, 1).expand(h, 2 * h, 3)
            return {"albedo": d, "specular": torch.full((h, 2 * h, 1), 0.6),
                    "roughness": torch.full((h, 2 * h, 1), 0.5), "normal": None}
        app = self.appearance
        if height is not None and height != app.height:
            if with_delta and self.albedo_delta is not None:
                raise HackError("maps: the per-texel albedo refinement is at the full atlas "
                                f"({app.height} px), not at {height} px.")
            key = (int(height), self.alpha.shape[1])
            if key not in self._coarse_appearance:
                self._coarse_appearance[key] = app.downsampled(*key)
            app = self._coarse_appearance[key]
        m = app.maps(self.alpha)
        d = m.diffuse[0]
        if with_delta and self.albedo_delta is not None:
            d = (d + self.albedo_delta).clamp(0.0, 1.0)
        return {"albedo": d, "specular": m.specular[0], "roughness": m.roughness[0],
                "normal": m.normal[0]}

    def photometric(self, texel: bool = False) -> list[StageReport]:
        from hack_render.fit import photometric as ph

        return ph.run(self, texel)

    def run(self) -> FitResult:
        self.fit_camera()
        self.fit_shape()
        if self.cfg.photometric.enabled:
            self.photometric(texel=False)
            if self.cfg.texel.enabled and self.appearance is not None:
                self.photometric(texel=True)
        return FitResult(self.model, self.appearance, self.cfg, self.views, self.beta,
                         self.psi, self.alpha, self.eta, self.tau, self.albedo_delta,
                         self.reports, self.timings,
                         [r.failure for r in self.reports if r.failure])


def _landmark_embedding(name: str, model):
    """The landmark embedding of ``landmarks.embedding`` ("dlib", "vertices" or a path), or
    None for the model's vertices. The shipped "dlib" file falls back to the vertices with
    a warning when it is missing or does not fit the model; a named file must load."""
    from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default

    if name == "vertices":
        return None
    if name == "dlib":
        return load_default(model)
    return LandmarkEmbedding.load(name, model)


def _load_appearance():
    """The appearance PCA model, or None (constant albedo) when it is unavailable."""
    try:
        from appearance.model import AppearanceModel

        return AppearanceModel.load()
    except (ImportError, OSError, HackError):
        return None
