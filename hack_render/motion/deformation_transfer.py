"""Deformation transfer (Sumner & Popovic 2004) between meshes of one topology.

Source deformation gradients use Sumner's fourth vertex, ``v4 = v1 + n / sqrt(|n|)`` with
``n = e1 x e2``: per triangle S_t = V~ V^-1, V = [e1, e2, e4] (3 x 3). The target's deformed
vertices x minimise the area-weighted deformation-gradient mismatch

    sum_t a_t || (X_t - S_t E_t) E_t^+ ||_F^2,   X_t = [x2 - x1, x3 - x1], E_t the target's
                                                   rest edges (3 x 2), E^+ its pseudo-inverse

which is a Poisson system (the cotangent Laplacian of the target's rest mesh) in the free
vertices, with the other vertices held at the target's rest positions. The matrix depends only
on the target's rest mesh: :class:`TargetSolver` factorises it once per identity and solves
for every expression (all right-hand sides at once).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from hack_render.errors import HackError


def source_gradients(rest: np.ndarray, deformed: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-triangle deformation gradients (T, 3, 3) of rest -> deformed (Sumner's 4th vertex)."""
    def frame(x):
        e1 = x[faces[:, 1]] - x[faces[:, 0]]
        e2 = x[faces[:, 2]] - x[faces[:, 0]]
        n = np.cross(e1, e2)
        e4 = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30))
        return np.stack([e1, e2, e4], -1)  # (T, 3, 3), columns

    v, vt = frame(rest), frame(deformed)
    return vt @ np.linalg.inv(v)


class TargetSolver:
    """One target rest mesh: the factorised Poisson system of deformation transfer.

    Args:
        rest: (N, 3) target rest vertices.
        faces: (T, 3) triangles (the deformed part; other triangles may be left out).
        free: boolean (N,) vertices solved for; the rest stay at their rest positions.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, free: np.ndarray):
        n = len(rest)
        self.rest, self.faces = rest.astype(np.float64), faces
        self.free = np.flatnonzero(free)
        self.fixed = np.flatnonzero(~free)
        if len(self.free) == 0:
            raise HackError("deformation transfer: no free vertices to solve for.")
        e1 = self.rest[faces[:, 1]] - self.rest[faces[:, 0]]
        e2 = self.rest[faces[:, 2]] - self.rest[faces[:, 0]]
        self.edges = np.stack([e1, e2], -1)  # (T, 3, 2)
        gram = np.einsum("tki,tkj->tij", self.edges, self.edges)  # E^T E (T, 2, 2)
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
        if (area <= 1e-16).any():
            keep = area > 1e-16
            faces, self.edges, gram, area = faces[keep], self.edges[keep], gram[keep], area[keep]
            self.faces = faces
        self.weight = area[:, None, None] * np.linalg.inv(gram)  # (T, 2, 2)
        t = len(faces)
        # D: (2T, N) rows e1 = x2 - x1, e2 = x3 - x1.
        rows = np.repeat(np.arange(2 * t), 2)
        cols = np.stack([faces[:, 1], faces[:, 0], faces[:, 2], faces[:, 0]], 1).ravel()
        vals = np.tile([1.0, -1.0], 2 * t)
        self.d = sparse.csr_matrix((vals, (rows, cols)), shape=(2 * t, n))
        self.w = _block_diag(self.weight)
        dtw = self.d.T @ self.w
        self.dtw_f = dtw[self.free]
        k = (dtw @ self.d).tocsr()
        self.k_fc = k[self.free][:, self.fixed]
        self.lu = splu(k[self.free][:, self.free].tocsc())

    def transfer(self, gradients: np.ndarray) -> np.ndarray:
        """Deformed target vertices (E, N, 3) for source gradients (E, T, 3, 3)."""
        g = np.asarray(gradients)
        e = g.shape[0]
        target_edges = g @ self.edges[None]  # (E, T, 3, 2): S_t E_t
        b = target_edges.transpose(1, 3, 0, 2).reshape(2 * len(self.faces), e * 3)  # rows e1,e2 per t
        rhs = self.dtw_f @ b - self.k_fc @ np.tile(self.rest[self.fixed], (1, e))
        rhs = np.asarray(rhs)
        # One right-hand side at a time: SuperLU's multi-column solve is several times slower.
        x = np.stack([self.lu.solve(rhs[:, i]) for i in range(rhs.shape[1])], 1)  # (F, E*3)
        out = np.broadcast_to(self.rest, (e,) + self.rest.shape).copy()
        out[:, self.free] = x.reshape(len(self.free), e, 3).transpose(1, 0, 2)
        return out


def _block_diag(blocks: np.ndarray) -> sparse.csr_matrix:
    """Block-diagonal sparse matrix of (T, 2, 2) blocks, vectorised."""
    t = len(blocks)
    base = 2 * np.arange(t)
    rows = np.stack([base, base, base + 1, base + 1], 1).ravel()
    cols = np.stack([base, base + 1, base, base + 1], 1).ravel()
    return sparse.csr_matrix((blocks.reshape(t, 4).ravel(), (rows, cols)), shape=(2 * t, 2 * t))
