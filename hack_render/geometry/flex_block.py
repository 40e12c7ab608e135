"""The flexion block (model format 5): a pose corrective keyed on the chain's net flexion.

The per-joint ``R - I`` correctives are linear in each joint's rotation; along a whole-head
nod those eight features are nearly collinear, so they cannot copy how skin folds under
the chin and stretches over the throat at a sane size (docs/model.md, "A corrective keyed
on the net flexion"). The block adds rest-space offsets on the neck's vertices

    d(beta, theta) = sum_h w_h(theta) (B_h0 + sum_s beta_s B_hs)

with ``phi`` the axis-angle of the chain's net rotation ``R_1 R_2 ... R_8`` (the head
against the thorax; the root's ``global_orient`` is not part of it) and

    w_h = max(0, 1 - |phi_x - k_h| / width) * exp(-(phi_y^2 + phi_z^2) / purity^2) * c^p

piecewise-linear hats over the net flexion angle (knots ``k_h``, none at 0, so the block
vanishes at rest) that fade out of combined rotations, and out of poses whose joints bend
against each other: c = |sum_k a_k| / sum_k |a_k| with a_k the x of joint k's axial vector
``(R_k - R_k^T) / 2`` (sin angle times the axis), 1 in a nod (every joint bending the same
way) and small where the joints alternate, to the power p (``flex_coherence``; 0: off). At most two hats are non-zero in
any pose, and only those rows of the basis are read. ``beta_s`` are the first S_f shape
weights (the others do not enter). Arrays: ``flex_vertices`` (M,), ``flex_basis``
(H, 1 + S_f, M, 3) metres, ``flex_knots_deg`` (H,), ``flex_width_deg`` (),
``flex_purity_deg`` (), ``flex_coherence`` () (:mod:`hack_render.geometry.model_file`).

This module is NumPy only (posing one mesh for a render runs without torch); the torch
side is :func:`hack_render.geometry.lbs.flex_weights` and
:class:`hack_render.geometry.products.FlexBlock`.
"""

from __future__ import annotations

import math

import numpy as np

from hack_render.geometry import np_rotations

#: the arrays of the block in a model file
KEYS = ("flex_vertices", "flex_basis", "flex_knots_deg", "flex_width_deg", "flex_purity_deg",
        "flex_coherence")


def flex_weights_np(theta: np.ndarray, knots_deg, width_deg: float,
                    purity_deg: float, coherence: float = 0.0) -> np.ndarray:
    """The hats' weights (T, H) of joint poses theta (T, K, 3) axis-angle (the root
    excluded), in NumPy (float64), as :func:`hack_render.geometry.lbs.flex_weights`."""
    theta = np.asarray(theta, np.float64)
    rot = np_rotations.axis_angle_to_matrix(theta.reshape(-1, *theta.shape[-2:]))
    net = rot[:, 0]
    for k in range(1, rot.shape[1]):
        net = net @ rot[:, k]
    phi = np_rotations.matrix_to_axis_angle(net)
    knots = np.deg2rad(np.asarray(knots_deg, np.float64))
    h = np.maximum(0.0, 1 - np.abs(phi[:, :1] - knots) / math.radians(width_deg))
    h = h * np.exp(-(phi[:, 1:] ** 2).sum(-1, keepdims=True) / math.radians(purity_deg) ** 2)
    if coherence:
        a = 0.5 * (rot[..., 2, 1] - rot[..., 1, 2])  # (T, K)
        h = h * ((np.abs(a.sum(-1)) / (np.abs(a).sum(-1) + 1e-9)) ** coherence)[:, None]
    return h


def flex_offsets_np(arrays, beta: np.ndarray, theta: np.ndarray) -> np.ndarray | None:
    """The block's offsets (M, 3) float32 on ``flex_vertices`` for one identity beta (S,)
    and one pose theta (K, 3) from a model file's arrays; None when no hat is active."""
    a = arrays
    w = flex_weights_np(theta[None], a["flex_knots_deg"], float(a["flex_width_deg"]),
                        float(a["flex_purity_deg"]), float(a["flex_coherence"]))[0]
    active = np.flatnonzero(w)
    if not len(active):
        return None
    basis = a["flex_basis"]
    s = min(len(beta), basis.shape[1] - 1)
    coef = np.concatenate([[1.0], np.asarray(beta, np.float64)[:s]]).astype(np.float32)
    rows = basis[active][:, :1 + s]  # (A, 1 + s, M, 3)
    x = (w[active, None] * coef[None]).astype(np.float32)
    return np.tensordot(x, rows, axes=([0, 1], [0, 1])).astype(np.float32)
