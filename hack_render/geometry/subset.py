"""The model's forward at a few vertices: for losses that read a few hundred of its
26,719 vertices (the photo fit's landmark stages: the landmark embedding's triangles, the
jawline's candidate strips and the ring of faces about them).

:class:`VertexSubset` applies to vertices that move rigidly with the skull's node (no
blend between joints, no pose corrective, no larynx: what a face's landmarks read on the
shipped model), where the posed vertices of identity ``beta`` and expression ``psi`` are

    X = A(theta, g) [T + beta B_S + psi B_E + psi (M + w(beta) C)] + a(theta, g) + t

with the shape and generic expression rows ``B_S``, ``B_E``, the personalised expression
basis's mean ``M`` and components ``C`` (``w``: its MLP of beta) all read at the subset's
columns only, and ``A, a`` the skull node's rigid transform (the chain's forward
kinematics at the identity's rest joints). The same values as
:meth:`~hack_render.geometry.model.HackModel.forward` at those vertices to float
rounding, and differentiable in every input (tests/test_fit_views.py checks both); a
shape stage's forward and backward read about 5 MB of bases instead of about 100 MB.
"""

from __future__ import annotations

import numpy as np
import torch

from hack_render.geometry.lbs import (
    chain_parents,
    is_path,
    local_rotations,
    path_transforms,
    rigid_transforms,
)


def _columns(index: torch.Tensor) -> torch.Tensor:
    """Vertex indices (n,) -> their (3n,) x, y, z columns in a flat (3N,) layout."""
    return (3 * index[:, None] + torch.arange(3)).reshape(-1)


class VertexSubset:
    """The posed vertices ``index`` (n,) of ``model``; build with :meth:`build`."""

    def __init__(self, model, index: torch.Tensor):
        self.model = model
        self.index = index
        cols = _columns(index)
        self.template = model.template.reshape(-1)[cols]              # (3n,)
        self.basis = model.expr_shape_basis[:, cols].contiguous()     # (E + S, 3n)
        self.ep = None
        ep = getattr(model, "expr_personal", None)
        if ep is not None:
            where = {int(v): i for i, v in enumerate(ep.vertices.tolist())}
            own = [(k, where[int(v)]) for k, v in enumerate(index.tolist()) if int(v) in where]
            if own:
                at = torch.tensor([k for k, _ in own])
                pc = _columns(torch.tensor([p for _, p in own]))
                # (positions in the subset, mean (D, 3m), rows (D, C, 3m), the MLP)
                self.ep = (at, ep.mean[:, pc].contiguous(),
                           ep.rows[:, :, pc].contiguous(), ep.mlp)

    @classmethod
    def build(cls, model, vertices) -> VertexSubset | None:
        """The subset of ``vertices`` (any order, repeats allowed), or None where the
        model's forward there is not the rigid form above (a vertex blended between
        joints or carrying a pose corrective or the larynx, a model without the bases
        read here): the caller then runs the whole forward."""
        index = torch.as_tensor(np.unique(np.asarray(vertices, dtype=np.int64)))
        need = ("template", "expr_shape_basis", "blended_vertices", "rigid_node",
                "rest_joints", "parents")
        if len(index) == 0 or not all(hasattr(model, k) for k in need):
            return None
        if int(index.max()) >= model.num_vertices or int(index.min()) < 0:
            return None
        moved = [model.blended_vertices]
        if getattr(model, "has_pose_basis", False):  # folded into M_P's mean or not
            moved.append(getattr(model, "pose_columns", None))
        if getattr(model, "pose_personal", None) is not None:
            moved.append(model.pose_personal.vertices)
        if getattr(model, "has_larynx", False):
            moved.append(model.larynx_vertices)
        if getattr(model, "flex", None) is not None:  # format 5: the flexion block
            moved.append(model.flex.vertices)
        if any(bool(torch.isin(index, m).any()) for m in moved if m is not None and len(m)):
            return None
        return cls(model, index)

    def __call__(self, beta: torch.Tensor, psi: torch.Tensor, theta: torch.Tensor,
                 global_orient: torch.Tensor, transl: torch.Tensor | None = None
                 ) -> torch.Tensor:
        """Posed subset vertices (B, n, 3). beta (1, s), one identity for the batch;
        psi (B, E); theta (B, 8, 3); global_orient (B, 3); transl (B, 3) or None."""
        m = self.model
        E, nb, B = m.num_expressions, beta.shape[1], psi.shape[0]
        shaped = torch.addmm(self.template[None], beta, self.basis[E:E + nb]) if nb \
            else self.template[None]
        rest = torch.addmm(shaped, psi, self.basis[:E]).view(B, -1, 3)
        if self.ep is not None:
            at, mean, rows, mlp = self.ep
            w, _ = mlp.weights(beta)        # (1, C); b2 exactly where it is constant
            personal = psi @ (mean + torch.matmul(w[0], rows))      # (B, 3m)
            rest = rest.index_add(1, at, personal.view(B, -1, 3))
        # the skull node's rigid transform (the model's _posing, without its blend)
        joints = m.rest_joints(beta).expand(B, -1, -1)
        nodes = torch.cat([joints[:, :1], joints], 1)
        rot = local_rotations(theta, global_orient)
        parents = chain_parents(m.parents)
        if is_path(parents):
            _, rel = path_transforms(rot, nodes)
        else:
            _, rel = rigid_transforms(rot, nodes, parents)
        A = rel[:, m.rigid_node, :3]                                  # (B, 3, 4)
        out = rest @ A[..., :3].transpose(1, 2) + A[:, None, :, 3]
        return out if transl is None else out + transl[:, None]
