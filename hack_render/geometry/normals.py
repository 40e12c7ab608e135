"""Vertex normals of a triangle mesh (NumPy), shared by the renderer and the hair layer."""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals. vertices (N, 3), faces (F, 3) -> (N, 3)."""
    v = vertices[faces]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    idx = faces.ravel()
    # bincount is the fast scatter-add (np.add.at is several times slower)
    n = np.stack([np.bincount(idx, np.repeat(fn[:, c], 3), minlength=len(vertices))
                  for c in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)
