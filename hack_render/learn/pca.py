"""PCA helpers shared by the learners: fit, compactness and held-out generalisation curves.

All functions take samples as rows of a (n, D) float array (D may be large: the fit uses the
n x n Gram matrix, so memory is O(n D) for the data and O(n^2) extra).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError


@dataclass
class PCA:
    """mean (D,), components (C, D) orthonormal rows, std (C,) per-component std,
    variance_ratio (n-1,) explained variance ratio of every component the data has."""

    mean: np.ndarray
    components: np.ndarray
    std: np.ndarray
    variance_ratio: np.ndarray

    def project(self, x: np.ndarray, k: int | None = None) -> np.ndarray:
        """Weights (n, k) of samples x (n, D) on the first k components."""
        c = self.components[:k]
        return (x - self.mean) @ c.T

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        """Samples (n, D) from weights (n, k)."""
        return self.mean + w @ self.components[: w.shape[1]]


def fit_pca(x: np.ndarray, num_components: int | None = None) -> PCA:
    """PCA of samples x (n, D) via the Gram matrix (exact for n << D).

    Raises:
        HackError: with fewer than 2 samples or non-finite values.
    """
    x = np.asarray(x)
    if x.ndim != 2 or x.shape[0] < 2:
        raise HackError(f"PCA: expected at least 2 samples as rows of a 2-D array, found shape {x.shape}.")
    if not np.isfinite(x).all():
        raise HackError("PCA: the samples contain NaN or inf values.")
    mean = x.mean(0)
    xc = (x - mean).astype(np.float64)
    gram = xc @ xc.T
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1]
    evals, evecs = np.clip(evals[order], 0, None), evecs[:, order]
    keep = evals > evals[0] * 1e-12 if evals[0] > 0 else np.zeros(len(evals), bool)
    evals, evecs = evals[keep], evecs[:, keep]
    comps = (evecs.T @ xc) / np.sqrt(evals)[:, None]
    ratio = evals / evals.sum() if evals.sum() > 0 else evals
    c = len(evals) if num_components is None else min(num_components, len(evals))
    std = np.sqrt(evals / max(len(x) - 1, 1))
    return PCA(mean=mean.astype(np.float32), components=comps[:c].astype(np.float32),
               std=std[:c].astype(np.float32), variance_ratio=ratio)


def compactness(pca: PCA) -> np.ndarray:
    """Cumulative explained variance ratio (C,) against the number of components 1..C."""
    return np.cumsum(pca.variance_ratio)


def generalisation(train: np.ndarray, test: np.ndarray, ks: list[int], points: int = 3) -> dict:
    """Held-out error against the number of components (paper Fig. 11).

    Args:
        train: (n, D) training samples; test: (m, D) held-out samples; ``points`` coordinates
            per point (3 for xyz displacements) so the RMSE is per point, in the samples' unit.
    Returns:
        {"k": ks, "rmse_mean": [...], "rmse_std": [...]} over the held-out samples.
    """
    pca = fit_pca(train)
    out = {"k": [], "rmse_mean": [], "rmse_std": []}
    for k in ks:
        k = min(k, len(pca.components))
        rec = pca.reconstruct(pca.project(test, k))
        err = ((rec - test) ** 2).reshape(len(test), -1, points).sum(-1).mean(-1) ** 0.5
        out["k"].append(int(k))
        out["rmse_mean"].append(float(err.mean()))
        out["rmse_std"].append(float(err.std()))
    return out
