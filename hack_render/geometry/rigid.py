"""Rigid alignment of point sets in NumPy (no torch): the rotation and translation that
carry one set onto another in the least-squares sense (Kabsch)."""

from __future__ import annotations

import numpy as np


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (3, 3) and translation t (3,) with dst ~ src @ R.T + t (least squares).

    Args:
        src, dst: (n, 3) corresponding points, n >= 3 not all on a line. R is a proper
            rotation (det +1, never a reflection).
    """
    a, b = src.mean(0), dst.mean(0)
    u, _, vt = np.linalg.svd((src - a).T @ (dst - b))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, b - r @ a
