"""Rotation conversions, exact and differentiable near zero.

All functions broadcast over leading dimensions and keep the input's dtype and device.

Euler convention (used for anatomical limits): a joint rotation is
``R = Rx(flexion) @ Rz(lateral) @ Ry(axial)`` in the joint's local frame (Y up, face +Z),
i.e. intrinsic X, then Z, then Y. Lateral bending sits in the middle because its per-joint
range is smallest (<= 11 degrees), far from the +-90 degree gimbal singularity. Positive
flexion (about +X) tips the head forward (Y towards +Z), positive axial rotation (about +Y)
turns the face towards +X (the subject's left), positive lateral bending (about +Z) tilts the
top of the head towards -X (the subject's right ear down).
"""

from __future__ import annotations

import torch

from hack_render.geometry.np_rotations import euler_quaternion, quat_product

# Below this squared angle the closed forms lose precision; Taylor series are used instead.
_SMALL = 1e-6


def _safe_where(cond: torch.Tensor, small: torch.Tensor, big_fn, x: torch.Tensor) -> torch.Tensor:
    """``where(cond, small, big_fn(x))`` without NaN gradients leaking from the unused branch."""
    x_safe = torch.where(cond, torch.ones_like(x), x)
    return torch.where(cond, small, big_fn(x_safe))


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix. v: (..., 3) -> (..., 3, 3)."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(r: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula. r: (..., 3) axis times angle (radians) -> (..., 3, 3).

    Uses ``R = I + a K + b K^2`` with ``a = sin(t)/t``, ``b = (1 - cos t)/t^2`` and series for
    small ``t``, so the value and gradient are exact at ``r = 0`` (no ``norm(r + eps)``).
    """
    t2 = (r * r).sum(-1, keepdim=True).unsqueeze(-1)  # (..., 1, 1)
    small = t2 < _SMALL
    a_series = 1 - t2 / 6 + t2 * t2 / 120
    b_series = 0.5 - t2 / 24 + t2 * t2 / 720
    a = _safe_where(small, a_series, lambda s: torch.sin(s.sqrt()) / s.sqrt(), t2)
    b = _safe_where(small, b_series, lambda s: (1 - torch.cos(s.sqrt())) / s, t2)
    k = skew(r)
    eye = torch.eye(3, dtype=r.dtype, device=r.device).expand_as(k)
    return eye + a * k + b * (k @ k)


def quaternion_to_axis_angle(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (..., 4) as (w, x, y, z) -> axis-angle (..., 3), angle in [0, pi]."""
    q = torch.where(q[..., :1] < 0, -q, q)  # shortest rotation
    w, v = q[..., :1], q[..., 1:]
    s2 = (v * v).sum(-1, keepdim=True)
    small = s2 < _SMALL
    # 2 atan2(s, w) / s, with its series 2/w (1 - s^2/(3 w^2)) for small s.
    series = 2 / w * (1 - s2 / (3 * w * w))
    factor = _safe_where(small, series, lambda x: 2 * torch.atan2(x.sqrt(), w) / x.sqrt(), s2)
    return v * factor


def matrix_to_quaternion(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) (w, x, y, z), w >= 0.

    Shepperd's method: picks the best-conditioned of four formulas per element.
    """
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cands = torch.stack([
        torch.stack([1 + m00 + m11 + m22, m[..., 2, 1] - m[..., 1, 2],
                     m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
        torch.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m00 - m11 - m22,
                     m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        torch.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                     1 - m00 + m11 - m22, m[..., 1, 2] + m[..., 2, 1]], -1),
        torch.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                     m[..., 1, 2] + m[..., 2, 1], 1 - m00 - m11 + m22], -1),
    ], dim=-2)  # (..., 4, 4): row k is 4 q_k q
    diag = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                        1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = diag.argmax(-1, keepdim=True)
    row = torch.gather(cands, -2, best.unsqueeze(-1).expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = row / row.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def matrix_to_axis_angle(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrix (..., 3, 3) -> axis-angle (..., 3)."""
    return quaternion_to_axis_angle(matrix_to_quaternion(m))


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of quaternions (..., 4), scalar first (w, x, y, z)."""
    return torch.stack(quat_product(a, b), -1)


def euler_to_axis_angle(e: torch.Tensor) -> torch.Tensor:
    """Anatomical Euler angles (..., 3) = (flexion X, axial Y, lateral Z), radians -> axis-angle.

    The component order of ``e`` follows the axes (x, y, z); the composition order is the
    module's convention ``Rx(e_x) @ Rz(e_z) @ Ry(e_y)``.
    """
    return quaternion_to_axis_angle(torch.stack(euler_quaternion(e, torch.cos, torch.sin), -1))


def matrix_to_euler(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrix (..., 3, 3) -> (flexion X, axial Y, lateral Z) radians, module convention.

    With R = Rx(a) Rz(b) Ry(c): R01 = -sin b, R21/R11 = tan a, R02/R00 = tan c.
    """
    a = torch.atan2(m[..., 2, 1], m[..., 1, 1])
    c = torch.atan2(m[..., 0, 2], m[..., 0, 0])
    cb = torch.sqrt(m[..., 0, 0] ** 2 + m[..., 0, 2] ** 2)
    b = torch.atan2(-m[..., 0, 1], cb)
    return torch.stack([a, c, b], -1)


def axis_angle_to_euler(r: torch.Tensor) -> torch.Tensor:
    """Axis-angle (..., 3) -> (flexion X, axial Y, lateral Z) radians, module convention."""
    return matrix_to_euler(axis_angle_to_matrix(r))
