"""Synthetic motion for tests and benchmarks of the motion learners. NOT captured data:
every sequence here follows a rule written below, so a learner's result on it says whether
the learner can recover a known mapping, not how real necks or larynges move.

- :func:`neck_sequences`: smooth random head rotations shared over the 8 joints by a rule
  that is *not* ``distribute_head_rotation``'s proportional one: small rotations are taken
  mostly by the upper joints and large ones recruit the lower ones, and lateral bending
  couples with axial rotation to the same side below C2 (compensated at C1-C2), as the
  lower cervical spine's coupled motion (White & Panjabi 1990) does qualitatively.
- :func:`larynx_sequences`: speech-like expression curves and a larynx slide that is a
  known lagged function of them (:func:`lagged_tau`).
"""

from __future__ import annotations

import numpy as np
import torch

from hack_render.geometry.rotations import euler_to_axis_angle
from hack_render.geometry.skeleton import head_rotation_range_deg, rotation_limits

#: The lagged rule of :func:`lagged_tau`: (shape name, lag in frames, gain in metres).
TAU_RULE = (("jawOpen", 3, -0.006), ("mouthFunnel", 6, 0.004), ("mouthPucker", 2, 0.003))


def _smooth_curves(rng: np.random.Generator, frames: int, fps: float, dims: int,
                   max_hz: float) -> np.ndarray:
    """(frames, dims) smooth random curves in [-1, 1]: sums of 4 sinusoids each."""
    t = np.arange(frames)[:, None] / fps
    out = np.zeros((frames, dims))
    for _ in range(4):
        f = rng.uniform(0.05, max_hz, dims)
        out += rng.uniform(0.3, 1.0, dims) * np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3, dims))
    return out / np.abs(out).max(0).clip(1e-9)


def neck_rule(angles: np.ndarray) -> np.ndarray:
    """The synthetic rule: whole-head Euler angles (T, 3) radians (flexion X, axial Y,
    lateral Z) -> theta (T, 8, 3) axis-angle."""
    lim = rotation_limits(torch.float64).numpy()  # (8, 3, 2)
    total = np.abs(lim).sum(0).max(1)  # (3,) a loose scale per axis
    depth = np.arange(8)[::-1].astype(np.float64)  # o-c1: 0 ... c7-t1: 7
    a = angles[:, None, :]  # (T, 1, 3)
    frac = np.clip(np.abs(a) / total, 0.0, 1.0)
    span = np.where(a >= 0, lim[None, :, :, 1], -lim[None, :, :, 0])  # (T, 8, 3)
    w = span * np.exp(-2.5 * (1.0 - frac) * depth[None, :, None] / 7.0)
    e = a * w / w.sum(1, keepdims=True)
    couple = 0.6 * e[:, :6, 2]  # lateral bend -> same-side axial rotation, C2-C3 ... C7-T1
    e[:, :6, 1] += couple
    e[:, 6, 1] -= couple.sum(1)  # compensated at C1-C2
    return euler_to_axis_angle(torch.as_tensor(e)).numpy()


def neck_sequences(n: int, frames: int = 240, fps: float = 30.0, seed: int = 0,
                   reach: float = 0.8) -> list[np.ndarray]:
    """``n`` theta sequences (frames, 8, 3) of smooth head motion up to ``reach`` of the
    whole neck's range per axis, shared by :func:`neck_rule`."""
    rng = np.random.default_rng(seed)
    rngs = np.deg2rad(head_rotation_range_deg().numpy())  # (3, 2)
    out = []
    for _ in range(n):
        c = _smooth_curves(rng, frames, fps, 3, 0.5)
        ang = np.where(c >= 0, c * rngs[:, 1], -c * rngs[:, 0]) * reach
        out.append(neck_rule(ang))
    return out


def lagged_tau(psi: np.ndarray, names: list[str]) -> np.ndarray:
    """The known larynx slide (T,) metres of expressions psi (T, E): per :data:`TAU_RULE`
    entry, gain times the shape's weight ``lag`` frames earlier (the first frame's weight
    before the sequence starts), summed, plus a saturation ``-0.004 tanh(4 jawOpen *
    mouthFunnel)`` of the two shapes together (lag 3)."""
    t = np.zeros(len(psi))
    lagged = {}
    for name, lag, gain in TAU_RULE:
        x = psi[:, names.index(name)]
        x = np.r_[np.full(lag, x[0]), x[:len(x) - lag]]
        lagged[name] = x
        t += gain * x
    jaw = lagged["jawOpen"]
    funnel = psi[:, names.index("mouthFunnel")]
    funnel = np.r_[np.full(3, funnel[0]), funnel[:len(funnel) - 3]]
    return t - 0.004 * np.tanh(4.0 * jaw * funnel)


def larynx_sequences(n: int, names: list[str], frames: int = 200, fps: float = 30.0,
                     seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (psi (frames, E), tau (frames,)) pairs: speech-like activations in [0, 1] of
    the rule's shapes and a few others (which do not move the larynx), tau by
    :func:`lagged_tau`."""
    rng = np.random.default_rng(seed)
    used = [r[0] for r in TAU_RULE] + [k for k in ("mouthSmile_L", "mouthSmile_R",
                                                    "browInnerUp", "eyeBlink_L")
                                       if k in names]
    idx = [names.index(k) for k in used]
    out = []
    for _ in range(n):
        psi = np.zeros((frames, len(names)))
        c = _smooth_curves(rng, frames, fps, len(idx), 4.0)
        gate = 0.5 + 0.5 * _smooth_curves(rng, frames, fps, len(idx), 0.4)
        psi[:, idx] = np.clip(0.5 + 0.5 * c, 0, 1) * gate
        out.append((psi, lagged_tau(psi, names)))
    return out
