"""The fit's loss terms on a :class:`~hack_render.fit.state.FitState`: landmarks (jawline
re-matched to the occluding contour), silhouette, focal, pose, expression and identity
priors, and the shape objective that sums them over the views. Every robust term uses
:mod:`hack_render.fit.robust`. Pure functions of (state, config, view, vertices,
iteration); the only state they write is the view's contour correspondences
(``View.jaw``, ``View.sil_contour``), re-selected every few iterations."""

from __future__ import annotations

import math

import numpy as np
import torch

from hack_render.fit.camera import focal_prior_px
from hack_render.fit.config import FitConfig
from hack_render.fit.robust import huber
from hack_render.fit.state import FitState, View
from hack_render.geometry.skeleton import adjacent_similarity_penalty, rotation_limit_penalty
from hack_render.render.bridge import vertex_normals_torch

#: dlib's jawline points are re-matched to the occluding contour every this many iterations
JAW_REMATCH_EVERY = 10
#: the landmark and silhouette terms' robust (Huber) knee, as a fraction of the face size
#: (the terms' unit: 1 % of the face)
HUBER_KNEE = 0.01
#: weigh each point by the detector's inverse variance about the embedding (the refiner's
#: weights for refined points, else the embedding file's): synthetic subjects 0-7, landmark
#: stages, 1.66 mm against 1.74 mm unweighted
CALIBRATED_WEIGHTS = True
#: the silhouette term's two parts: the model's outer contour points off the mask's border,
#: and skin vertices projected outside the mask
SILHOUETTE_CONTOUR_WEIGHT = 1.0
SILHOUETTE_INSIDE_WEIGHT = 1.0
#: the model's outer contour for the silhouette term is re-selected every this many iterations
SILHOUETTE_CONTOUR_EVERY = 10
#: E_rot (paper Eq. 9: the joints beyond their anatomical ranges; the photometric stage's
#: E_larynx for eta and tau too)
W_ROT = 1.0
#: E_sim (paper Eq. 10, normalised by the joints' ranges)
W_SIM = 0.1
#: the residual joint rotations beyond the anatomical share of the head's turn
W_DTHETA = 0.5
#: the torso's (global) rotation prior, camera.rotate "head"
W_GLOBAL = 1.0
#: camera.rotate "torso": a weak torso prior (the camera may stand anywhere about the body)
#: and the neck's rotation (head_angles) costing W_NECK per rad^2, so a turn the landmarks
#: cannot place goes to the torso (synthetic: camera yaw 30 deg, neck 3 deg -> fitted neck
#: yaw ~7 deg, 32 deg in "head" mode; tests/test_fit_views.py)
W_GLOBAL_TORSO = 0.01
W_NECK = 0.5


def _normals(state: FitState, verts: torch.Tensor) -> np.ndarray:
    return vertex_normals_torch(verts, state.faces).numpy()


def model_landmarks(state: FitState, cfg: FitConfig, v: View, verts: torch.Tensor,
                    it: int) -> torch.Tensor:
    """(68, 3) landmark points with the jawline re-matched to the contour every
    :data:`JAW_REMATCH_EVERY` iterations: the calibrated embedding's surface points
    (barycentric interpolation, differentiable) when the view uses it, else the model's
    landmark vertices."""
    # the vision package's points (face mesh, shape predictors) are fixed surface points
    # (3-D convention), dlib's jawline lies on the visible outline: only the latter is
    # re-matched to the contour
    if v.detection.source not in ("mesh", "ert") \
            and it % max(1, JAW_REMATCH_EVERY) == 0:
        with torch.no_grad():
            vv = verts.detach()
            state.jaw.match(vv.numpy(), _normals(state, vv), state.camera_centre(v),
                            lambda p: state.project(v, torch.as_tensor(p)).numpy(),
                            v.detection.points)
            v.jaw = state.jaw.current.copy()
    if v.embedded:
        pts = state.embedding.points(verts)
        if v.jaw is not None:  # contour points; a fixed jaw point (the chin) stays embedded
            fixed = torch.tensor([len(c) == 1 for c in state.jaw.candidates])[:, None]
            pts = torch.cat([torch.where(fixed, pts[:17], verts[torch.as_tensor(v.jaw)]),
                             pts[17:]])
        return pts
    idx = state.lmk_idx.clone()
    if v.jaw is not None:
        idx[:17] = torch.as_tensor(v.jaw)
    return verts[idx]


def landmark_scale(cfg: FitConfig, v: View) -> float:
    """The shape stage's objective's scale beside the photo term for a view:
    ``photometric.w_landmarks`` where its points are dlib's, a file's or the face mesh's,
    ``w_landmarks_fallback`` where they are the shape predictors' (the vision package's
    points past 40 degrees of yaw, or where the mesh sees no face), which are less sure."""
    pc = cfg.photometric
    return pc.w_landmarks_fallback if v.detection.source == "ert" else pc.w_landmarks


def view_landmark_weights(state: FitState, cfg: FitConfig, v: View) -> torch.Tensor:
    """(68,) the landmark loss's weights for a view: the configured ones, times the
    detector's weights when the view's points go through the embedding
    (:data:`CALIBRATED_WEIGHTS`): the refiner's for refined points, else the
    embedding file's."""
    emb = state.embedding
    if not (v.embedded and CALIBRATED_WEIGHTS and emb is not None):
        return state.lmk_w
    w = v.detection.weights if v.detection.weights is not None else emb.weights
    if w is None:
        return state.lmk_w
    return state.lmk_w * torch.as_tensor(w, dtype=state.lmk_w.dtype)


def landmark_loss(state: FitState, cfg: FitConfig, v: View, verts: torch.Tensor,
                  it: int) -> torch.Tensor:
    """Weighted Huber of the landmark residuals, in units of the robust knee (a fraction
    of the face size), so the term is O(1) at a typical misfit and the priors' weights
    read naturally."""
    pred = state.project(v, model_landmarks(state, cfg, v, verts, it))
    tgt = torch.as_tensor(v.detection.points, dtype=pred.dtype)
    r = torch.linalg.vector_norm(pred - tgt, dim=-1) / (v.detection.size * HUBER_KNEE)
    w = view_landmark_weights(state, cfg, v)
    if v.detection.visible is not None:  # hidden points (a profile's far side) count 0
        w = w * torch.as_tensor(v.detection.visible, dtype=w.dtype)
    return (w * huber(r)).sum() / w.sum().clamp_min(1e-6)


def focal_prior(cfg: FitConfig, v: View) -> torch.Tensor:
    f0, sigma, _ = focal_prior_px(cfg.camera, v.photo)
    return ((v.log_focal - math.log(f0)) / sigma).pow(2).sum()


def silhouette_loss(state: FitState, cfg: FitConfig, v: View, verts: torch.Tensor,
                    it: int) -> torch.Tensor:
    """The silhouette term (``silhouette.py``): skin vertices outside the person mask
    (one-sided) plus the model's outer contour points off the mask's border, Huber, in
    the landmark term's units; the contour set is re-selected every
    :data:`SILHOUETTE_CONTOUR_EVERY` iterations."""
    sil, ms = v.silhouette, state.silhouette
    if it % max(1, SILHOUETTE_CONTOUR_EVERY) == 0 or v.sil_contour is None:
        with torch.no_grad():
            vv = verts.detach()
            n = _normals(state, vv)
            pairs, t = ms.select_contour(
                vv.numpy().astype(np.float64), n.astype(np.float64), state.camera_centre(v),
                lambda p: state.project(v, torch.as_tensor(p, dtype=vv.dtype)).numpy(),
                sil.shape, max(v.detection.size / 60.0, 0.5))
        v.sil_contour = (torch.as_tensor(pairs, dtype=torch.long),
                         torch.as_tensor(t, dtype=verts.dtype))
    knee = v.detection.size * HUBER_KNEE
    pairs, t = v.sil_contour
    n_c = max(len(t), 1)
    d, ok = sil.distance(state.project(v, verts.index_select(0, ms.inside)))
    inside = (huber(torch.relu(d) / knee) * ok).sum() / n_c
    if len(t):
        d, ok = sil.distance(state.project(v, ms.points(verts, pairs, t)))
        contour = (huber(d / knee) * ok).sum() / n_c
    else:
        contour = inside * 0.0
    return SILHOUETTE_INSIDE_WEIGHT * inside + SILHOUETTE_CONTOUR_WEIGHT * contour


def pose_priors(state: FitState, cfg: FitConfig, v: View,
                th: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """E_rot, E_sim and the rotations' priors of a view (``th``: its (1, 8, 3) neck
    pose, :meth:`~hack_render.fit.state.FitState.theta`, when the caller has it)."""
    th = state.theta(v) if th is None else th
    terms = {"E_rot": W_ROT * rotation_limit_penalty(th).sum(),
             "E_sim": W_SIM * adjacent_similarity_penalty(th, normalized=True).sum(),
             "dtheta": W_DTHETA * (v.dtheta ** 2).sum()}
    if cfg.camera.rotate == "torso":  # the turn to the torso, the neck held
        terms["global"] = W_GLOBAL_TORSO * (v.global_orient ** 2).sum()
        terms["neck"] = W_NECK * (v.head_angles ** 2).sum()
    else:
        terms["global"] = W_GLOBAL * (v.global_orient ** 2).sum()
    return terms


def psi_prior(state: FitState, cfg: FitConfig, v: View) -> torch.Tensor:
    """w_psi times the expression prior: sum(psi) ("l1", psi is in [0, 1], so this is the
    L1 norm: a sparse prior, a few strong FACS units cost less than many weak ones) or
    sum(psi^2) ("l2")."""
    s = cfg.shape
    psi = state.view_psi(v)
    return s.w_psi * (psi.sum() if s.psi_prior == "l1" else (psi ** 2).sum())


def beta_prior(state: FitState, cfg: FitConfig) -> torch.Tensor:
    return cfg.shape.w_beta * (state.beta ** 2).sum()


def shape_terms(state: FitState, cfg: FitConfig, v: View, verts: torch.Tensor,
                it: int, th: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """One view's part of the shape objective: landmarks, focal prior, pose priors and the
    expression prior (the photometric stage keeps it, scaled), and the silhouette term
    when the view has a person mask (``th`` as in :func:`pose_priors`)."""
    terms = {"landmarks": landmark_loss(state, cfg, v, verts, it),
             "focal_prior": 0.01 * focal_prior(cfg, v), **pose_priors(state, cfg, v, th),
             "psi_prior": psi_prior(state, cfg, v)}
    if v.silhouette is not None:
        terms["silhouette"] = silhouette_loss(state, cfg, v, verts, it)
    return terms


def shape_objective(state: FitState, cfg: FitConfig, it: int) -> tuple[torch.Tensor, dict]:
    """Sum of :func:`shape_terms` over the views plus the identity prior, and its terms
    as floats (the shape stage's loss)."""
    total, terms = 0.0, {}
    landmarks_only = all(v.silhouette is None for v in state.views)
    th = state.thetas()
    for i, (v, verts) in enumerate(zip(state.views, state.forward_views(landmarks_only, th))):
        for k, x in shape_terms(state, cfg, v, verts, it, th[i:i + 1]).items():
            total = total + x
            terms[k] = terms.get(k, 0.0) + float(x.detach())
    bp = beta_prior(state, cfg)
    terms["beta_prior"] = float(bp.detach())
    return total + bp, terms


def camera_objective(state: FitState, cfg: FitConfig, it: int) -> tuple[torch.Tensor, dict]:
    """The camera stage's loss: landmarks, a light focal prior and E_rot, per view."""
    total, terms = 0.0, {"landmarks": 0.0, "focal_prior": 0.0}
    th = state.thetas()
    for i, (v, verts) in enumerate(zip(state.views, state.forward_views(True, th))):
        lm = landmark_loss(state, cfg, v, verts, it)
        fp = 0.01 * focal_prior(cfg, v)
        rot = rotation_limit_penalty(th[i:i + 1]).sum()
        total = total + lm + fp + rot
        terms["landmarks"] += float(lm.detach())
        terms["focal_prior"] += float(fp.detach())
    return total, terms


def landmark_residual_iod(v: View, fitted: np.ndarray) -> float | None:
    """Mean distance between the fitted points (:func:`fitted_points`) and the detected
    ones (the chin and the 51 inner points the detector sees), in units of the detected
    outer-eye distance."""
    det = v.detection
    idx = np.array([8] + list(range(17, 68)))
    if det.visible is not None:
        idx = idx[np.asarray(det.visible, bool)[idx]]
    iod = max(float(np.linalg.norm(det.points[36] - det.points[45])), 1e-9)
    d = np.linalg.norm(fitted[idx] - det.points[idx], axis=1)
    return round(float(d.mean() / iod), 4) if len(idx) else None


def fitted_points(state: FitState, cfg: FitConfig, v: View, rematch: bool = False
                  ) -> np.ndarray:
    """(68, 2) the fitted model's landmark points projected into the view's photo, in
    pixels: dlib's jawline where it was last matched, or (``rematch``) matched again to
    the contour (which updates the view's matched jawline)."""
    with torch.no_grad():
        verts = state.forward(v).vertices[0]
        it = 0 if rematch or JAW_REMATCH_EVERY <= 1 else 1
        return state.project(v, model_landmarks(state, cfg, v, verts, it)).numpy()
