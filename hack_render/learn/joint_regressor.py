"""Joint-regressor trainer (paper Eq. 6): J from (mesh, joint) pairs.

E_joint = sum_i || J V_i - j_i ||^2 over training meshes V_i (N, 3) with labelled joints j_i
(K, 3), e.g. from ultrasound or CT. Each row of J is non-negative over a candidate ring of
vertices (those within ``slab`` of the joint's mean height) and sums to one (translation
equivariance); the problem is a bounded least squares per joint (scipy's BVLS), with a small
ridge that spreads weight over the ring so J follows the whole cross-section.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from hack_render.errors import HackError


def train_joint_regressor(meshes: np.ndarray, joints: np.ndarray, candidates: np.ndarray | None = None,
                          slab: float = 0.012, smooth: float = 0.05) -> np.ndarray:
    """Fit J (K, N).

    Args:
        meshes: (P, N, 3) rest-pose training meshes, metres.
        joints: (P, K, 3) their labelled joint positions.
        candidates: vertex indices allowed in J (default: all).
        slab: half-height (metres) of each joint's candidate ring around its mean height.
        smooth: ridge weight (relative, as in skeleton_fit.affine_regressor).
    """
    meshes, joints = np.asarray(meshes, np.float64), np.asarray(joints, np.float64)
    if meshes.ndim != 3 or joints.ndim != 3 or meshes.shape[0] != joints.shape[0] or meshes.shape[2] != 3:
        raise HackError(f"joint regressor: expected meshes (P, N, 3) and joints (P, K, 3) with the "
                        f"same P, found {meshes.shape} and {joints.shape}.")
    p, n = meshes.shape[:2]
    cand = np.arange(n) if candidates is None else np.asarray(candidates)
    mean_mesh = meshes.mean(0)
    reg = np.zeros((joints.shape[1], n))
    for k in range(joints.shape[1]):
        jy = joints[:, k, 1].mean()
        ring = cand[np.abs(mean_mesh[cand, 1] - jy) < slab]
        if len(ring) < 3:
            raise HackError(f"joint regressor: joint {k} has only {len(ring)} candidate vertices "
                            f"within {slab} m of its height; widen --slab.")
        a = np.vstack([meshes[:, ring].transpose(0, 2, 1).reshape(p * 3, len(ring)) * 100.0,
                       np.full((1, len(ring)), 10.0 * np.sqrt(p)), smooth * np.sqrt(p) * np.eye(len(ring))])
        b = np.concatenate([joints[:, k].reshape(-1) * 100.0, [10.0 * np.sqrt(p)], np.zeros(len(ring))])
        w = lsq_linear(a, b, bounds=(0, 1), method="bvls").x
        if w.sum() <= 0:
            raise HackError(f"joint regressor: joint {k} got all-zero weights; check the labels.")
        reg[k, ring] = w / w.sum()
    return reg


def joint_errors(reg: np.ndarray, meshes: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Per-mesh, per-joint Euclidean error (P, K) in metres of J applied to meshes."""
    return np.linalg.norm(np.einsum("kn,pnc->pkc", reg, meshes) - joints, axis=-1)
