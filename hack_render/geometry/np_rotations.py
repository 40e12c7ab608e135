"""The rotation conversions of :mod:`hack_render.geometry.rotations` in NumPy, for code
that must not import torch (range checks, posing one mesh for a render). Same
conventions: axis-angle in radians, anatomical Euler angles (flexion X, axial Y,
lateral Z) composed as ``Rx @ Rz @ Ry``. Not differentiable; the torch functions are the
ones to optimise through. ``tests/test_posing.py`` holds the two equal."""

from __future__ import annotations

import numpy as np

_SMALL = 1e-6  # squared angle below which the series replace the closed forms


def axis_angle_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rodrigues' formula. r: (..., 3) -> (..., 3, 3)."""
    r = np.asarray(r, dtype=np.float64)
    t2 = (r * r).sum(-1)[..., None, None]
    t = np.sqrt(t2)
    small = t2 < _SMALL
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
        b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / t2)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    o = np.zeros_like(x)
    k = np.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*r.shape[:-1], 3, 3)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_euler(m: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> (flexion X, axial Y, lateral Z) radians."""
    a = np.arctan2(m[..., 2, 1], m[..., 1, 1])
    c = np.arctan2(m[..., 0, 2], m[..., 0, 0])
    b = np.arctan2(-m[..., 0, 1], np.sqrt(m[..., 0, 0] ** 2 + m[..., 0, 2] ** 2))
    return np.stack([a, c, b], -1)


def axis_angle_to_euler(r: np.ndarray) -> np.ndarray:
    """Axis-angle (..., 3) -> (flexion X, axial Y, lateral Z) radians."""
    return matrix_to_euler(axis_angle_to_matrix(r))


def quat_product(a, b) -> tuple:
    """The Hamilton product's components (w, x, y, z) of quaternions ``a`` and ``b``
    (..., 4): NumPy arrays or torch tensors alike (:mod:`~hack_render.geometry.rotations`
    stacks them too)."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def euler_quaternion(e, cos, sin) -> tuple:
    """The components (w, x, y, z) of the quaternion of ``Rx(e_x) @ Rz(e_z) @ Ry(e_y)``,
    for anatomical Euler angles ``e`` (..., 3) = (flexion X, axial Y, lateral Z): NumPy
    arrays (pass ``np.cos, np.sin``) or torch tensors (``torch.cos, torch.sin``) alike.
    The product qx qz qy written out."""
    cx, sx = cos(e[..., 0] / 2), sin(e[..., 0] / 2)
    cy, sy = cos(e[..., 1] / 2), sin(e[..., 1] / 2)
    cz, sz = cos(e[..., 2] / 2), sin(e[..., 2] / 2)
    pw, px, py, pz = cx * cz, sx * cz, -sx * sz, cx * sz  # qx qz
    return (pw * cy - py * sy, px * cy - pz * sy, pw * sy + py * cy, px * sy + pz * cy)


def quaternion_to_axis_angle(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) as (w, x, y, z) -> axis-angle (..., 3), angle in [0, pi]."""
    q = np.where(q[..., :1] < 0, -q, q)
    w, v = q[..., :1], q[..., 1:]
    s2 = (v * v).sum(-1, keepdims=True)
    s = np.sqrt(s2)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(s2 < _SMALL, 2 / w * (1 - s2 / (3 * w * w)), 2 * np.arctan2(s, w) / s)
    return v * factor


def matrix_to_axis_angle(m: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> axis-angle (..., 3), by the unit quaternion of
    Shepperd's method (the best-conditioned of four formulas per matrix), as the torch
    ``matrix_to_axis_angle``."""
    m = np.asarray(m, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    a, b, c = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    d, e, f = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    cands = np.stack([np.stack([1 + m00 + m11 + m22, a, b, c], -1),
                      np.stack([a, 1 + m00 - m11 - m22, d, e], -1),
                      np.stack([b, d, 1 - m00 + m11 - m22, f], -1),
                      np.stack([c, e, f, 1 - m00 - m11 + m22], -1)], -2)
    diag = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22,
                     1 - m00 - m11 + m22], -1)
    row = np.take_along_axis(cands, diag.argmax(-1)[..., None, None], -2)[..., 0, :]
    return quaternion_to_axis_angle(row / np.linalg.norm(row, axis=-1, keepdims=True))


def euler_to_axis_angle(e: np.ndarray) -> np.ndarray:
    """(flexion X, axial Y, lateral Z) radians (..., 3) -> axis-angle (..., 3)."""
    e = np.asarray(e, dtype=np.float64)
    return quaternion_to_axis_angle(np.stack(euler_quaternion(e, np.cos, np.sin), -1))
