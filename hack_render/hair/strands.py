"""Geometry the hair's growing and posing share: triangle frames and root points, the
skin's collision proxy (:class:`BodyProxy`: the signed distance to the nearest skin
vertex's tangent plane), points sampled on and snapped to triangles, the open edges of a
mesh, and strands cut at a floor and resampled along their length.

Split from :mod:`hack_render.hair.groom` (its growth steps use these; so do
:mod:`hack_render.hair.pose` and :mod:`hack_render.export.hair_cards`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.geometry.nearest import PointTree
from hack_render.geometry.normals import cross3, norm3
from hack_render.hair.regions import HeadSurface


def triangle_frames(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3, 3) orthonormal frames of triangles: rows e1 (first edge), e2, n (normal)."""
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    e1 = b - a
    n = cross3(e1, c - a)
    e1 = e1 / np.maximum(norm3(e1, keepdims=True), 1e-20)
    n = n / np.maximum(norm3(n, keepdims=True), 1e-20)
    return np.stack([e1, cross3(n, e1), n], axis=-2)


def root_points(v: np.ndarray, faces: np.ndarray, tri: np.ndarray, bary: np.ndarray
                ) -> np.ndarray:
    return np.einsum("sk,skc->sc", bary, v[faces[tri]])


def unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(norm3(x, keepdims=True), 1e-12)


def tangent(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    return unit(d - np.sum(d * n, -1, keepdims=True) * n)


class BodyProxy:
    """Signed distance to the skin, approximated by the nearest skin vertex's tangent plane
    (positive outside). Used to grow strands outside the body and to test them."""

    def __init__(self, v: np.ndarray, faces: np.ndarray, skin: np.ndarray,
                 _parts: tuple | None = None):
        if _parts is None:
            surface = HeadSurface(v, faces, skin, np.zeros(0, np.int64))
            _parts = surface.skin_vertices, surface.skin_normals, surface.skin_tree
        self.index, normals, self.tree = _parts
        self.points = v[self.index]
        self.normals = normals[self.index]

    @staticmethod
    def of(surface: HeadSurface) -> BodyProxy:
        """The proxy of ``surface``'s skin, from its arrays made once
        (:class:`~hack_render.hair.regions.HeadSurface`): the same as
        ``BodyProxy(surface.vertices, surface.faces, surface.skin)``."""
        return BodyProxy(surface.vertices, surface.faces, surface.skin,
                         (surface.skin_vertices, surface.skin_normals, surface.skin_tree))

    def nearest(self, p: np.ndarray, bound: float = np.inf, index: bool = False):
        """(signed distance (...,), outward normal (..., 3)) at points ``p`` (..., 3);
        a point farther than ``bound`` from every skin vertex: +inf and a zero normal.
        ``index``: also the nearest skin vertex (..., into :attr:`index`; -1 beyond
        ``bound``)."""
        flat = p.reshape(-1, 3)
        dist, i = self.tree.query(flat, distance_upper_bound=bound)
        far = ~np.isfinite(dist)
        i = np.where(far, 0, i)
        n = np.where(far[:, None], 0.0, self.normals[i])
        d = np.where(far, np.inf, np.sum((flat - self.points[i]) * n, -1))
        out = d.reshape(p.shape[:-1]), n.reshape(p.shape)
        return out + (np.where(far, -1, i).reshape(p.shape[:-1]),) if index else out

    def push_out(self, p: np.ndarray, shell, bound: float = np.inf, index: bool = False):
        """``p`` moved along the nearest normal to at least ``shell`` (metres, broadcast)
        outside the skin. ``bound``: points farther than that from every skin vertex are
        outside (their k-d tree search stops there): what a caller may say of points at
        most a step from points outside the skin (:func:`_walk`). ``index``: also
        :class:`Nearest`, each point's nearest skin vertex where the point did not move
        (:func:`_group` takes it as the anchor instead of searching again)."""
        d, n, i = self.nearest(p, bound, index=True)
        lack = np.maximum(np.asarray(shell) - d, 0.0)
        out = p + lack[..., None] * n
        if not index:
            return out
        return out, Nearest(out, np.where(lack > 0, -1, i), self)


@dataclass
class Nearest:
    """Points (..., 3) and each one's nearest skin vertex (..., into ``proxy.index``; -1:
    not known), as a :class:`BodyProxy` query found them: a later search for the same
    points (:func:`_group`'s anchors) takes these instead (the same tree and points: the
    same answer)."""

    points: np.ndarray
    index: np.ndarray
    proxy: BodyProxy


def sample_triangles(v: np.ndarray, faces: np.ndarray, candidates: np.ndarray, count: int,
                     rng: np.random.Generator, weight: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """``count`` area-uniform random points on ``candidates`` (face indices), each as
    (face index, barycentric (3,)); ``weight`` (per candidate, 0..1) thins them."""
    if count <= 0 or len(candidates) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    t = v[faces[candidates]]
    area = 0.5 * norm3(cross3(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))
    p = area * (weight if weight is not None else 1.0)
    if p.sum() <= 0:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    pick = rng.choice(len(candidates), size=count, p=p / p.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], -1)
    return candidates[pick], bary


def closest_on_triangles(v: np.ndarray, faces: np.ndarray, candidates: np.ndarray,
                         points: np.ndarray, tree: PointTree | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """For each point (P, 3), the nearest of ``candidates``' triangles by centroid among
    the 8 nearest, and the point's barycentric coordinates in it (clamped inside).
    ``tree``: a k-d tree over the candidates' centroids, if one is at hand."""
    tree = tree if tree is not None else PointTree(v[faces[candidates]].mean(1))
    _, near = tree.query(points, k=min(8, len(candidates)))
    near = np.atleast_2d(near)
    best_t, best_b, best_d = None, None, None
    for j in range(near.shape[1]):
        tri = candidates[near[:, j]]
        a, b, c = (v[faces[tri, k]] for k in range(3))
        bary = barycentric(points, a, b, c)
        q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
        dist = norm3(q - points)
        if best_d is None:
            best_t, best_b, best_d = tri.copy(), bary, dist
        else:
            better = dist < best_d
            best_t[better], best_b[better], best_d[better] = tri[better], bary[better], \
                dist[better]
    return best_t, best_b


def barycentric(p, a, b, c) -> np.ndarray:
    """Barycentric coordinates of ``p``'s projection on each triangle, clamped to it."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(-1), (v0 * v1).sum(-1), (v1 * v1).sum(-1)
    d20, d21 = (v2 * v0).sum(-1), (v2 * v1).sum(-1)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-30)
    y = (d11 * d20 - d01 * d21) / den
    z = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.stack([1 - y - z, y, z], -1), 0, None)
    return bary / bary.sum(-1, keepdims=True)


def polyline_distance(p2: np.ndarray, line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance, arc parameter 0..1) of 2-D points to a polyline (L, 2)."""
    seg = np.diff(line, axis=0)
    lengths = np.linalg.norm(seg, axis=-1)
    cum = np.r_[0.0, np.cumsum(lengths)]
    best_d = np.full(len(p2), np.inf)
    best_s = np.zeros(len(p2))
    for i in range(len(seg)):
        t = np.clip(((p2 - line[i]) @ seg[i]) / max(lengths[i] ** 2, 1e-20), 0, 1)
        d = np.linalg.norm(p2 - (line[i] + t[:, None] * seg[i]), axis=-1)
        better = d < best_d
        best_d[better] = d[better]
        best_s[better] = (cum[i] + t[better] * lengths[i]) / cum[-1]
    return best_d, best_s


def open_edge_vertices(faces: np.ndarray) -> np.ndarray:
    """Vertices on the open boundary of a triangle mesh (edges of one triangle): the bust's
    cut, the mouth's and eyes' openings. A point whose nearest skin vertex is one of them
    lies beyond the surface's edge, not inside it. (Each edge as one integer key, its
    vertices sorted: a 1-D unique, several times faster than the rows' own.)"""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    if len(e) == 0:
        return np.zeros(0, faces.dtype)
    n = np.int64(e.max()) + 1
    key = e[:, 0].astype(np.int64) * n + e[:, 1]
    uniq, count = np.unique(key, return_counts=True)
    once = uniq[count == 1]
    return np.unique(np.concatenate([once // n, once % n])).astype(faces.dtype, copy=False)


def cut_strands(pts: np.ndarray, floor: float) -> np.ndarray:
    """Strands cut where they first go below ``floor`` (y), their K points spread evenly
    (by arc length) over the part kept, so no segment has zero length. Vectorised over
    the strands that keep the same number of points (a long groom cuts ~13k strands)."""
    k = pts.shape[1]
    below = pts[..., 1] < floor
    cut = below.any(1)
    if not cut.any():
        return pts
    out = pts.copy()
    rows = np.flatnonzero(cut)
    first = np.argmax(below[rows], 1)
    for m in np.unique(np.maximum(first, 1) + 1):  # the points each strand keeps
        sel = np.maximum(first, 1) + 1 == m
        i, f = rows[sel], first[sel]
        keep = pts[i, :m].copy()
        on = f >= 1  # end on the floor, between the last point above and the first below
        a, b = pts[i[on], f[on] - 1], pts[i[on], f[on]]
        t = (a[:, 1] - floor) / np.maximum(a[:, 1] - b[:, 1], 1e-12)
        keep[on, -1] = a + t[:, None] * (b - a)
        arc = np.concatenate([np.zeros((len(i), 1)), np.cumsum(
            norm3(np.diff(keep, axis=1)), 1)], 1)
        stub = arc[:, -1] <= 1e-6  # rooted at the floor itself: a short stub along it
        if stub.any():
            d = pts[i[stub], 1] - pts[i[stub], 0]
            d = d / np.maximum(norm3(d, keepdims=True), 1e-12) * 1e-3
            keep[stub] = pts[i[stub], :1]
            keep[stub, -1] = pts[i[stub], 0] + d
            arc[stub] = 0.0
            arc[stub, -1] = 1e-3
        out[i] = resample_strands(keep, arc, k)
    return out


def resample_strands(keep: np.ndarray, arc: np.ndarray, k: int) -> np.ndarray:
    """(n, k, 3) points at ``k`` even arc lengths along polylines ``keep`` (n, m, 3) with
    cumulative arc lengths ``arc`` (n, m), as ``np.interp`` per coordinate: the segment
    whose start is the last at or before each length (the end itself: the last point)."""
    m = arc.shape[1]
    at = np.linspace(0.0, 1.0, k)[None] * arc[:, -1:]
    j = np.clip((arc[:, None, :] <= at[:, :, None]).sum(-1) - 1, 0, m - 2)
    a0 = np.take_along_axis(arc, j, 1)
    a1 = np.take_along_axis(arc, j + 1, 1)
    p0 = np.take_along_axis(keep, j[..., None], 1)
    p1 = np.take_along_axis(keep, j[..., None] + 1, 1)
    span = a1 - a0
    t = np.where(span > 0, (at - a0) / np.where(span > 0, span, 1.0), 1.0)
    out = p0 + t[..., None] * (p1 - p0)
    last = at >= arc[:, -1:]  # np.interp's value at and past the end
    out[last] = np.broadcast_to(keep[:, -1:], out.shape)[last]
    return out
