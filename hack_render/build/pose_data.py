"""Simulated registered pose sequences for learning P_beta and W (paper Sec. 4.2, 5.2).

No dynamic captures exist here, so the default model's pose training data is *simulated*:
each identity's rest mesh is posed by dual-quaternion skinning (DQS; Kavan et al. 2008)
driven by the 8 vertebral joints, over the paper's range-of-motion action list (Sec. 4.2).
DQS is a higher-fidelity deformer than LBS for a neck: blending rigid transforms as unit
dual quaternions keeps each blended transform rigid, so the neck does not lose volume under
axial twist or bending (LBS's "candy wrapper"), which is exactly the error pose blendshapes
exist to correct. :func:`twist_area_ratio` measures it.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms, skin
from hack_render.geometry.rotations import _quat_mul, matrix_to_quaternion
from hack_render.geometry.skeleton import distribute_head_rotation

#: (name, whole-head Euler target in degrees (flexion, axial, lateral), frames), after Sec. 4.2.
ACTIONS = (
    ("flex", (45.0, 0.0, 0.0), 16), ("extend", (-60.0, 0.0, 0.0), 16),
    ("rotate_left", (0.0, 75.0, 0.0), 16), ("rotate_right", (0.0, -75.0, 0.0), 16),
    ("bend_left", (0.0, 0.0, 40.0), 16), ("bend_right", (0.0, 0.0, -40.0), 16),
    ("extension_hold", (-35.0, 0.0, 0.0), 12), ("twist", (15.0, 60.0, 20.0), 16),
)


def dqs(vertices: torch.Tensor, weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """Dual-quaternion skinning. vertices (B, N, 3), weights (N, K), rel (B, K, 4, 4) -> (B, N, 3)."""
    qr = matrix_to_quaternion(rel[..., :3, :3])  # (B, K, 4), w >= 0
    t = torch.cat([torch.zeros_like(rel[..., :1, 3]), rel[..., :3, 3]], -1)  # (B, K, 4)
    qd = 0.5 * _quat_mul(t, qr)
    br = torch.einsum("nk,bkc->bnc", weights, qr)
    bd = torch.einsum("nk,bkc->bnc", weights, qd)
    norm = br.norm(dim=-1, keepdim=True)
    br, bd = br / norm, bd / norm
    w, xyz = br[..., :1], br[..., 1:]
    v = vertices
    # Rotate v by br: v + 2 w (xyz x v) + 2 xyz x (xyz x v).
    c1 = torch.cross(xyz, v, dim=-1)
    rotated = v + 2 * w * c1 + 2 * torch.cross(xyz, c1, dim=-1)
    conj = torch.cat([br[..., :1], -br[..., 1:]], -1)
    trans = 2 * _quat_mul(bd, conj)[..., 1:]
    return rotated + trans


def action_thetas(actions=ACTIONS) -> list[tuple[str, torch.Tensor]]:
    """Per action, theta (F, 8, 3): out to the target and back (sin^2 ease), shared over the
    joints by their ranges and clamped to the limits."""
    out = []
    for name, target, frames in actions:
        s = torch.tensor([math.sin(math.pi * i / (frames - 1)) ** 2 for i in range(frames)],
                         dtype=torch.float64)
        ang = torch.deg2rad(torch.tensor(target, dtype=torch.float64))[None] * s[:, None]
        out.append((name, distribute_head_rotation(ang)))
    return out


def single_joint_sweeps(frames: int = 8) -> list[tuple[str, torch.Tensor]]:
    """Per joint, axis and side, theta (F, 8, 3) easing that one angle to its anatomical
    limit and back: the range of motion of each segment alone, which the whole-head actions
    never reach (they share a rotation over all joints)."""
    from hack_render.geometry.rotations import euler_to_axis_angle
    from hack_render.geometry.skeleton import JOINT_NAMES, rotation_limits

    lim = rotation_limits(torch.float64)
    s = torch.tensor([math.sin(math.pi * i / (frames - 1)) ** 2 for i in range(frames)], dtype=torch.float64)
    out = []
    for j, name in enumerate(JOINT_NAMES):
        for a, axis in enumerate("xyz"):
            for side in range(2):
                e = torch.zeros(frames, 8, 3, dtype=torch.float64)
                e[:, j, a] = lim[j, a, side] * s
                out.append((f"{name}_{axis}{'-+'[side]}", euler_to_axis_angle(e)))
    return out


def pose_sequence(rest: torch.Tensor, joints: torch.Tensor, weights: torch.Tensor,
                  parents: tuple[int, ...], theta: torch.Tensor, deformer: str = "dqs") -> torch.Tensor:
    """Posed vertices (F, N, 3) of one rest mesh (N, 3) with rest joints (K, 3)."""
    f = theta.shape[0]
    rot = local_rotations(theta, theta.new_zeros(f, 3))
    j = joints.expand(f, -1, -1)
    _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(parents))
    r = rest.expand(f, -1, -1)
    return dqs(r, weights, rel) if deformer == "dqs" else skin(r, weights, rel)


def twist_area_ratio(rest, joints, weights, parents, ring_idx: np.ndarray, degrees: float = 75.0) -> dict:
    """Area of a neck cross-section ring (vertex loop indices) after a whole-head axial twist,
    over its rest area, for LBS and DQS: 1.0 means no volume loss."""
    theta = distribute_head_rotation(torch.deg2rad(torch.tensor([[0.0, degrees, 0.0]], dtype=torch.float64)))
    out = {}
    for name in ("lbs", "dqs"):
        posed = pose_sequence(rest, joints, weights, parents, theta, name)[0].numpy()
        out[name] = _loop_area(posed[ring_idx]) / _loop_area(rest.numpy()[ring_idx])
    return out


def _loop_area(p: np.ndarray) -> float:
    """Area of the polygon of points p (n, 3) projected on the plane of least variance,
    ordered by angle about their centroid."""
    c = p - p.mean(0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    xy = c @ vt[:2].T
    order = np.argsort(np.arctan2(xy[:, 1], xy[:, 0]))
    x, y = xy[order, 0], xy[order, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
