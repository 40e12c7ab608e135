"""The skeleton's and the larynx's ranges as plain data, and the checks against them,
without torch.

The tables (the joints and their White & Panjabi ranges, the larynx's ``tau`` and ``eta``
ranges; sources in :mod:`hack_render.geometry.skeleton` and
:mod:`hack_render.geometry.larynx`, which re-export them) and the range checks that report
out-of-range input (:mod:`hack_render.geometry.limits`) are NumPy only, so a command that
poses one mesh without torch (:mod:`hack_render.geometry.posing`) warns, clamps and refuses
exactly as the torch path does. Angles follow :mod:`hack_render.geometry.rotations`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from hack_render.errors import expect
from hack_render.geometry import np_rotations

JOINT_NAMES: tuple[str, ...] = ("c7-t1", "c6-c7", "c5-c6", "c4-c5", "c3-c4", "c2-c3", "c1-c2", "o-c1")
NUM_JOINTS = len(JOINT_NAMES)
#: Parent of each joint in JOINT_NAMES order; -1 is the root (thorax).
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 4, 5, 6)

# (flexion + extension combined, lateral bending one side, axial rotation one side), degrees.
# White & Panjabi (1990), representative values; see ANATOMY.md.
RANGES_DEG = {
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
FLEXION_SHARE = {"o-c1": 0.4}

# How a whole-head rotation is shared over the levels (distribute_head_rotation), per axis:
# None shares it in proportion to the joints' limits above (White & Panjabi); a table gives
# in-vivo per-level angles, degrees, one side, measured at the subjects' full head rotation,
# and the head's rotation is shared in their proportions until a level reaches its limit, the
# rest then going to the levels still free (so the whole range above is still reached, with
# every joint at its limit). docs/model.md ("The spine against in-vivo data") compares the
# rules with the literature level by level.
#
# Axial rotation (y), one side, mean of healthy volunteers (3D MRI, registered vertebrae):
#   o-c1 1.7, c1-c2 36.2: Ishii T et al., Kinematics of the upper cervical spine in rotation:
#     in vivo three-dimensional analysis. Spine 2004;29(7):E139-44 (15 subjects; Results).
#   c2-c3 2.2, c3-c4 4.5, c4-c5 4.6, c5-c6 4.0, c6-c7 1.6, c7-t1 1.5: Ishii T et al.,
#     Kinematics of the subaxial cervical spine in rotation in vivo three-dimensional
#     analysis. Spine 2004;29(24):2826-31 (10 subjects, maximum head rotation 69.5; Results).
# Flexion/extension (x) and lateral bending (z) keep the limits' proportions: the in-vivo
# data found (Wu et al. 2007, Eur Spine J 16:1435, C2/3 13.5 and C4/5 22.6 of combined
# flexion-extension; Lan et al. 2014, BMC Musculoskelet Disord 15:273, lateral bending
# C2/3-C6/7 7.66, 8.37, 8.91, 7.19, 6.31) agree with them within 3 degrees per level, or
# leave levels unmeasured (o-c1, c1-c2, c7-t1): see docs/model.md.
IN_VIVO_AXIAL_DEG = {
    "o-c1": 1.7, "c1-c2": 36.2,
    "c2-c3": 2.2, "c3-c4": 4.5, "c4-c5": 4.6, "c5-c6": 4.0, "c6-c7": 1.6, "c7-t1": 1.5,
}
HEAD_SHARE_DEG: dict[int, dict[str, float] | None] = {0: None, 1: IN_VIVO_AXIAL_DEG, 2: None}

#: Names of the Euler axes (x, y, z) of a joint or of a whole-head rotation.
HEAD_AXES: tuple[str, str, str] = ("flexion/extension (x)", "axial rotation (y)",
                                   "lateral bending (z)")

# The whole neck's active range, head relative to thorax, degrees per axis (min, max), for
# a healthy adult: ANATOMY.md's "whole-neck active range" (flexion about 50, extension about
# 60-70, lateral bending about 45 per side, rotation about 80 per side), which its per-joint
# table (White & Panjabi, above) overshoots when every joint is at its limit at once: the
# joints' sums reach flexion 65.5 and lateral bending 61 (head_rotation_range_deg). In vivo,
# Niewiadomski C et al., Experimental assessment of cervical ranges of motion and
# compensatory strategies, Chiropractic & Manual Therapies 27 (2019) (97 healthy subjects,
# head relative to thorax, opto-electronic; Results): flexion + extension 127.4 +- 15.1,
# lateral inclination 89.3 +- 12 (both sides together), axial rotation 146.4 +- 13. The
# rotation's active range is above the joints' sum (77), so that axis is not narrowed.
# A joint coupling, not a joint limit: each joint keeps its own range (the checks below and
# :func:`clamp_theta` use those); this envelope bounds the sum of the joints' angles on
# each axis (:func:`within_active_range`), and the pose benchmarks give their figures
# within it too (docs/model.md, "Within the neck's active range").
ACTIVE_RANGE_DEG: tuple[tuple[float, float], ...] = ((-70.0, 50.0), (-80.0, 80.0), (-45.0, 45.0))

#: Vertical slide tau, metres (up positive): (min, max). See :mod:`~hack_render.geometry.larynx`.
TAU_RANGE_M: tuple[float, float] = (-0.01, 0.02)
#: Larynx size eta (1 = the identity's own larynx): (min, max).
ETA_RANGE: tuple[float, float] = (0.0, 1.5)
#: The default eta everywhere (Python API, parameter files, CLI): the identity's own larynx.
ETA_DEFAULT = 1.0


@lru_cache(maxsize=1)
def _limits_deg() -> np.ndarray:
    rows = []
    for name in JOINT_NAMES:
        fe, lat, axial = RANGES_DEG[name]
        share = FLEXION_SHARE.get(name, 0.5)
        rows.append([[-(1 - share) * fe, share * fe], [-axial, axial], [-lat, lat]])
    out = np.array(rows, dtype=np.float64)
    out.flags.writeable = False
    return out


def limits_deg() -> np.ndarray:
    """Per-joint Euler limits in degrees, (8, 3, 2) float64: [joint, axis (x, y, z), (min,
    max)]. Axis x: (-extension, +flexion); y: (-axial, +axial); z: (-lateral, +lateral)."""
    return _limits_deg().copy()


def head_rotation_range_deg() -> np.ndarray:
    """The whole neck's range for a head rotation, degrees, (3, 2): the sums of the joints'
    limits per axis."""
    return _limits_deg().sum(0)


def whole_neck_angles_deg(theta) -> np.ndarray:
    """The whole neck's angle per axis of poses (..., 8, 3) (axis-angle, radians): the sum
    over the joints of each joint's Euler angles, degrees (..., 3). A whole-head rotation
    shared out by :func:`distribute_head_rotation` gives back its own angles."""
    theta = _numpy(theta)
    expect(theta.ndim >= 2 and theta.shape[-2:] == (NUM_JOINTS, 3), "theta",
           f"shape (..., {NUM_JOINTS}, 3) axis-angle per joint", f"shape {theta.shape}")
    return np.rad2deg(np_rotations.axis_angle_to_euler(theta)).sum(-2)


def within_active_range(theta, tol_deg: float = 1e-6) -> np.ndarray:
    """(...,) bool: poses (..., 8, 3) whose whole-neck angles (:func:`whole_neck_angles_deg`)
    lie within :data:`ACTIVE_RANGE_DEG` on every axis."""
    a = whole_neck_angles_deg(theta)
    rng = np.asarray(ACTIVE_RANGE_DEG)
    return ((a >= rng[:, 0] - tol_deg) & (a <= rng[:, 1] + tol_deg)).all(-1)


def _numpy(x) -> np.ndarray:
    """A float64 array of ``x`` (a number, a sequence, an array or a torch tensor)."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def outside_limits(theta, tol_deg: float = 1e-3) -> list[tuple[int, str, str, float, float, float]]:
    """The joint angles of a pose (8, 3) or poses (B, 8, 3) (axis-angle, radians) beyond the
    limits: (joint, name, axis, deg, min, max) each."""
    theta = _numpy(theta)
    expect(theta.ndim >= 2 and theta.shape[-2:] == (NUM_JOINTS, 3), "theta",
           f"shape (..., {NUM_JOINTS}, 3) axis-angle per joint", f"shape {theta.shape}")
    e = np.rad2deg(np_rotations.axis_angle_to_euler(theta.reshape(-1, NUM_JOINTS, 3)))
    lim = _limits_deg()
    bad = []
    for b in range(e.shape[0]):
        for j in range(NUM_JOINTS):
            for a, axis in enumerate("xyz"):
                lo, hi = float(lim[j, a, 0]), float(lim[j, a, 1])
                val = float(e[b, j, a])
                if val < lo - tol_deg or val > hi + tol_deg:
                    bad.append((j, JOINT_NAMES[j], axis, val, lo, hi))
    return bad


def head_rotation_outside_limits(angles_deg, tol_deg: float = 1e-6
                                 ) -> list[tuple[str, float, float, float]]:
    """Axes of a whole-head rotation (3,) degrees beyond :func:`head_rotation_range_deg`:
    (axis name, requested deg, min, max) each."""
    a = _numpy(angles_deg).reshape(3)
    rng = head_rotation_range_deg()
    return [(HEAD_AXES[i], float(a[i]), float(rng[i, 0]), float(rng[i, 1])) for i in range(3)
            if a[i] < rng[i, 0] - tol_deg or a[i] > rng[i, 1] + tol_deg]


def larynx_outside_limits(eta, tau, tol: float = 1e-9) -> list[tuple[str, float, float, float]]:
    """The eta and tau values beyond their ranges: (name, value, min, max) per entry."""
    bad = []
    for name, x, (lo, hi) in (("eta", eta, ETA_RANGE), ("tau", tau, TAU_RANGE_M)):
        for val in _numpy(x).flatten().tolist():
            if val < lo - tol or val > hi + tol:
                bad.append((name, val, lo, hi))
    return bad


def clamp_theta(theta: np.ndarray) -> np.ndarray:
    """Each joint's Euler angles clamped to its limits (NumPy; the torch twin, for
    gradients, is :func:`hack_render.geometry.skeleton.clamp_to_limits`). (..., 8, 3)."""
    lim = np.deg2rad(_limits_deg())
    e = np_rotations.axis_angle_to_euler(theta)
    return np_rotations.euler_to_axis_angle(np.clip(e, lim[..., 0], lim[..., 1]))


def _share_knots(limits: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sharing of one side of one axis as a piecewise-linear map: knots of the head's
    angle A (K,) and each joint's angle at them E (K, 8), both from 0 to the full range.

    limits (8,) > 0: each joint's limit on that side; weights (8,) > 0: the shares while no
    joint is at its limit. Joint k's angle is min(limit_k, weight_k * t) at the water level t
    where the joints' angles sum to the head's; a knot wherever one more joint saturates."""
    t = np.unique(limits / weights)  # the levels where joints saturate, ascending
    t = np.concatenate([[0.0], t])
    e = np.minimum(limits[None], weights[None] * t[:, None])  # (K, 8)
    return e.sum(1), e


@lru_cache(maxsize=1)
def head_share_knots() -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], ...]:
    """The rule of :func:`distribute_head_rotation` as knots, radians: for each axis (x, y,
    z) and side (0: negative, 1: positive) the head's angle magnitudes A (K,) and the joints'
    angle magnitudes E (K, 8) at them (piecewise linear in between; A[-1] is the range)."""
    lim = np.abs(np.deg2rad(_limits_deg()))  # (8, 3, 2)
    out = []
    for axis in range(3):
        table = HEAD_SHARE_DEG[axis]
        sides = []
        for side in (0, 1):
            limits = lim[:, axis, side]
            weights = limits if table is None else np.array([table[n] for n in JOINT_NAMES])
            a, e = _share_knots(limits, weights / weights.sum())
            a.flags.writeable = False
            e.flags.writeable = False
            sides.append((a, e))
        out.append(tuple(sides))
    return tuple(out)


def head_share_deg(angles_deg) -> np.ndarray:
    """Per-joint Euler angles (8, 3), degrees, that :func:`distribute_head_rotation` gives a
    whole-head rotation (3,) degrees within the range (beyond it, each joint at its limit)."""
    a = np.deg2rad(_numpy(angles_deg).reshape(3))
    out = np.zeros((NUM_JOINTS, 3))
    for axis, sides in enumerate(head_share_knots()):
        knots, e = sides[int(a[axis] >= 0)]
        mag = abs(a[axis])
        out[:, axis] = np.sign(a[axis]) * np.array(
            [np.interp(mag, knots, e[:, k]) for k in range(NUM_JOINTS)])
    return np.rad2deg(out)


def distribute_head_rotation(angles: np.ndarray) -> np.ndarray:
    """A whole-head rotation (3,) radians shared over the 8 joints by the rule of
    :data:`HEAD_SHARE_DEG` (in-vivo shares for axial rotation, the joints' ranges for the
    other axes), each joint within its limits: (8, 3) axis-angle (NumPy; the torch twin, for
    gradients, is :func:`hack_render.geometry.skeleton.distribute_head_rotation`)."""
    e = np.deg2rad(head_share_deg(np.rad2deg(np.asarray(angles, dtype=np.float64))))
    return np_rotations.euler_to_axis_angle(e)
