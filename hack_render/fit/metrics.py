"""Accuracy measures of a fit against known truth (bench/bench_fit.py and the tests)."""

from __future__ import annotations

import numpy as np


def similarity_transform(x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t), the similarity (scale, rotation, translation) with s R x + t nearest to
    y in least squares, for points x, y (N, d), d = 2 or 3 (Umeyama 1991; no reflection)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    U, S, Vt = np.linalg.svd(yc.T @ xc)
    D = np.eye(x.shape[1])
    D[-1, -1] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = U @ D @ Vt
    s = float((S * np.diag(D)).sum() / max((xc ** 2).sum(), 1e-300))
    return s, R, my - s * R @ mx


def similarity_error(x: np.ndarray, y: np.ndarray) -> float:
    """Mean distance between points y (N, 3) and x (N, 3) after the best similarity
    transform (scale, rotation, translation) of x onto y (Umeyama 1991)."""
    s, R, t = similarity_transform(x, y)
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.linalg.norm(s * x @ R.T + t - y, axis=1).mean())
