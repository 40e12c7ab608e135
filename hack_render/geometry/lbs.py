"""Linear blend skinning over the HACK kinematic chain, as small pure functions.

Nodes: 0 is the root (thorax; it carries ``global_orient`` and sits at the c7-t1 joint),
nodes 1..8 are the joints c7-t1 ... o-c1. Rest-pose joint frames are aligned with the
model axes (as in SMPL), so a joint's local X/Y/Z are the model's X/Y/Z at rest.
"""

from __future__ import annotations

import torch

from hack_render.geometry.rotations import axis_angle_to_matrix


def chain_parents(parents: tuple[int, ...]) -> tuple[int, ...]:
    """Parents of the 9-node chain (root + joints) from the joints' parents (-1 = root)."""
    return (-1,) + tuple(p + 1 for p in parents)


def pose_gate(rot_mats: torch.Tensor, gate_rad: float, chain: float = 0.0) -> torch.Tensor:
    """The corrective gate of each joint (format 3): g = s^2 / (s^2 + c^4) with s = 2 (1 -
    cos angle) (about angle^2), so about angle^4 / (angle^4 + c^4): near 0 for rotations well
    under ``gate_rad`` = c, 1/2 at c, near 1 above. Rational in the entries of R, so smooth
    everywhere (no square root at zero). rot_mats: (..., K, 3, 3) -> (..., K).

    ``chain`` = lambda (format 4, ``pose_gate_chain``): s = 2 (1 - cos angle) + lambda |n|^2,
    n = sum over the K joints of each R's axial vector (sin angle times its axis): the
    chain's net rotation, about the head's angle to the thorax. A whole-head nod spread over
    the joints at a few degrees each then opens every joint's gate; rotations that
    alternate along the chain cancel in n and stay gated.

    Why: small rotations that alternate along the chain are where plain LBS barely
    stretches and a linear corrective shaped for large rotations adds stretch; the gate
    leaves them to LBS (docs/model.md, "Folds and the LBS rule")."""
    tr = rot_mats.diagonal(dim1=-2, dim2=-1).sum(-1)
    s = 3.0 - tr  # 2 (1 - cos angle)
    if chain:
        n = net_axial(rot_mats)
        s = s + chain * (n * n).sum(-1, keepdim=True)
    s2 = s * s
    return s2 / (s2 + gate_rad ** 4)


def net_axial(rot_mats: torch.Tensor) -> torch.Tensor:
    """The sum over the K joints of each rotation's axial vector (R - R^T) / 2 read as a
    vector (sin angle times the axis): (..., K, 3, 3) -> (..., 3)."""
    r = rot_mats
    v = torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                     r[..., 1, 0] - r[..., 0, 1]], -1)
    return 0.5 * v.sum(-2)


def pose_feature(rot_mats: torch.Tensor, gate_rad: float | None = None,
                 chain: float = 0.0) -> torch.Tensor:
    """SMPL-style pose feature ``(R_k - I)`` flattened, each joint's block times its
    :func:`pose_gate` when ``gate_rad`` is given (model files of format 3 with a
    ``pose_gate_deg``; ``chain``: format 4's ``pose_gate_chain``). rot_mats: (B, K, 3, 3) ->
    (B, 9K)."""
    eye = torch.eye(3, dtype=rot_mats.dtype, device=rot_mats.device)
    d = rot_mats - eye
    if gate_rad is not None:
        d = d * pose_gate(rot_mats, gate_rad, chain)[..., None, None]
    return d.flatten(1)


def rotation_log(r: torch.Tensor) -> torch.Tensor:
    """Axis-angle (..., 3) of rotations (..., 3, 3) below 180 degrees: the axial vector
    (R - R^T) / 2 = sin(angle) axis times angle / sin(angle) (angle = atan2(sin, cos), its
    series 1 + sin^2 / 6 near 0, so exact and differentiable at the identity). The same
    values as ``rotations.matrix_to_axis_angle`` in a dozen elementwise operations instead
    of Shepperd's method: the flexion block's net rotation in every forward (B = 1 runs
    dozens of small operations, each a fixed cost)."""
    v = 0.5 * torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                           r[..., 1, 0] - r[..., 0, 1]], -1)
    c = (0.5 * (r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1)).unsqueeze(-1)
    s2 = (v * v).sum(-1, keepdim=True)
    small = (s2 < 1e-8) & (c > 0)
    s = torch.where(small, torch.ones_like(s2), s2).sqrt()
    return v * torch.where(small, 1 + s2 / 6, torch.atan2(s, c) / s)


def flex_weights(rot_mats: torch.Tensor, knots_rad: torch.Tensor, width_rad: float,
                 purity_rad: float, coherence: float = 0.0,
                 net: torch.Tensor | None = None) -> torch.Tensor:
    """The flexion block's weights (B, H) (format 5, :mod:`hack_render.geometry.flex_block`):
    hats over the net flexion angle phi_x, ``max(0, 1 - |phi_x - k_h| / width)``, times
    ``exp(-(phi_y^2 + phi_z^2) / purity^2)``, times ``c^coherence`` with c = |sum_k a_k| /
    sum_k |a_k| the coherence of the joints' flexion (a_k: joint k's axial vector's x,
    sin angle times the axis; 1 when every joint bends the same way, as in a nod).
    rot_mats: the joints' (B, K, 3, 3), no root; ``net``: their product (B, 3, 3) where
    the caller has it (the forward's kinematics)."""
    if net is None:
        net = rot_mats[:, 0]
        for k in range(1, rot_mats.shape[1]):
            net = net @ rot_mats[:, k]
    phi = rotation_log(net)
    h = torch.relu(1 - (phi[:, :1] - knots_rad).abs() / width_rad)
    h = h * torch.exp(-(phi[:, 1:] ** 2).sum(-1, keepdim=True) / purity_rad ** 2)
    if coherence:
        a = 0.5 * (rot_mats[..., 2, 1] - rot_mats[..., 1, 2])  # (B, K)
        c = a.sum(-1).abs() / (a.abs().sum(-1) + 1e-9)
        h = h * (c ** coherence)[:, None]
    return h


def _offset_matrix(parents: tuple[int, ...], like: torch.Tensor) -> torch.Tensor:
    """(K, K) constant matrix D with (D j)_k = j_k - j_parent(k) (the root: j_0), in
    ``like``'s dtype and device: one product instead of a difference per node."""
    rows = [[(1.0 if i == k else 0.0) - (1.0 if i == p else 0.0) for i in range(len(parents))]
            for k, p in enumerate(parents)]
    return torch.tensor(rows, dtype=like.dtype, device=like.device)


def rigid_transforms(rot_mats: torch.Tensor, joints: torch.Tensor,
                     parents: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward kinematics.

    Args:
        rot_mats: (B, K, 3, 3) local rotations, node order with parents before children.
        joints: (B, K, 3) rest positions of the nodes.
        parents: parent index per node, -1 for the root.

    Returns:
        posed_joints: (B, K, 3) world positions of the nodes after posing.
        rel: (B, K, 4, 4) transforms that map a rest-pose point to its posed position when
            it moves rigidly with node k (the quantity blended by LBS).
    """
    B, K = joints.shape[:2]
    # each node's offset from its parent (the root's from the origin), by Python indexing
    # of the constant chain: no index tensors built per call
    rel_joints = torch.matmul(_offset_matrix(parents, joints), joints)
    bottom = joints.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(B, K, 1, 4)
    local = torch.cat([torch.cat([rot_mats, rel_joints.unsqueeze(-1)], -1), bottom], -2)
    world = [local[:, 0]]
    for k in range(1, K):
        world.append(world[parents[k]] @ local[:, k])
    world_t = torch.stack(world, dim=1)
    posed_joints = world_t[..., :3, 3]
    # Remove the rest-pose joint location: rel = world @ [I, -j_rest; 0, 1].
    shift = posed_joints - (world_t[..., :3, :3] @ joints.unsqueeze(-1)).squeeze(-1)
    rel = torch.cat([torch.cat([world_t[..., :3, :3], shift.unsqueeze(-1)], -1), bottom], -2)
    return posed_joints, rel


def is_path(parents: tuple[int, ...]) -> bool:
    """Whether a chain's parents are (-1, 0, 1, ..., K - 2): every node the previous one's
    child (HACK's: root, c7-t1, ..., o-c1)."""
    return tuple(parents) == tuple(range(-1, len(parents) - 1))


def path_transforms(rot_mats: torch.Tensor, joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`rigid_transforms` of a path chain (:func:`is_path`), with ``rel``'s top three
    rows only: (B, K, 3, 4). Each node's world transform is the product of the local ones
    from the root to it; the K products are taken as a prefix scan (ceil(log2 K) batched
    products, each node combining with the one d before it for d = 1, 2, 4, ...) instead
    of K - 1 products one after another: the same values to rounding, in fewer, larger
    operations (a B = 1 forward runs dozens of small ones)."""
    B, K = joints.shape[:2]
    offsets = torch.cat([joints[:, :1], joints[:, 1:] - joints[:, :-1]], 1)
    bottom = joints.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(B, K, 1, 4)
    world = torch.cat([torch.cat([rot_mats, offsets.unsqueeze(-1)], -1), bottom], -2)
    d = 1
    while d < K:
        world = torch.cat([world[:, :d], world[:, :-d] @ world[:, d:]], 1)
        d *= 2
    rot_w = world[..., :3, :3]
    posed = world[..., :3, 3]
    shift = posed - (rot_w @ joints.unsqueeze(-1)).squeeze(-1)
    return posed, torch.cat([rot_w, shift.unsqueeze(-1)], -1)


def skin(vertices: torch.Tensor, weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """Blend node transforms per vertex and apply them.

    Args:
        vertices: (B, N, 3) rest-pose vertices (with all corrective blendshapes).
        weights: (N, K) skinning weights, rows summing to 1.
        rel: (B, K, 4, 4) from :func:`rigid_transforms`.

    Returns:
        (B, N, 3) posed vertices. The blend is one (N, K) x (K, 12) product. It blends
        ``rel - I`` and adds the vertex back, which equals ``(W @ rel) v`` when rows sum to
        1 and is exact at the rest pose even when stored weights sum to 1 only to float32
        precision.
    """
    B, K = rel.shape[:2]
    eye = torch.eye(4, dtype=rel.dtype, device=rel.device)[:3]
    # D[b, n] = sum_k W[n, k] (rel[b, k] - I): contraction over k, rows 0..2 of the 4x4 only.
    d = torch.matmul(weights, (rel[..., :3, :] - eye).reshape(B, K, 12)).reshape(B, -1, 3, 4)
    return vertices + (d[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + d[..., 3]


def skin_reference(vertices: torch.Tensor, weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """Slow per-vertex LBS, for tests: a Python loop over vertices and nodes."""
    out = torch.zeros_like(vertices)
    for b in range(vertices.shape[0]):
        for n in range(vertices.shape[1]):
            acc = torch.zeros(4, 4, dtype=vertices.dtype)
            for k in range(weights.shape[1]):
                acc = acc + weights[n, k] * rel[b, k]
            p = torch.cat([vertices[b, n], vertices.new_ones(1)])
            out[b, n] = (acc @ p)[:3]
    return out


def local_rotations(theta: torch.Tensor, global_orient: torch.Tensor) -> torch.Tensor:
    """Rotation matrices of the chain: (B, 3) root and (B, 8, 3) joints -> (B, 9, 3, 3)."""
    return axis_angle_to_matrix(torch.cat([global_orient.unsqueeze(1), theta], dim=1))
