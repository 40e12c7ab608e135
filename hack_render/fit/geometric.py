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

from hack_render.fit import terms
from hack_render.fit.config import FitConfig
from hack_render.fit.stages import StageLog, StageReport
from hack_render.fit.state import FitState


def fit_camera(state: FitState, cfg: FitConfig, log: StageLog) -> StageReport:
    """Translation and head rotation (and focal, ``camera.fit_focal``) from landmarks."""
    c = cfg.camera
    groups = []
    for v in state.views:
        turn = v.global_orient if c.rotate == "torso" else v.head_angles
        groups += [{"params": [v.transl], "lr": c.lr * 0.1},
                   {"params": [turn], "lr": c.lr}]
        if c.fit_focal:
            groups.append({"params": [v.log_focal], "lr": c.lr})
    return log.run("camera", groups, lambda it: terms.camera_objective(state, cfg, it),
                   c.iterations)


def fit_shape(state: FitState, cfg: FitConfig, log: StageLog) -> StageReport:
    """Identity, expression and neck pose (and the camera, gently) from landmarks and the
    silhouette: :func:`~hack_render.fit.terms.shape_objective`."""
    s = cfg.shape
    groups = [{"params": [state.beta], "lr": s.lr}, {"params": [state.psi], "lr": s.lr}]
    for v in state.views:
        # the joints' residuals take small steps: Adam's first steps move every
        # coordinate by about its lr, and 8 joints' residuals add up (at 0.5 x lr the
        # first step turned the head by ~5 degrees and the landmark loss rose 20-fold)
        groups += [{"params": [v.dtheta], "lr": s.lr_joints},
                   {"params": [v.head_angles], "lr": s.lr_head},
                   {"params": [v.global_orient],
                    "lr": s.lr_torso if cfg.camera.rotate == "torso" else s.lr_head},
                   {"params": [v.transl], "lr": s.lr * 0.05},
                   {"params": [v.log_focal], "lr": s.lr * 0.5}]
        if v.psi is not None:
            groups.append({"params": [v.psi], "lr": s.lr})
    return log.run("shape", groups, lambda it: terms.shape_objective(state, cfg, it),
                   s.iterations, after_step=state.clamp_)
