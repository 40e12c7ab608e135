"""Exact distances from points to a triangle mesh, found through a KD-tree.

:func:`point_to_mesh` gives each point's distance to the nearest point of a mesh's
surface: candidate triangles come from the ``k`` nearest of dense surface samples
(scipy's ``cKDTree``), then the exact point-triangle distance (Ericson, *Real-Time
Collision Detection*, 5.1.5) is taken over the candidates. With samples a fraction of the
triangle size apart the nearest triangle is always among the candidates.
"""

from __future__ import annotations

import numpy as np


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                               ) -> np.ndarray:
    """Closest points (M, 3) on triangles (a, b, c) (each (M, 3)) to points p (M, 3)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    safe = np.where(np.abs(denom) > 1e-30, denom, 1.0)
    v = vb / safe
    w = vc / safe
    out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
    # edges and vertices, from the least to the most specific region (later wins)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_bc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
        t_ac = np.clip(d2 / (d2 - d6), 0, 1)
        t_ab = np.clip(d1 / (d1 - d3), 0, 1)
    m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out[m] = (b + (c - b) * t_bc[:, None])[m]
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out[m] = (a + ac * t_ac[:, None])[m]
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out[m] = (a + ab * t_ab[:, None])[m]
    m = (d6 >= 0) & (d5 <= d6)
    out[m] = c[m]
    m = (d3 >= 0) & (d4 <= d3)
    out[m] = b[m]
    m = (d1 <= 0) & (d2 <= 0)
    out[m] = a[m]
    return out


class MeshDistance:
    """Nearest-surface queries on one triangle mesh (vertices (N, 3), faces (F, 3))."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, samples_per_face: int = 6,
                 seed: int = 0):
        from scipy.spatial import cKDTree

        self.v = np.asarray(vertices, np.float64)
        self.f = np.asarray(faces, np.int64)
        rng = np.random.default_rng(seed)
        n = samples_per_face
        r1, r2 = rng.random((len(self.f), n)), rng.random((len(self.f), n))
        s = np.sqrt(r1)
        w = np.stack([1 - s, s * (1 - r2), s * r2], -1)  # (F, n, 3)
        tri = self.v[self.f]  # (F, 3, 3)
        pts = np.einsum("fnk,fkc->fnc", w, tri).reshape(-1, 3)
        pts = np.concatenate([pts, tri.mean(1), self.v])
        owner = np.concatenate([np.repeat(np.arange(len(self.f)), n), np.arange(len(self.f)),
                                self._a_face_of_each_vertex()])
        self.owner = owner
        self.tree = cKDTree(pts)

    def _a_face_of_each_vertex(self) -> np.ndarray:
        out = np.zeros(len(self.v), np.int64)
        out[self.f.ravel()] = np.repeat(np.arange(len(self.f)), 3)
        return out

    def closest(self, points: np.ndarray, k: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distance (M,), closest point (M, 3), face (M,)) for each of ``points`` (M, 3)."""
        points = np.asarray(points, np.float64)
        _, idx = self.tree.query(points, k=k, workers=-1)
        faces = self.owner[idx]  # (M, k) candidate faces (repeats are harmless)
        best_d = np.full(len(points), np.inf)
        best_p = np.zeros_like(points)
        best_f = np.zeros(len(points), np.int64)
        for j in range(k):
            tri = self.f[faces[:, j]]
            q = closest_point_on_triangles(points, self.v[tri[:, 0]], self.v[tri[:, 1]],
                                           self.v[tri[:, 2]])
            d = np.linalg.norm(points - q, axis=1)
            better = d < best_d
            best_d[better], best_p[better], best_f[better] = d[better], q[better], faces[better, j]
        return best_d, best_p, best_f


def point_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) distance of each point to the mesh surface (same units as the inputs)."""
    return MeshDistance(vertices, faces).closest(points)[0]


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the triangles (a degenerate one: zero)."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def open_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) sorted vertex pairs of the edges used by one triangle only (holes, cuts)."""
    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    return uniq[count == 1]


def beyond_open_boundary(points: np.ndarray, closest: np.ndarray, face: np.ndarray,
                         vertices: np.ndarray, faces: np.ndarray, tol: float = 1e-6
                         ) -> np.ndarray:
    """(M,) bool: points beyond the mesh's edge (a hole's, a cut's): their closest points
    (``MeshDistance.closest``'s points and faces) lie on the open boundary (an edge of one
    triangle only, or a vertex of one) and the offset runs more along the surface than
    along its normal. The mesh does not cover such a point: its distance, to the edge, is
    not a measure of anything. (A point on the edge, or above it, is covered.)"""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    edges = open_edges(f)
    if not len(edges):
        return np.zeros(len(closest), bool)
    n = len(v)
    keys = np.sort(edges[:, 0] * n + edges[:, 1])
    rim = np.zeros(n, bool)
    rim[edges.ravel()] = True
    tri = f[face]
    a, b, c = (v[tri[:, k]] for k in range(3))
    e0, e1, q = b - a, c - a, np.asarray(closest, np.float64) - a
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (q * e0).sum(1), (q * e1).sum(1)
    den = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):
        wb = (d11 * d20 - d01 * d21) / den
        wc = (d00 * d21 - d01 * d20) / den
    bary = np.stack([1.0 - wb - wc, wb, wc], 1)  # weights of corners 0, 1, 2
    out = np.zeros(len(closest), bool)
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # edge opposite corner k
        lo, hi = np.minimum(tri[:, i], tri[:, j]), np.maximum(tri[:, i], tri[:, j])
        pos = np.searchsorted(keys, lo * n + hi)
        is_open = keys[np.minimum(pos, len(keys) - 1)] == lo * n + hi
        out |= (bary[:, k] < tol) & is_open
        out |= (bary[:, k] > 1.0 - tol) & rim[tri[:, k]]  # at an open corner
    normal = np.cross(e0, e1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    d = np.asarray(points, np.float64) - np.asarray(closest, np.float64)
    along = np.abs((d * normal).sum(1))
    return out & (np.linalg.norm(d - (d * normal).sum(1, keepdims=True) * normal, axis=1)
                  > along)


def beyond_point_cloud(query: np.ndarray, points: np.ndarray, normals: np.ndarray,
                       nearest: np.ndarray, spacing: float) -> np.ndarray:
    """(M,) bool: query points beyond a point cloud's edge: the offset to their nearest
    point ``nearest`` (indices) runs along the surface (its tangential part over twice
    the cloud's ``spacing``) rather than along the normal, as it does over the cloud."""
    d = np.asarray(query, np.float64) - points[nearest]
    n = normals[nearest]
    tangential = d - (d * n).sum(1, keepdims=True) * n
    return np.linalg.norm(tangential, axis=1) > 2.0 * spacing
