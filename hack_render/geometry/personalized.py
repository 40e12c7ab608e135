"""HACK for one fixed identity (:meth:`HackModel.personalize`): "personalise once, animate
many". Everything that depends on beta alone (the shaped template, the expression basis with
the personalised correctives folded in, the pose correctives on their columns, the joints,
the larynx's maps, the flexion block's rows) is built once; the forward then reads one expression basis and poses."""

from __future__ import annotations

import torch
from torch import nn

from hack_render.errors import HackError
from hack_render.geometry import larynx as _larynx
from hack_render.geometry.lbs import local_rotations
from hack_render.geometry.products import add_rows_, rows_product
from hack_render.geometry.skeleton import clamp_to_limits
from hack_render.threads import bulk_work, small_work


class PersonalizedHack(nn.Module):
    """HACK for one fixed identity: "personalise once, animate many"."""

    def __init__(self, model, beta):
        super().__init__()
        self.model = model
        p = model._params(beta, None, None, None, None, None, None)
        beta = p["beta"]
        if beta.shape[0] != 1:
            raise HackError(f"beta: personalize takes one identity, found batch {beta.shape[0]}.")
        with torch.no_grad():
            beta_full = torch.nn.functional.pad(beta, (0, model.num_shape - beta.shape[1]))
            e, n = model.num_expressions, model.num_vertices
            v_shaped = model.template.view(1, -1) + beta_full @ model.expr_shape_basis[e:]
            expr = model.expr_shape_basis[:e].clone().view(e, n, 3)  # (E, N, 3)
            if model.expr_personal is not None:
                expr.index_add_(1, model.expr_personal.vertices, model.expr_personal.basis(beta_full))
            # pose correctives on the union of the generic and personalised columns
            parts = []
            if model.has_pose_basis:
                parts.append((model.pose_columns, model.pose_basis_columns.view(-1, len(model.pose_columns), 3)))
            if model.pose_personal is not None:
                parts.append((model.pose_personal.vertices, model.pose_personal.basis(beta_full)))
            self.uses_pose = bool(parts)
            if parts:
                cols = torch.unique(torch.cat([c for c, _ in parts]))
                pose = torch.zeros(9 * model.num_joints, n, 3, dtype=expr.dtype, device=expr.device)
                for c, b in parts:
                    pose.index_add_(1, c, b)
                self.register_buffer("pose_columns", cols)
                self.register_buffer("pose_basis", pose[:, cols].reshape(pose.shape[0], -1).contiguous())
            self.register_buffer("v_shaped", v_shaped)
            self.register_buffer("basis", expr.reshape(e, -1))
            self.register_buffer("joints", model.rest_joints(beta_full)[0])
            if model.has_larynx:
                self.register_buffer("larynx_combined", model._larynx_combined(beta_full))
            if model.flex is not None:  # format 5: each hat's offsets for this identity
                self.register_buffer("flex_rows", model.flex.identity_rows(beta_full))

    def forward(self, psi=None, theta=None, global_orient=None, transl=None, eta=None,
                tau=None, clamp_limits: bool = False):
        """As :meth:`HackModel.forward` at the personalised beta (same defaults)."""
        m = self.model
        p = m._params(None, psi, theta, global_orient, transl, eta, tau)
        if clamp_limits:
            p["theta"] = clamp_to_limits(p["theta"])
            p["eta"], p["tau"] = _larynx.clamp_larynx(p["eta"], p["tau"])
        B = p["theta"].shape[0]
        with small_work(B == 1):  # as HackModel.forward
            rot = local_rotations(p["theta"], p["global_orient"])
            joints = self.joints.expand(B, -1, -1)
            posing = m._posing(joints, rot, p["transl"])
            flex = m.flex_delta(None, rot, posing[3], self.flex_rows) if m.flex is not None else None
            with bulk_work():
                rest = rows_product(p["psi"], self.basis, self.v_shaped).view(B, -1, 3)
            if self.uses_pose:
                add_rows_(rest, self.pose_columns,
                           (m.pose_features(rot) @ self.pose_basis).view(B, -1, 3))
            if flex is not None:
                add_rows_(rest, *flex)
            if m.has_larynx:
                add_rows_(rest, m.larynx_vertices,
                           m._larynx_sample(self.larynx_combined.expand(B, -1, -1, -1),
                                            p["eta"], p["tau"]))
            return m._pose(rest, joints, rot, p["transl"], posing)
