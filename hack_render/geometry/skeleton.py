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

import torch

from hack_render.errors import expect
from hack_render.geometry.rotations import (
    axis_angle_to_euler,
    euler_to_axis_angle,
)

JOINT_NAMES: tuple[str, ...] = ("c7-t1", "c6-c7", "c5-c6", "c4-c5", "c3-c4", "c2-c3", "c1-c2", "o-c1")
NUM_JOINTS = len(JOINT_NAMES)
#: Parent of each joint in JOINT_NAMES order; -1 is the root (thorax).
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 4, 5, 6)

# (flexion + extension combined, lateral bending one side, axial rotation one side), degrees.
# White & Panjabi (1990), representative values; see ANATOMY.md.
_RANGES_DEG = {
    "o-c1": (25.0, 5.0, 5.0),
    "c1-c2": (20.0, 5.0, 40.0),
    "c2-c3": (10.0, 10.0, 3.0),
    "c3-c4": (15.0, 11.0, 7.0),
    "c4-c5": (20.0, 11.0, 7.0),
    "c5-c6": (20.0, 8.0, 7.0),
    "c6-c7": (17.0, 7.0, 6.0),
    "c7-t1": (9.0, 4.0, 2.0),
}
# Share of the combined flexion/extension range that is flexion: o-c1 extends more than it
# flexes (ANATOMY.md, 40/60); 50/50 elsewhere.
_FLEXION_SHARE = {"o-c1": 0.4}


def rotation_limits_deg() -> torch.Tensor:
    """Per-joint Euler limits in degrees, shape (8, 3, 2): [joint, axis (x, y, z), (min, max)].

    Axis x: (-extension, +flexion); y: (-axial, +axial); z: (-lateral, +lateral).
    """
    rows = []
    for name in JOINT_NAMES:
        fe, lat, axial = _RANGES_DEG[name]
        share = _FLEXION_SHARE.get(name, 0.5)
        rows.append([[-(1 - share) * fe, share * fe], [-axial, axial], [-lat, lat]])
    return torch.tensor(rows, dtype=torch.float64)


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


def outside_limits(theta: torch.Tensor, tol_deg: float = 1e-3) -> list[tuple[int, str, str, float, float, float]]:
    """List the angles beyond the limits of a single pose (8, 3): (joint, name, axis, deg, min, max)."""
    _check_theta(theta)
    e = torch.rad2deg(axis_angle_to_euler(theta.detach().double().reshape(-1, NUM_JOINTS, 3)))
    lim = rotation_limits_deg()
    bad = []
    for b in range(e.shape[0]):
        for j in range(NUM_JOINTS):
            for a, axis in enumerate("xyz"):
                lo, hi = lim[j, a].tolist()
                val = float(e[b, j, a])
                if val < lo - tol_deg or val > hi + tol_deg:
                    bad.append((j, JOINT_NAMES[j], axis, val, lo, hi))
    return bad


def head_rotation_range_deg() -> torch.Tensor:
    """The whole neck's range for a head rotation, degrees, shape (3, 2): [axis (flexion X,
    axial Y, lateral Z), (min, max)], the sums of the joints' limits (float64). A request
    beyond it is what :func:`distribute_head_rotation` clamps."""
    return rotation_limits_deg().sum(0)


def head_rotation_outside_limits(angles_deg, tol_deg: float = 1e-6
                                 ) -> list[tuple[str, float, float, float]]:
    """Axes of a whole-head rotation (3,) degrees beyond :func:`head_rotation_range_deg`:
    (axis name, requested deg, min, max) each."""
    a = torch.as_tensor(angles_deg, dtype=torch.float64).reshape(3)
    rng = head_rotation_range_deg()
    return [(HEAD_AXES[i], float(a[i]), float(rng[i, 0]), float(rng[i, 1])) for i in range(3)
            if a[i] < rng[i, 0] - tol_deg or a[i] > rng[i, 1] + tol_deg]


#: Names of the Euler axes (x, y, z) of a joint or of a whole-head rotation.
HEAD_AXES: tuple[str, str, str] = ("flexion/extension (x)", "axial rotation (y)",
                                   "lateral bending (z)")


def distribute_head_rotation(angles: torch.Tensor, clamp: bool = True) -> torch.Tensor:
    """Share a whole-head rotation over the 8 joints in proportion to their ranges.

    Args:
        angles: (..., 3) whole-head Euler angles in radians (flexion X, axial Y, lateral Z).
            Flexion is shared by the joints' flexion ranges, extension by their extension
            ranges; each joint's angle is ``angle * range_k / sum(range)``.
        clamp: clamp each joint to its limits (a head rotation beyond the whole neck's range
            then stops at the range).

    Returns:
        theta: (..., 8, 3) axis-angle per joint. The composition of the eight rotations
        approximates the requested head rotation (exactly for a single axis).
    """
    expect(angles.shape[-1:] == (3,), "angles", "shape (..., 3)", f"shape {tuple(angles.shape)}")
    lim = rotation_limits(angles.dtype, angles.device)  # (8, 3, 2)
    lo, hi = lim[..., 0], lim[..., 1]  # (8, 3)
    frac_pos = hi / hi.sum(0)
    frac_neg = lo / lo.sum(0)
    a = angles.unsqueeze(-2)  # (..., 1, 3)
    e = torch.where(a >= 0, a * frac_pos, a * frac_neg)
    if clamp:
        e = torch.maximum(torch.minimum(e, hi), lo)
    return euler_to_axis_angle(e)
