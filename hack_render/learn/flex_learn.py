"""Fitting the flexion block (model format 5, :mod:`hack_render.geometry.flex_block`) to
ARAP.

The block's offsets are the ridge least-squares fit, on whole-head flexion/extension poses
of sampled identities, of ARAP's rest-space residual over the model without the block:
the offsets that the model's own skinning carries onto ARAP's posed skin (ARAP with the
skin's rigid sets, as ``bench/bench_pose_arap.py``), linear in beta (hats x [1, beta]).
They are then applied at a fraction ``scale`` of that fit: the full fit folds skin past
the neck's active range and raises the expression's stretch, and the fraction was chosen
on validation pairs of their own (``bench/bench_flexion_block.py --scales``, docs/model.md
"Model version 8").
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from hack_render.geometry.deformation import skin_topology
from hack_render.geometry.lbs import chain_parents, flex_weights, local_rotations, rigid_transforms
from hack_render.geometry.model import HackModel
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.learn.pose_data import ArapNeck, pose_sequence

#: the block's defaults (those of model version 8)
STEP_DEG = 10.0
PURITY_DEG = 20.0
RIDGE = 1e-2
#: the power of the joints' flexion coherence (1 in the training nods: the fit is the same)
COHERENCE = 4.0
#: offsets below this (metres, every hat and term) are rounding: their vertices are left out
KEEP_M = 1e-7


def knots_deg(lo: float, hi: float, step: float = STEP_DEG) -> np.ndarray:
    """Knots every ``step`` degrees from ``lo`` to ``hi`` (on the grid through 0), 0 left out."""
    k = np.arange(-180.0, 180.0 + 1e-9, step)
    return k[(np.abs(k) > 1e-9) & (k >= lo - 1e-9) & (k <= hi + 1e-9)]


def training_poses() -> torch.Tensor:
    """The 35 whole-head flexion/extension poses (-70 to 66 degrees, float64) the block is
    fitted on."""
    angles = torch.deg2rad(torch.linspace(-70, 66, 35, dtype=torch.float64))
    return distribute_head_rotation(torch.stack([angles, 0 * angles, 0 * angles], -1))


class ArapResidual:
    """ARAP's rest-space offsets over a model's own posed skin (a float64 model without
    the block), per identity."""

    def __init__(self, model: HackModel):
        self.model = model
        self.topo = skin_topology(model)
        self.w = model.skinning_weights.double()
        self.rigid = self.w.max(1).values >= 1 - 1e-6
        self.vertices = torch.unique(self.topo.faces.reshape(-1))  # the block's vertices

    def __call__(self, beta: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
        """(P, M * 3) for one identity beta (S,) and poses theta (P, K, 3)."""
        person = self.model.personalize(beta[None])
        with torch.no_grad():
            rest = person().vertices[0]
            posed = person(theta=theta).vertices
        joints = person.joints.double()
        j = joints.expand(len(theta), -1, -1)
        rot = local_rotations(theta, theta.new_zeros(len(theta), 3))
        _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1),
                                  chain_parents(self.model.parents))
        blend = torch.einsum("vk,pkij->pvij", self.w, rel)
        neck = ArapNeck(rest.numpy(), self.topo.faces.numpy(), self.rigid.numpy())
        arap = pose_sequence(rest, joints.reshape(-1, 3), self.w, self.model.parents, theta,
                             "arap", neck, 30)

        def to_rest(x):
            return torch.linalg.solve(blend[..., :3, :3], (x - blend[..., :3, 3])[..., None])[..., 0]

        d = to_rest(arap) - to_rest(posed)
        return d[:, self.vertices].reshape(len(d), -1)


def fit_flex_block(arrays: dict[str, np.ndarray], knots: np.ndarray, scale: float,
                   identities: int = 40, seed: int = 777, terms: int = 20,
                   step: float = STEP_DEG, purity: float = PURITY_DEG, ridge: float = RIDGE,
                   coherence: float = COHERENCE,
                   report: Callable[[str], None] | None = None) -> dict[str, np.ndarray]:
    """The format-5 arrays of a block fitted for the model ``arrays`` (which must carry
    none) on ``identities`` identities beta ~ N(0, I) (``terms`` shape weights, seed
    ``seed``) x :func:`training_poses`, applied at ``scale`` of the fit."""
    model = HackModel(arrays).double()
    res = ArapResidual(model)
    theta = training_poses()
    rot = local_rotations(theta, theta.new_zeros(len(theta), 3))[:, 1:]
    h = flex_weights(rot, torch.deg2rad(torch.as_tensor(knots, dtype=torch.float64)),
                     math.radians(step), math.radians(purity), coherence)  # (P, H)
    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(identities, terms, generator=g, dtype=torch.float64)
    x, y = [], []
    for i, b in enumerate(betas):
        z = torch.cat([torch.ones(1, dtype=b.dtype), b])
        x.append((h[:, :, None] * z).reshape(len(h), -1))
        y.append(res(b, theta))
        if report is not None:
            report(f"ARAP on identity {i + 1}/{identities}")
    x, y = torch.cat(x), torch.cat(y)
    coef = torch.linalg.solve(x.T @ x + ridge * torch.eye(x.shape[1], dtype=x.dtype), x.T @ y)
    basis = scale * coef.reshape(len(knots), terms + 1, len(res.vertices), 3)
    # the skin's vertices that the block moves (ARAP leaves the rigid ones where the model
    # puts them: their offsets are zero to rounding, and are not stored)
    keep = basis.abs().amax(dim=(0, 1, 3)) > KEEP_M
    return {"flex_vertices": res.vertices[keep].numpy().astype(np.int32),
            "flex_basis": basis[:, :, keep].numpy().astype(np.float32),
            "flex_knots_deg": np.asarray(knots, np.float32),
            "flex_width_deg": np.asarray(step, np.float32),
            "flex_purity_deg": np.asarray(purity, np.float32),
            "flex_coherence": np.asarray(coherence, np.float32)}
