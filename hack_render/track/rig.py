"""The tracker's landmark rig: the 68 landmark points of one identity as a closed-form
function of the per-frame parameters, for fast per-frame solves.

Every vertex the landmark embedding reads moves rigidly with the skull (node o-c1: no
pose corrective, no larynx, no blend between joints on the face; :meth:`LandmarkRig.build`
checks it), so for a fixed identity (beta, eta) the posed landmarks are

    X(psi, h, g, t) = A(h, g) [L0 + sum_e psi_e D_e] + a(h, g) + t

with ``L0`` the rest landmarks, ``D_e`` the rest displacement of expression e (the
generic and the identity's personalised expression shapes: both linear in psi, checked
when built), ``A, a`` the skull's rigid transform from the head rotation ``h`` (shared
over the 8 joints by :func:`~hack_render.geometry.skeleton.distribute_head_rotation`)
and the torso rotation ``g``, and ``t`` the model's translation. The test suite checks
the rig against the full model forward.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hack_render.errors import HackError
from hack_render.fit.landmark_embedding import embedded_points
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
from hack_render.geometry.skeleton import distribute_head_rotation


@dataclass
class LandmarkRig:
    """Rest landmarks ``L0`` (68, 3), expression displacements ``D`` (E, 68, 3), the
    identity's rest joints (1, 8, 3), the chain's parents and the skull's node."""

    L0: torch.Tensor
    D: torch.Tensor
    rest_joints: torch.Tensor
    parents: tuple[int, ...]
    node: int

    @classmethod
    def build(cls, model, beta: torch.Tensor, embedding=None) -> LandmarkRig:
        """The rig of ``model`` at identity ``beta`` (1, S); the 68 points are the landmark
        embedding's (``embedding``, a :class:`~hack_render.fit.landmark_embedding.
        LandmarkEmbedding`) or, without one, the model's landmark vertices."""
        ids = (torch.as_tensor(embedding.vertex_ids).reshape(-1) if embedding is not None
               else model.landmark_indices)
        used = set(ids.tolist())
        if used & set(model.blended_vertices.tolist()) or model.rigid_node != model.num_joints:
            raise HackError("track: this model's landmark vertices do not move rigidly with "
                            "the skull; the tracker's closed-form rig does not apply.")
        for name in ("pose_columns", "larynx_vertices"):
            if hasattr(model, name) and used & set(getattr(model, name).tolist()):
                raise HackError(f"track: landmark vertices carry {name}; the tracker's "
                                "closed-form rig does not apply.")
        E = model.num_expressions
        psi = torch.cat([torch.zeros(1, E), torch.eye(E)], 0)
        with torch.no_grad():
            rest = model(beta=beta.detach(), psi=psi).rest_vertices.double()
        pts = landmark_points(rest, embedding, model)
        L0, D = pts[0], pts[1:] - pts[:1]
        # psi enters linearly: a combination of two shapes equals the sum of their deltas
        with torch.no_grad():
            mix = torch.zeros(1, E)
            mix[0, : min(E, 3)] = torch.tensor([0.7, 0.4, 0.9][: min(E, 3)])
            got = landmark_points(model(beta=beta.detach(), psi=mix).rest_vertices.double(),
                                  embedding, model)[0]
        want = L0 + torch.einsum("e,elc->lc", mix[0].double(), D)
        if float((got - want).abs().max()) > 1e-5:
            raise HackError("track: the model's expressions are not linear in psi at the "
                            "landmarks; the tracker's closed-form rig does not apply.")
        with torch.no_grad():
            joints = model.rest_joints(beta.detach()).double()
        return cls(L0, D, joints, chain_parents(model.parents), model.rigid_node)

    def skull(self, h: torch.Tensor, g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The skull's rigid transform (A (T, 3, 3), a (T, 3)) for head rotations ``h``
        (T, 3: flexion, axial, lateral, radians) and torso rotations ``g`` (T, 3)."""
        theta = distribute_head_rotation(h, clamp=False)
        rot = local_rotations(theta, g)
        joints = self.rest_joints.expand(h.shape[0], -1, -1)
        nodes = torch.cat([joints[:, :1], joints], 1)
        _, rel = rigid_transforms(rot, nodes, self.parents)
        a = rel[:, self.node]
        return a[:, :3, :3], a[:, :3, 3]

    def points(self, psi: torch.Tensor, h: torch.Tensor, g: torch.Tensor,
               t: torch.Tensor) -> torch.Tensor:
        """Posed landmarks (T, 68, 3) in metres, the model's world frame."""
        rest = self.L0 + torch.einsum("te,elc->tlc", psi, self.D)
        hg = torch.cat([h, g], 1)
        if len(hg) > 8 and not hg.requires_grad:  # a finite-difference batch
            # (solve._frame_lm, no autograd): most rows move only psi or t and share the
            # skull's transform, made once per distinct (h, g): 7 of 63 rows, 0.8 ms
            # instead of 1.4 ms a batch on the 2-core test host
            uniq, inv = torch.unique(hg, dim=0, return_inverse=True)
            if len(uniq) < len(hg):
                A, a = self.skull(uniq[:, :3], uniq[:, 3:])
                return rest @ A[inv].transpose(1, 2) + (a[inv] + t)[:, None]
        A, a = self.skull(h, g)
        return rest @ A.transpose(1, 2) + (a + t)[:, None]


def landmark_points(vertices: torch.Tensor, embedding, model) -> torch.Tensor:
    """The model's 68 landmarks (B, 68, 3) on ``vertices`` (B, N, 3): by the landmark
    embedding's barycentric points, or the model's landmark vertices without one."""
    if embedding is None:
        return vertices[:, model.landmark_indices]

    return embedded_points(vertices, torch.as_tensor(embedding.vertex_ids),
                           torch.as_tensor(embedding.bary))
