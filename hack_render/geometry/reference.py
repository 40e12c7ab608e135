"""G written plainly (:func:`reference_forward`): dense (3N-wide) shape, expression and pose
bases, each row's personalised bases built in full, the larynx per row and every vertex
skinned by :func:`lbs.skin`. The same model as :meth:`HackModel.forward`, the fast path, kept
for teaching and as the reference the tests compare the fast path with; slow."""

from __future__ import annotations

import torch

from hack_render.geometry.lbs import (
    chain_parents,
    flex_weights,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.geometry.model import HackOutput


def reference_forward(model, beta=None, psi=None, theta=None, global_orient=None,
                      transl=None, eta=None, tau=None):
    """G written plainly, for teaching and as the tests' reference for the fast forward:
    dense (3N-wide) shape, expression and pose bases, each row's personalised bases built
    in full, the larynx per row, and every vertex skinned by :func:`lbs.skin`. Same inputs
    and defaults as :meth:`HackModel.forward` (no ``clamp_limits``); slow."""
    m = model
    p = m._params(beta, psi, theta, global_orient, transl, eta, tau)
    B, n, E = p["theta"].shape[0], m.num_vertices, m.num_expressions
    beta = torch.nn.functional.pad(p["beta"], (0, m.num_shape - p["beta"].shape[1]))
    beta = beta.expand(B, -1)
    rot = local_rotations(p["theta"], p["global_orient"])
    feat = pose_feature(rot[:, 1:], m.pose_gate_rad, m.pose_gate_chain)
    shape_dirs, expr_dirs = m.expr_shape_basis[E:], m.expr_shape_basis[:E]
    rest = m.template + (beta @ shape_dirs + p["psi"] @ expr_dirs).view(B, n, 3)
    if m.has_pose_basis:  # the dense (72, N, 3) pose basis, zeros off the stored columns
        dense = torch.zeros(feat.shape[1], n, 3, dtype=rest.dtype, device=rest.device)
        dense[:, m.pose_columns] = m.pose_basis_columns.view(feat.shape[1], -1, 3)
        rest = rest + (feat @ dense.view(feat.shape[1], -1)).view(B, n, 3)
    for pb, coeffs in ((m.expr_personal, p["psi"]), (m.pose_personal, feat)):
        if pb is None:
            continue
        rows = []
        for b in range(B):  # each row's own basis: mean + sum_c w_c components_c
            w = pb.mlp(beta[b:b + 1])[0]
            basis = pb.mean + torch.einsum("c,cdk->dk", w, pb.components)
            rows.append((coeffs[b] @ basis).view(-1, 3))
        rest = rest.index_add(1, pb.vertices, torch.stack(rows))
    if m.flex is not None:  # format 5: every hat, each row's own identity
        w = flex_weights(rot[:, 1:], m.flex.knots.to(rest.dtype), m.flex.width, m.flex.purity,
                         m.flex.coherence)
        rest = rest.index_add(1, m.flex.vertices, torch.einsum(
            "bh,bhk->bk", w, m.flex.identity_rows(beta)).view(B, -1, 3))
    if m.has_larynx:
        lar = m._larynx_sample(m._larynx_combined(beta), p["eta"], p["tau"])
        rest = rest.index_add(1, m.larynx_vertices, lar)
    joints = m.rest_joints(beta)
    nodes = torch.cat([joints[:, :1], joints], 1)
    posed, rel = rigid_transforms(rot, nodes, chain_parents(m.parents))
    verts = skin(rest, m.skinning_weights, rel) + p["transl"][:, None]
    return HackOutput(vertices=verts, joints=posed[:, 1:] + p["transl"][:, None],
                      rest_joints=joints, landmarks=verts[:, m.landmark_indices],
                      rest_vertices=rest)
