"""Stages 2 and 3, from landmarks (and the silhouette): each takes the state, the config
and the stage log, updates the state's parameters and returns its report.

- :func:`fit_camera`: focal length, camera translation and the head's rotation (shared
  over the 8 cervical joints by the anatomical prior,
  :func:`~hack_render.geometry.skeleton.distribute_head_rotation`).
- :func:`fit_shape`: beta, psi and a residual theta, with a Gaussian prior on beta, a
  sparse prior on psi, E_rot (Eq. 9) and E_sim (Eq. 10), plus the silhouette term
  (``silhouette.py``) where the view has a person mask.
"""

from __future__ import annotations

import torch

from hack_render.fit import terms
from hack_render.fit.config import FitConfig
from hack_render.fit.stages import StageLog, StageReport
from hack_render.fit.state import FitState

#: the camera stage's Adam step (head turn and log focal; the translation's is 0.1 x)
CAMERA_LR = 0.03
#: the shape stage's Adam step for beta and psi (the translation's 0.05 x, the focal's 0.5 x)
SHAPE_LR = 0.02
#: the shape stage's steps (radians) for the head's rotation, the residual per-joint
#: rotations (small: see fit_shape; at 0.01 rad for joints and head the landmark loss rose
#: 14-fold in the first 10 iterations, tests/test_fit_priors.py) and the torso's ("torso"
#: mode; "head" mode takes HEAD_LR for it)
HEAD_LR = 0.002
JOINTS_LR = 0.0004
TORSO_LR = 0.005


def fit_camera(state: FitState, cfg: FitConfig, log: StageLog) -> StageReport:
    """Translation and head rotation (and focal, ``camera.fit_focal``) from landmarks."""
    c = cfg.camera
    groups = []
    for v in state.views:
        turn = v.global_orient if c.rotate == "torso" else v.head_angles
        groups += [{"params": [v.transl], "lr": CAMERA_LR * 0.1},
                   {"params": [turn], "lr": CAMERA_LR}]
        if c.fit_focal:
            groups.append({"params": [v.log_focal], "lr": CAMERA_LR})
    with state.grads_only([p for g in groups for p in g["params"]]):
        return log.run("camera", groups, lambda it: terms.camera_objective(state, cfg, it),
                       c.iterations)


def fit_shape(state: FitState, cfg: FitConfig, log: StageLog) -> StageReport:
    """Identity, expression and neck pose (and the camera, gently) from landmarks and the
    silhouette: :func:`~hack_render.fit.terms.shape_objective`."""
    s = cfg.shape
    groups = [{"params": [state.beta], "lr": SHAPE_LR}, {"params": [state.psi], "lr": SHAPE_LR}]
    for v in state.views:
        # the joints' residuals take small steps: Adam's first steps move every
        # coordinate by about its lr, and 8 joints' residuals add up (at 0.5 x lr the
        # first step turned the head by ~5 degrees and the landmark loss rose 20-fold)
        groups += [{"params": [v.dtheta], "lr": JOINTS_LR},
                   {"params": [v.head_angles], "lr": HEAD_LR},
                   {"params": [v.global_orient],
                    "lr": TORSO_LR if cfg.camera.rotate == "torso" else HEAD_LR},
                   {"params": [v.transl], "lr": SHAPE_LR * 0.05},
                   {"params": [v.log_focal], "lr": SHAPE_LR * 0.5}]
        if v.psi is not None:
            groups.append({"params": [v.psi], "lr": SHAPE_LR})
    with state.grads_only([p for g in groups for p in g["params"]]):
        return log.run("shape", groups, lambda it: terms.shape_objective(state, cfg, it),
                       s.iterations, after_step=state.clamp_)


#: a view's person mask is dropped from the silhouette term when, with it, the shape
#: stage's fitted points end more than this many outer-eye distances further from the
#: detected ones than without it: its border beside the face is then not the face's
#: outline (an object held in front of the face, hair or a hat around it). The
#: cameraman's mask (his camera over his face's front) took his points from 1.1 % to
#: 8.4 %; the astronaut's and Grace Hopper's moved them -0.2 and +0.8 % (docs/fit.md)
SILHOUETTE_MARGIN_IOD = 0.02


def fit_shape_checked(state: FitState, cfg: FitConfig, log: StageLog) -> StageReport:
    """:func:`fit_shape`, and where a view has a person mask, the stage once more without
    the silhouette term: a view whose fitted points the term pulls further than
    ``SILHOUETTE_MARGIN_IOD`` from the detected ones loses its mask (for the photometric
    stage too; its ``silhouette_note`` says why), and the stage is kept as run with the
    masks that remain."""
    masked = [v.silhouette is not None for v in state.views]
    if state.silhouette is None or not any(masked) or not cfg.silhouette.check:
        return fit_shape(state, cfg, log)
    start = _snapshot(state)
    rep = fit_shape(state, cfg, log)
    with_mask = [terms.landmark_residual_iod(v, terms.fitted_points(state, cfg, v))
                 for v in state.views]
    after = _snapshot(state)
    _restore(state, start)
    masks = [v.silhouette for v in state.views]
    for v in state.views:
        v.silhouette = None
    rep_without = fit_shape(state, cfg, log)
    rep_without.name = "shape (no silhouette, not kept)"   # the report named "shape" is
    # the run whose parameters are kept
    without = [terms.landmark_residual_iod(v, terms.fitted_points(state, cfg, v))
               for v in state.views]
    drop = [m and a is not None and b is not None and a > b + SILHOUETTE_MARGIN_IOD
            for m, a, b in zip(masked, with_mask, without)]
    for v, m, d, a, b in zip(state.views, masks, drop, with_mask, without):
        v.silhouette = None if d else m
        if d:
            v.silhouette_note = (f"dropped ({v.silhouette_note}): with it the fitted points "
                                 f"ended {a:.3f} of the outer-eye distance from the "
                                 f"detected ones, {b:.3f} without; its border beside the "
                                 "face is not the face's outline (an object in front of "
                                 "the face, hair)")
    if not any(drop):
        _restore(state, after)
        return rep
    rep.name = "shape (with the masks, not kept)"
    if all(d or not m for d, m in zip(drop, masked)):
        rep_without.name = "shape"
        return rep_without
    _restore(state, start)
    return fit_shape(state, cfg, log)


def _snapshot(state: FitState) -> dict:
    """The shape stage's parameters and matched contours, copied (see :func:`_restore`)."""
    views = [{k: getattr(v, k).detach().clone() for k in _VIEW_PARAMS
              if getattr(v, k) is not None} | {"jaw": v.jaw, "sil_contour": v.sil_contour}
             for v in state.views]
    return {"beta": state.beta.detach().clone(), "psi": state.psi.detach().clone(),
            "jaw_current": state.jaw.current.copy(), "views": views}


_VIEW_PARAMS = ("log_focal", "transl", "head_angles", "dtheta", "global_orient", "psi")


def _restore(state: FitState, snap: dict) -> None:
    with torch.no_grad():
        state.beta.copy_(snap["beta"])
        state.psi.copy_(snap["psi"])
        for v, saved in zip(state.views, snap["views"]):
            for k in _VIEW_PARAMS:
                if k in saved:
                    getattr(v, k).copy_(saved[k])
            v.jaw, v.sil_contour = saved["jaw"], saved["sil_contour"]
    state.jaw.current = snap["jaw_current"].copy()
