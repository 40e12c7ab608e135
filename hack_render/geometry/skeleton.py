"""The HACK cervical skeleton: joint names, chain, anatomical rotation limits and priors.

Eight joints, from the thorax up (paper Sec. 3.1): c7-t1, c6-c7, c5-c6, c4-c5, c3-c4,
c2-c3, c1-c2, o-c1. Each sits behind an intervertebral disc; o-c1 is the
atlanto-occipital joint. A ninth node, the root (thorax, T1), carries the global rotation
and holds the chest and shoulders.

Rotation limits: White & Panjabi, *Clinical Biomechanics of the Spine* (1990), Table 2-? as
reproduced on the Anatomy Standard page cited by the paper (Fig. 5); flexion/extension is
the segment's combined range, split 40/60 (flexion/extension) at o-c1 and 50/50 elsewhere;
lateral bending and axial rotation are per side (see shared docs ANATOMY.md).
Angles follow :mod:`hack_render.geometry.rotations`: (flexion X, axial Y, lateral Z).
"""

from __future__ import annotations

import functools

import torch

from hack_render.errors import expect
from hack_render.geometry import anatomy
from hack_render.geometry.anatomy import (  # noqa: F401  (the tables and checks, re-exported)
    HEAD_AXES,
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    head_rotation_outside_limits,
    limits_deg,
    outside_limits,
)
from hack_render.geometry.rotations import (
    axis_angle_to_euler,
    euler_to_axis_angle,
)


def rotation_limits_deg() -> torch.Tensor:
    """Per-joint Euler limits in degrees, shape (8, 3, 2): [joint, axis (x, y, z), (min, max)]
    (float64; the table is :func:`hack_render.geometry.anatomy.limits_deg`).

    Axis x: (-extension, +flexion); y: (-axial, +axial); z: (-lateral, +lateral).
    """
    return torch.from_numpy(limits_deg())


def rotation_limits(dtype=torch.float32, device=None) -> torch.Tensor:
    """As :func:`rotation_limits_deg`, in radians, shape (8, 3, 2)."""
    return torch.deg2rad(rotation_limits_deg()).to(dtype=dtype, device=device)


def _check_theta(theta: torch.Tensor) -> None:
    expect(theta.ndim >= 2 and tuple(theta.shape[-2:]) == (NUM_JOINTS, 3), "theta",
           f"shape (..., {NUM_JOINTS}, 3) axis-angle per joint", f"shape {tuple(theta.shape)}")


def rotation_limit_penalty(theta: torch.Tensor) -> torch.Tensor:
    """E_rot (paper Eq. 9): L1 norm of the Euler-angle excess over the limits, per pose.

    theta: (..., 8, 3) axis-angle -> (...,) radians; zero inside the limits, positive outside.
    """
    _check_theta(theta)
    e = axis_angle_to_euler(theta)
    lim = rotation_limits(theta.dtype, theta.device)
    excess = torch.relu(e - lim[..., 1]) + torch.relu(lim[..., 0] - e)
    return excess.sum(dim=(-1, -2))


def adjacent_similarity_penalty(theta: torch.Tensor, normalized: bool = False) -> torch.Tensor:
    """E_sim (paper Eq. 10): sum over adjacent joints of ||e_i - e_{i+1}||^2 (Euler, rad^2).

    theta: (..., 8, 3) -> (...,). With ``normalized``, each angle is first divided by its
    joint's half range, so joints are compared by the fraction of their range they use
    (the anatomical prior shares motion in proportion to range, not equally).
    """
    _check_theta(theta)
    e = axis_angle_to_euler(theta)
    if normalized:
        lim = rotation_limits(theta.dtype, theta.device)
        e = e / (0.5 * (lim[..., 1] - lim[..., 0]))
    return ((e[..., 1:, :] - e[..., :-1, :]) ** 2).sum(dim=(-1, -2))


def clamp_to_limits(theta: torch.Tensor) -> torch.Tensor:
    """Clamp each joint's Euler angles to its limits. theta: (..., 8, 3) -> (..., 8, 3)."""
    _check_theta(theta)
    lim = rotation_limits(theta.dtype, theta.device)
    e = axis_angle_to_euler(theta)
    return euler_to_axis_angle(torch.maximum(torch.minimum(e, lim[..., 1]), lim[..., 0]))


def head_rotation_range_deg() -> torch.Tensor:
    """The whole neck's range for a head rotation, degrees, shape (3, 2): [axis (flexion X,
    axial Y, lateral Z), (min, max)], the sums of the joints' limits (float64). A request
    beyond it is what :func:`distribute_head_rotation` clamps."""
    return torch.from_numpy(anatomy.head_rotation_range_deg())


@functools.lru_cache(maxsize=64)
def _ramps(knots_id: int, clamp: bool, dtype: torch.dtype, device: str):
    """(knots (K,), the first segment's slope (8,), the slope changes at knots 1.. (K-1, 8))
    of :func:`anatomy.head_share_knots`' table ``knots_id`` (axis * 2 + side)."""
    a_np, e_np = anatomy.head_share_knots()[knots_id // 2][knots_id % 2]
    a = torch.tensor(a_np, dtype=dtype, device=device)  # a copy: knots are read-only
    e = torch.tensor(e_np, dtype=dtype, device=device)
    slope = (e[1:] - e[:-1]) / (a[1:] - a[:-1])[:, None]  # (K-1, 8)
    tail = torch.zeros_like(slope[:1]) if clamp else (e[-1] / a[-1])[None]
    slope = torch.cat([slope, tail])  # segment k starts at knot k
    return a[1:], slope[0], slope[1:] - slope[:-1]


def _piecewise(m: torch.Tensor, knots_id: int, clamp: bool) -> torch.Tensor:
    """A piecewise-linear map through the knots (A[k], E[k]) of table ``knots_id`` of
    :func:`anatomy.head_share_knots` (E[0] = 0 at A[0] = 0), at magnitudes m (...,) >= 0 ->
    (..., 8). Beyond the last knot: the last value (``clamp``) or the line from the origin
    through it. Written as a sum of ramps, ``m s_0 + sum_k relu(m - A_k) (s_k - s_{k-1})``,
    so that its gradient at 0 is the first segment's slope (the fitter starts there)."""
    a, s0, ds = _ramps(knots_id, clamp, m.dtype, str(m.device))
    m = m.unsqueeze(-1)  # (..., 1)
    return m * s0 + torch.relu(m - a) @ ds


def distribute_head_rotation(angles: torch.Tensor, clamp: bool = True) -> torch.Tensor:
    """Share a whole-head rotation over the 8 joints (the rule of
    :data:`hack_render.geometry.anatomy.HEAD_SHARE_DEG`).

    Flexion, extension and lateral bending are shared in proportion to the joints' ranges on
    that side: each joint's angle is ``angle * range_k / sum(range)``. Axial rotation is
    shared in the in-vivo proportions of Ishii et al. 2004 (c1-c2 about 64 %) until a joint
    reaches its limit, the rest then going to the joints still free; at the whole range
    every joint is at its limit, as before (knots: :func:`anatomy.head_share_knots`).

    Args:
        angles: (..., 3) whole-head Euler angles in radians (flexion X, axial Y, lateral Z).
        clamp: beyond the whole neck's range, stop at the range (each joint at its limit);
            without it, go on in proportion to the ranges (for fitting, where the head may
            pass the range on its way).

    Returns:
        theta: (..., 8, 3) axis-angle per joint. The composition of the eight rotations
        approximates the requested head rotation (exactly for a single axis).
    """
    expect(angles.shape[-1:] == (3,), "angles", "shape (..., 3)", f"shape {tuple(angles.shape)}")
    cols = []
    for axis in range(3):
        a = angles[..., axis]
        zero = torch.zeros_like(a)
        up = _piecewise(torch.where(a >= 0, a, zero), 2 * axis + 1, clamp)
        down = _piecewise(torch.where(a < 0, -a, zero), 2 * axis, clamp)
        cols.append(up - down)
    return euler_to_axis_angle(torch.stack(cols, -1))
