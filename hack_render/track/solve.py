"""Per-frame parameters from 2-D landmarks: a warm-started pass frame after frame, then one
joint solve over the clip with temporal priors.

Per frame: the whole-head rotation ``h`` (flexion, axial, lateral; shared over the 8 neck
joints by the anatomical prior), the torso rotation ``g``, the translation ``t`` and the
expression ``psi``; one camera for the clip (the keyframe fit's). The joint solve adds
velocity and acceleration penalties, so the result is smooth without the lag of a causal
filter, and carries lost frames (no landmarks) across by the same priors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from hack_render.fit.camera import R0
from hack_render.geometry.skeleton import head_rotation_range_deg


@dataclass
class ClipCamera:
    """The clip's pinhole camera: focal length (px), image size, and its translation
    (x_cam = R0 X + cam_t, metres; ``hack_render.fit.camera``)."""

    focal: float
    width: int
    height: int
    cam_t: np.ndarray

    def project(self, X: torch.Tensor) -> torch.Tensor:
        """(..., 3) world points -> (..., 2) pixels."""
        R = R0.to(X.dtype)
        cam = X @ R.T + torch.as_tensor(self.cam_t, dtype=X.dtype)
        uv = self.focal * cam[..., :2] / cam[..., 2:3].clamp_min(1e-4)
        return uv + torch.tensor([self.width / 2.0, self.height / 2.0], dtype=X.dtype)

    def to_dict(self) -> dict:
        f = float(self.focal)
        return {"width": self.width, "height": self.height,
                "K": [[f, 0.0, self.width / 2], [0.0, f, self.height / 2], [0.0, 0.0, 1.0]],
                "R": R0.tolist(), "t": [float(x) for x in self.cam_t],
                "convention": "OpenCV: x_cam = R @ X_world + t; x right, y down, z forward"}


@dataclass
class TrackConfig:
    """Weights of the per-frame solve (landmark residuals are in units of the face's
    outer-eye distance)."""

    robust_knee: float = 0.03       # Charbonnier knee, fraction of the outer-eye distance
    jaw_weight: float = 0.3         # the 17 jawline points (dlib's noisiest)
    psi_l1: float = 2e-4            # sparsity of the expression weights
    # keeps the torso near the keyframes' (radians^-2): the head's and the torso's rotations
    # move the face almost alike, so the landmarks alone cannot tell them apart
    torso_prior: float = 50.0
    # keeps the body's translation near the clip's mean, per axis x, y, z (metres^-2).
    # Landmarks alone trade a head pitch for a move up or down in the image: on the
    # benchmark clip without it the flexion was 5.2 degrees off and the neck sat 17 px
    # off in the image; with it on y, 1.4 degrees and 7 px. Sideways sway stays free, and
    # so does depth: it takes up the keyframe fit's focal length and scale (held too, it
    # pushed the expressions to open the jaw).
    transl_prior: tuple[float, float, float] = (0.0, 1000.0, 0.0)
    # temporal priors of the joint solve, per unit of each group (radians, metres,
    # expression weight): velocity and acceleration between consecutive frames
    velocity: dict = field(default_factory=lambda: {"h": 0.05, "g": 5.0, "t": 20.0,
                                                    "psi": 0.002})
    acceleration: dict = field(default_factory=lambda: {"h": 2.0, "g": 50.0, "t": 500.0,
                                                        "psi": 0.02})
    frame_iterations: int = 4       # Levenberg-Marquardt iterations per frame (warm start)
    joint_iterations: int = 60      # L-BFGS iterations of the joint solve per window
    window: int = 240               # frames per joint-solve window (overlap: window / 4)


@dataclass
class FrameParams:
    """Per-frame parameters (numpy, float64): ``h`` (T, 3), ``g`` (T, 3), ``t`` (T, 3),
    ``psi`` (T, E)."""

    h: np.ndarray
    g: np.ndarray
    t: np.ndarray
    psi: np.ndarray

    @property
    def frames(self) -> int:
        return len(self.h)

    def vector(self) -> np.ndarray:
        return np.concatenate([self.h, self.g, self.t, self.psi], 1)

    @classmethod
    def from_vector(cls, x: np.ndarray) -> FrameParams:
        return cls(x[:, :3].copy(), x[:, 3:6].copy(), x[:, 6:9].copy(),
                   np.clip(x[:, 9:], 0.0, 1.0))


def _transl_weights(cfg: TrackConfig) -> torch.Tensor:
    """(3,) the translation prior's weight per axis (x, y, z)."""
    return torch.as_tensor(cfg.transl_prior, dtype=torch.float64).expand(3)


def _landmark_weights(cfg: TrackConfig, point_weights: np.ndarray) -> torch.Tensor:
    """Per-point weights, (68,) for every frame or (T, 68) per frame (0 drops a point in
    that frame), the jawline scaled by ``jaw_weight``, each row with mean 1."""
    w = np.asarray(point_weights, dtype=np.float64).copy()
    w[..., :17] *= cfg.jaw_weight
    return torch.as_tensor(w / np.maximum(w.mean(-1, keepdims=True), 1e-12))


def _window(weights: np.ndarray, sl: slice) -> np.ndarray:
    """The rows of per-frame weights for frames ``sl`` (shared weights unchanged)."""
    w = np.asarray(weights)
    return w[sl] if w.ndim == 2 else w


class _Objective:
    """Landmark and prior terms over a window of frames (torch, float64)."""

    def __init__(self, rig, cam: ClipCamera, obs: np.ndarray, found: np.ndarray,
                 weights: np.ndarray, cfg: TrackConfig, g_ref: np.ndarray,
                 t_ref: np.ndarray | None = None):
        self.rig, self.cam, self.cfg = rig, cam, cfg
        # the translation the body stays near: fixed (the per-frame pass) or, when None,
        # the window's own mean (the joint solve)
        self.t_ref = None if t_ref is None else torch.as_tensor(t_ref, dtype=torch.float64)
        self.obs = torch.as_tensor(np.nan_to_num(obs))
        self.mask = torch.as_tensor(found, dtype=torch.float64)
        iod = np.linalg.norm(obs[:, 36] - obs[:, 45], axis=1)
        iod = np.where(found & np.isfinite(iod), iod, np.nanmedian(iod[found]) if found.any()
                       else 1.0)
        self.scale = torch.as_tensor(iod)
        self.w = _landmark_weights(cfg, weights)
        self.g_ref = torch.as_tensor(g_ref, dtype=torch.float64)
        rng = torch.deg2rad(head_rotation_range_deg().double())
        self.lo, self.hi = rng[:, 0], rng[:, 1]
        self.E = rig.D.shape[0]

    def data(self, x: torch.Tensor) -> torch.Tensor:
        """Per-frame landmark cost (T,)."""
        h, g, t, u = x[:, :3], x[:, 3:6], x[:, 6:9], x[:, 9:]
        psi = u.clamp(0.0, 1.0)
        uv = self.cam.project(self.rig.points(psi, h, g, t))
        r = (uv - self.obs).norm(dim=-1) / self.scale[:, None]
        k = self.cfg.robust_knee
        rho = k * k * (torch.sqrt(1 + (r / k) ** 2) - 1)
        return (rho * self.w).sum(1) * self.mask

    def priors(self, x: torch.Tensor) -> torch.Tensor:
        """Per-frame prior cost (T,)."""
        h, g, t, u = x[:, :3], x[:, 3:6], x[:, 6:9], x[:, 9:]
        box = torch.relu(-u) ** 2 + torch.relu(u - 1) ** 2
        lim = torch.relu(self.lo - h) ** 2 + torch.relu(h - self.hi) ** 2
        t_ref = (t.mean(0, keepdim=True) if self.t_ref is None
                 else self.t_ref.reshape(-1, 3)[:1])
        return (self.cfg.psi_l1 * u.clamp_min(0).sum(1) + 10.0 * box.sum(1)
                + 10.0 * lim.sum(1) + self.cfg.torso_prior * ((g - self.g_ref) ** 2).sum(1)
                + (_transl_weights(self.cfg) * (t - t_ref) ** 2).sum(1))

    def temporal(self, x: torch.Tensor, head: torch.Tensor | None = None) -> torch.Tensor:
        """Velocity and acceleration penalties; ``head``: fixed frames before the window."""
        xx = x if head is None else torch.cat([head, x], 0)
        if len(xx) < 2:
            return x.sum() * 0
        cost = x.new_zeros(())
        groups = {"h": slice(0, 3), "g": slice(3, 6), "t": slice(6, 9), "psi": slice(9, None)}
        v = xx[1:] - xx[:-1]
        a = xx[2:] - 2 * xx[1:-1] + xx[:-2] if len(xx) > 2 else None
        for name, sl in groups.items():
            cost = cost + self.cfg.velocity[name] * (v[:, sl] ** 2).sum()
            if a is not None:
                cost = cost + self.cfg.acceleration[name] * (a[:, sl] ** 2).sum()
        return cost


def _lbfgs(x0: torch.Tensor, fn, iterations: int) -> torch.Tensor:
    x = x0.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([x], lr=1.0, max_iter=iterations, history_size=20,
                            line_search_fn="strong_wolfe", tolerance_grad=1e-10,
                            tolerance_change=1e-12)

    def closure():
        opt.zero_grad()
        loss = fn(x)
        loss.backward()
        return loss

    opt.step(closure)
    return x.detach()


def _frame_residuals(obj: _Objective, i: int, prev: torch.Tensor, irls: torch.Tensor):
    """The residual function of frame ``i`` for Gauss-Newton, batched (x: (N, D) -> (N, R)):
    landmark residuals with the robust loss's IRLS weights, a small L2 pull of psi to 0
    (the L1 prior's local quadratic), the limit penalty, the torso prior and the pull
    toward the previous frame (the velocity prior)."""
    cfg = obj.cfg
    w = torch.sqrt((obj.w[i] if obj.w.ndim == 2 else obj.w) * irls)[:, None] / obj.scale[i]
    obs = obj.obs[i]
    vel = torch.cat([torch.full((3,), cfg.velocity["h"]), torch.full((3,), cfg.velocity["g"]),
                     torch.full((3,), cfg.velocity["t"]),
                     torch.full((obj.E,), cfg.velocity["psi"])]).double().sqrt()
    g_ref = obj.g_ref.reshape(-1)[:3]
    t_ref = prev[6:9] if obj.t_ref is None else obj.t_ref.reshape(-1)[:3]
    s_psi, s_torso = float(np.sqrt(cfg.psi_l1 * 10)), float(np.sqrt(cfg.torso_prior))
    s_transl = torch.sqrt(_transl_weights(cfg))

    def fn(x):
        h, g, t, u = x[:, :3], x[:, 3:6], x[:, 6:9], x[:, 9:]
        uv = obj.cam.project(obj.rig.points(u, h, g, t))
        data = ((uv - obs) * w).reshape(len(x), -1)
        lim = torch.relu(obj.lo - h) + torch.relu(h - obj.hi)
        return torch.cat([data, s_psi * u, 3.0 * lim, s_torso * (g - g_ref),
                          s_transl * (t - t_ref), vel * (x - prev)], 1)
    return fn


def _frame_lm(obj: _Objective, i: int, x0: torch.Tensor, prev: torch.Tensor,
              iterations: int, eps: float = 1e-7) -> torch.Tensor:
    """Levenberg-Marquardt on one frame from ``x0`` (psi kept in [0, 1] by projection).
    The Jacobian is taken by forward differences in float64, all columns in one batched
    evaluation of the rig (the rig is cheap per row; autograd's per-op overhead is not)."""
    x = x0.clone()
    n = len(x)
    k = obj.cfg.robust_knee
    lam = 1e-3
    eye = torch.eye(n, dtype=x.dtype)
    with torch.no_grad():
        for _ in range(iterations):
            uv = obj.cam.project(obj.rig.points(x[None, 9:], x[None, :3], x[None, 3:6],
                                                x[None, 6:9]))[0]
            r = (uv - obj.obs[i]).norm(dim=-1) / obj.scale[i]
            fn = _frame_residuals(obj, i, prev, 1.0 / torch.sqrt(1 + (r / k) ** 2))
            rows = fn(torch.cat([x[None], x[None] + eps * eye], 0))
            res = rows[0]
            J = (rows[1:] - res).T / eps
            cost = float(res @ res)
            H, g = J.T @ J, J.T @ res
            for _ in range(6):
                step = torch.linalg.solve(H + lam * torch.diag(torch.diag(H)) + 1e-9 * eye, -g)
                cand = x + step
                cand[9:] = cand[9:].clamp(0.0, 1.0)
                new = fn(cand[None])[0]
                if float(new @ new) < cost:
                    x, lam = cand, max(lam / 3, 1e-7)
                    break
                lam *= 4
            else:
                break
    return x


def _data_cost(obj: _Objective, i: int, x: torch.Tensor) -> float:
    with torch.no_grad():
        sub = _Objective.__new__(_Objective)
        sub.__dict__.update(obj.__dict__)
        sub.obs, sub.mask, sub.scale = obj.obs[i:i + 1], obj.mask[i:i + 1], obj.scale[i:i + 1]
        if obj.w.ndim == 2:
            sub.w = obj.w[i:i + 1]
        return float(sub.data(x[None]).sum() + sub.priors(x[None]).sum())


def _first_frame(obj: _Objective, i: int, x0: torch.Tensor, cfg: TrackConfig) -> torch.Tensor:
    """The first frame, with no previous frame to stay near: Levenberg-Marquardt from the
    given start and from the head turned -30, 0 and +30 degrees (the landmarks of a face
    seen from the front fit a turned head locally well too); the lowest cost wins."""
    free = TrackConfig(**{**cfg.__dict__, "velocity": {k: 0.0 for k in cfg.velocity}})
    first = _Objective.__new__(_Objective)
    first.__dict__.update({**obj.__dict__, "cfg": free})
    starts = [x0]
    for yaw in (-0.5, 0.0, 0.5):
        x = x0.clone()
        x[:3] = torch.tensor([0.0, yaw, 0.0], dtype=x.dtype)
        starts.append(x)
    best, best_cost = x0, float("inf")
    for x in starts:
        x = _frame_lm(first, i, x, x.clone(), 10 * cfg.frame_iterations)
        c = _data_cost(first, i, x)
        if c < best_cost:
            best, best_cost = x, c
    return best


def solve_frames(rig, cam: ClipCamera, obs: np.ndarray, found: np.ndarray,
                 weights: np.ndarray, init: FrameParams, cfg: TrackConfig | None = None,
                 progress: bool = True, g_ref: np.ndarray | None = None,
                 t_ref: np.ndarray | None = None) -> FrameParams:
    """The warm-started pass: frame i starts from frame i-1's solution (the first from
    ``init``'s first row, fitted longer, without the pull toward it) and is fitted alone
    by Levenberg-Marquardt, with a weak pull toward the previous frame (its velocity
    prior); a lost frame keeps the previous frame's parameters. ``g_ref``: the torso the
    prior holds (default: ``init``'s); ``t_ref``: the translation (default: ``init``'s)."""
    cfg = cfg or TrackConfig()
    T = len(obs)
    x_prev = torch.as_tensor(init.vector()[0], dtype=torch.float64)
    out = np.zeros((T, len(x_prev)))
    obj = _Objective(rig, cam, obs, found, weights, cfg,
                     init.g[:1] if g_ref is None else np.asarray(g_ref)[None],
                     init.t[:1] if t_ref is None else np.asarray(t_ref)[None])
    started, costs = False, []
    for i in tqdm(range(T), desc="tracking", unit="frame", disable=not progress, leave=False):
        if found[i]:
            if not started:  # the first frame: no previous frame to stay near
                x_prev = _first_frame(obj, i, x_prev, cfg)
                started = True
            x = _frame_lm(obj, i, x_prev, x_prev.clone(), cfg.frame_iterations)
            cost = _data_cost(obj, i, x)
            if costs and cost > 4.0 * float(np.median(costs[-15:])):
                # lost the face's pose (a fast turn, a bad detection): start again as for
                # a first frame, from here and from the turned heads, and keep the best
                y = _first_frame(obj, i, x, cfg)
                if _data_cost(obj, i, y) < cost:
                    x, cost = y, _data_cost(obj, i, y)
            costs.append(cost)
            x_prev = x
        out[i] = x_prev.numpy()
    return FrameParams.from_vector(out)


def solve_clip(rig, cam: ClipCamera, obs: np.ndarray, found: np.ndarray, weights: np.ndarray,
               init: FrameParams, g_ref: np.ndarray, cfg: TrackConfig | None = None,
               progress: bool = True, extra=None) -> FrameParams:
    """The joint solve: every frame's landmarks and priors plus velocity and acceleration
    penalties, over windows of ``cfg.window`` frames (each starting from the warm-started
    pass and joined to the frames before it; a clip up to 1.25 windows long is one). ``extra(x, frames)``: a further cost of a
    window's parameters x (T', D) for the frames (a slice) it holds (the outline stage's)."""
    cfg = cfg or TrackConfig()
    T = len(obs)
    x_all = torch.as_tensor(init.vector(), dtype=torch.float64).clone()
    # a clip up to a quarter longer than a window is one window: a second one over the
    # last window's frames for a short tail doubled the solve (250 frames: 240 + 240)
    span = T if T <= cfg.window + cfg.window // 4 else cfg.window
    step = max(1, span - span // 4)
    starts = list(range(0, max(T - span, 0) + 1, step))
    if starts[-1] + span < T:
        starts.append(T - span)
    for s in tqdm(starts, desc="smoothing", unit="window", disable=not progress or len(starts) < 2,
                  leave=False):
        e = min(T, s + span)
        obj = _Objective(rig, cam, obs[s:e], found[s:e], _window(weights, slice(s, e)), cfg,
                         g_ref)
        head = x_all[max(0, s - 2):s] if s > 0 else None
        sl = slice(s, e)

        def fn(x, obj=obj, head=head, sl=sl):
            cost = obj.data(x).sum() + obj.priors(x).sum() + obj.temporal(x, head)
            return cost if extra is None else cost + extra(x, sl)
        x = _lbfgs(x_all[s:e], fn, cfg.joint_iterations)
        keep = s if s == 0 else s + (min(cfg.window // 8, e - s))  # the overlap's later half
        x_all[keep:e] = x[keep - s:]
    return FrameParams.from_vector(x_all.numpy())


def landmark_error(rig, cam: ClipCamera, params: FrameParams, obs: np.ndarray,
                   found: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: mean landmark error in pixels and as a fraction of the outer-eye
    distance (NaN where lost), and the projected model landmarks (T, 68, 2)."""
    with torch.no_grad():
        X = rig.points(torch.as_tensor(params.psi), torch.as_tensor(params.h),
                       torch.as_tensor(params.g), torch.as_tensor(params.t))
        uv = cam.project(X).numpy()
    err = np.linalg.norm(uv - obs, axis=-1).mean(1)
    iod = np.linalg.norm(obs[:, 36] - obs[:, 45], axis=1)
    err = np.where(found, err, np.nan)
    return err, err / iod, uv
