"""Simulated registered pose sequences for learning P_beta and W (paper Sec. 4.2, 5.2).

No dynamic captures exist here, so the default model's pose training data is *simulated*:
each identity's rest mesh is posed over the paper's range-of-motion action list (Sec. 4.2),
plus every joint alone to its limits, by a deformer of higher fidelity than LBS, driven by
the 8 vertebral joints:

1. dual-quaternion skinning (DQS; Kavan et al. 2008): blending rigid transforms as unit
   dual quaternions keeps each blended transform rigid, so the neck does not lose volume
   under axial twist or bending (LBS's "candy wrapper"); :func:`twist_area_ratio` measures it;
2. then as-rigid-as-possible surface deformation (ARAP; Sorkine & Alexa 2007,
   :class:`ArapNeck`) of the neck skin, with the skull-rigid face and head and the
   root-rigid chest held where the skeleton puts them. Skinning concentrates a joint's
   rotation in the band of skin its weights blend over; ARAP spreads it over the whole
   free neck, which is what real skin does: a 40 degree c1-c2 twist stretches some skin
   edge by 53 % under LBS and by 24 % after ARAP (``ArapNeck`` docstring; the geometry
   test bounds every joint limit at 30 %).

The difference between this target and LBS is what the pose blendshapes learn.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy import sparse
from scipy.sparse.linalg import splu

from hack_render.errors import HackError
from hack_render.geometry.deformation import DeformationStats, deformation_stats, skin_topology
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms, skin
from hack_render.geometry.rotations import euler_to_axis_angle, matrix_to_quaternion, quat_mul
from hack_render.geometry.skeleton import JOINT_NAMES, distribute_head_rotation, rotation_limits

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
    qd = 0.5 * quat_mul(t, qr)
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
    trans = 2 * quat_mul(bd, conj)[..., 1:]
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


class ArapNeck:
    """As-rigid-as-possible surface deformation (Sorkine & Alexa 2007) of one rest mesh with
    a fixed vertex set, for many poses at once.

    The energy sum_i sum_j w_ij |(p_i - p_j) - R_i (v_i - v_j)|^2 (cotangent weights,
    clamped positive) is minimised over the free vertices' positions p and per-vertex
    rotations R_i by alternating the local step (R_i from the SVD of the edge covariance)
    and the global step (one sparse LU of the free-free Laplacian, factorised once per rest
    mesh). Fixed vertices keep the positions of the initial guess.

    Measured on the default model (face and head rigid with o-c1, chest rigid with the
    root, 1,309 free neck vertices): the largest skin-edge stretch at c1-c2's 40 degree
    axial limit drops from 0.53 (LBS) to 0.24, at o-c1's flexion limit from 0.31 to 0.16.

    Args:
        rest: (N, 3) rest vertices.
        faces: (T, 3) the surface to keep rigid (e.g. the skin triangles).
        fixed: (N,) bool; vertices outside ``faces`` are treated as fixed too.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, fixed: np.ndarray):
        rest = np.asarray(rest, np.float64)
        faces = np.asarray(faces, np.int64)
        n = len(rest)
        fixed = np.asarray(fixed, bool).copy()
        used = np.zeros(n, bool)
        used[faces.ravel()] = True
        fixed |= ~used
        if fixed.all():
            raise HackError("ArapNeck: every vertex is fixed; nothing to deform.")
        rows, cols, vals = [], [], []
        for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            u, v = rest[faces[:, a]] - rest[faces[:, c]], rest[faces[:, b]] - rest[faces[:, c]]
            cot = (u * v).sum(1) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-20)
            rows.append(faces[:, a]); cols.append(faces[:, b]); vals.append(0.5 * np.maximum(cot, 1e-3))
        w = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(n, n)).tocsr()
        w = (w + w.T).tocsr()
        lap = (sparse.diags(np.asarray(w.sum(1)).ravel()) - w).tocsr()
        self.free = np.flatnonzero(~fixed)
        self.fixed = np.flatnonzero(fixed)
        self.lu = splu(lap[self.free][:, self.free].tocsc())
        self.l_fx = lap[self.free][:, self.fixed].tocsr()
        # Vertices whose rotations the global step needs: the free ones and their neighbours.
        touched = np.zeros(n, bool)
        touched[self.free] = True
        touched[w[self.free].indices] = True
        self.active = np.flatnonzero(touched)
        pos = -np.ones(n, np.int64)
        pos[self.active] = np.arange(len(self.active))
        wa = w[self.active].tocoo()  # directed edges i -> j with i active
        self.ei, self.ej = self.active[wa.row], wa.col
        self.e0 = rest[self.ei] - rest[self.ej]  # (E, 3)
        ne = len(self.ei)
        # S_i = sum_j w_ij e0_ij e1_ij^T: one sparse (A, E) matrix.
        self.gather = sparse.csr_matrix((wa.data, (wa.row, np.arange(ne))), shape=(len(self.active), ne))
        # b_i = sum_j w_ij / 2 (R_i + R_j) e0_ij over the edges leaving free vertices.
        fpos = -np.ones(n, np.int64)
        fpos[self.free] = np.arange(len(self.free))
        sel = np.flatnonzero(fpos[self.ei] >= 0)
        self.b_edges, self.b_i, self.b_j = sel, pos[self.ei[sel]], pos[self.ej[sel]]
        self.b_sum = sparse.csr_matrix((0.5 * wa.data[sel], (fpos[self.ei[sel]], np.arange(len(sel)))),
                                       shape=(len(self.free), len(sel)))

    def __call__(self, initial: np.ndarray, iterations: int = 30) -> np.ndarray:
        """initial (F, N, 3) posed guesses (fixed vertices where they must stay) -> (F, N, 3)."""
        p = np.array(initial, np.float64, copy=True)
        f = p.shape[0]
        nf = len(self.free)
        rhs_fixed = np.stack([self.l_fx @ p[k, self.fixed] for k in range(f)])  # (F, nf, 3)
        for _ in range(iterations):
            e1 = p[:, self.ei] - p[:, self.ej]  # (F, E, 3)
            cov = self.e0[None, :, :, None] * e1[:, :, None, :]  # (F, E, 3, 3)
            s = (self.gather @ cov.transpose(1, 0, 2, 3).reshape(len(self.ei), -1))
            s = s.reshape(len(self.active), f, 3, 3).transpose(1, 0, 2, 3)
            u, _, vt = np.linalg.svd(s)
            d = np.sign(np.linalg.det(np.einsum("fakj,falk->fajl", vt, u)))
            u[..., :, 2] *= d[..., None]
            rot = np.einsum("fakj,falk->fajl", vt, u)  # R = V U^T, det +1
            r_e = rot[:, self.b_i] + rot[:, self.b_j]  # (F, Eb, 3, 3)
            be = np.einsum("fejk,ek->fej", r_e, self.e0[self.b_edges])
            b = (self.b_sum @ be.transpose(1, 0, 2).reshape(len(self.b_edges), -1)).reshape(nf, f, 3)
            rhs = b.transpose(1, 0, 2) - rhs_fixed
            sol = self.lu.solve(rhs.transpose(1, 0, 2).reshape(nf, -1))
            p[:, self.free] = sol.reshape(nf, f, 3).transpose(1, 0, 2)
        return p


def pose_sequence(rest: torch.Tensor, joints: torch.Tensor, weights: torch.Tensor,
                  parents: tuple[int, ...], theta: torch.Tensor, deformer: str = "dqs",
                  arap: ArapNeck | None = None, arap_iterations: int = 30) -> torch.Tensor:
    """Posed vertices (F, N, 3) of one rest mesh (N, 3) with rest joints (K, 3).

    ``deformer``: "lbs", "dqs", or "arap" (DQS, then ``arap`` (an :class:`ArapNeck` of this
    rest mesh) with the vertices it fixes left where DQS put them).
    """
    if deformer not in ("lbs", "dqs", "arap"):
        raise HackError(f"pose_sequence: unknown deformer {deformer!r}; use 'lbs', 'dqs' or 'arap'.")
    if deformer == "arap" and arap is None:
        raise HackError("pose_sequence: deformer 'arap' needs an ArapNeck of the rest mesh.")
    f = theta.shape[0]
    rot = local_rotations(theta, theta.new_zeros(f, 3))
    j = joints.expand(f, -1, -1)
    _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(parents))
    r = rest.expand(f, -1, -1)
    if deformer == "lbs":
        return skin(r, weights, rel)
    posed = dqs(r, weights, rel)
    if deformer == "dqs":
        return posed
    return torch.as_tensor(arap(posed.numpy(), arap_iterations), dtype=posed.dtype)


def arap_deformation(model, beta: torch.Tensor, theta: torch.Tensor, psi=None, topo=None,
                     iterations: int = 30, chunk: int = 25):
    """:func:`~hack_render.geometry.deformation.deformation_stats` of ARAP (DQS, then
    :class:`ArapNeck` of the skin) over poses theta (P, 8, 3) of one identity of a
    :class:`~hack_render.geometry.model.HackModel` (beta (1, S), expression psi (E,) held or
    None), in float64: the reference deformer of the stretch bench
    (``bench/bench_pose_arap.py``). The skin vertices skinned to one node are held rigid
    with it, the rigid sets of :func:`~hack_render.geometry.deformation.stretch_lower_bound`,
    so the bound holds for it too."""
    topo = topo or skin_topology(model)
    person = model.personalize(beta)
    with torch.no_grad():
        psi1 = None if psi is None else torch.as_tensor(psi, dtype=model.template.dtype).reshape(1, -1)
        rest = person(psi=psi1).vertices[0].double()
        joints = person.joints.reshape(-1, 3).double()
    w = model.skinning_weights.double()
    arap = ArapNeck(rest.numpy(), topo.faces.numpy(), (w.max(1).values >= 1 - 1e-6).numpy())
    parts = []
    for s in range(0, theta.shape[0], chunk):
        th = theta[s:s + chunk].double()
        posed = pose_sequence(rest, joints, w, model.parents, th, "arap", arap, iterations)
        f = th.shape[0]
        j = joints.expand(f, -1, -1)
        _, rel = rigid_transforms(local_rotations(th, th.new_zeros(f, 3)),
                                  torch.cat([j[:, :1], j], 1), chain_parents(model.parents))
        parts.append(deformation_stats(rest, posed, rel[..., :3, :3], topo))
    return DeformationStats(**{k: torch.cat([getattr(p, k) for p in parts])
                               for k in ("stretch", "compression", "folded")})


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
