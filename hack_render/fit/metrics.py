"""Accuracy measures of a fit against known truth (bench/bench_fit.py and the tests)."""

from __future__ import annotations

import numpy as np


def similarity_error(x: np.ndarray, y: np.ndarray) -> float:
    """Mean distance between points y (N, 3) and x (N, 3) after the best similarity
    transform (scale, rotation, translation) of x onto y (Umeyama 1991)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    U, S, Vt = np.linalg.svd(yc.T @ xc)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1, 1, d])
    R = U @ D @ Vt
    s = (S * np.diag(D)).sum() / (xc ** 2).sum()
    return float(np.linalg.norm(s * xc @ R.T - yc, axis=1).mean())
