"""Vertex normals of a triangle mesh (NumPy), shared by the renderer and the hair layer, and
the 3-vector products they are made of (:func:`cross3`, :func:`norm3`); the mesh's open cuts
(:func:`open_boundary`: the fit's contour, scan registration, the pose learner).

``cross3`` and ``norm3`` give the same bits as ``np.cross`` and ``np.linalg.norm(x,
axis=-1)`` (the same products and sums in the same order: the hair's grooms are compared
array by array, ``tests/test_nearest.py``) in a fraction of the time on (..., 3) arrays:
``np.cross`` moves the axes and copies both inputs, and the norm's reduction over an axis
of three pays a general reduction's set-up on every row."""

from __future__ import annotations

import numpy as np


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (..., 3) arrays (broadcast), float64 for float64 inputs."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def norm3(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1, keepdims=keepdims)`` of a (..., 3) array."""
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    n = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    return n[..., None] if keepdims else n


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals. vertices (N, 3), faces (F, 3) -> (N, 3)."""
    v = vertices[faces]
    fn = cross3(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    idx = faces.ravel()
    # bincount is the fast scatter-add (np.add.at is several times slower)
    n = np.stack([np.bincount(idx, np.repeat(fn[:, c], 3), minlength=len(vertices))
                  for c in range(3)], axis=1)
    length = norm3(n, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def open_boundary(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertices on an edge used by one triangle only (a mesh's open cuts:
    the default model's bust and back, the lips' and eyelids' rims)."""
    f = np.asarray(faces)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    out = np.zeros(n, bool)
    out[uniq[count == 1].ravel()] = True
    return out
