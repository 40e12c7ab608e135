"""Posing a groom on posed vertices, in NumPy (renders, exports) and in torch (gradients).

A strand's control points are stored in its root triangle's frame
(:func:`hack_render.hair.groom.triangle_frames`); posing rebuilds the frame on the posed
mesh and maps them back: ``p = root + frame^T local``. Strands therefore follow every input
of G(beta, psi, theta, eta, tau) through the skin they are rooted in.

Strands are rigid in their root's frame, so a long strand can swing into the neck or the
shoulders when the head turns or bends: :func:`pose_group` then pushes every control point
that lies less than :data:`MARGIN` outside the skin back out along the nearest skin
vertex's normal (the posed mesh's own, found by a k-d tree each call), which is what the
collision test (tests/test_hair.py) checks over poses sampled within the limits.
"""

from __future__ import annotations

import numpy as np

from hack_render.geometry.normals import vertex_normals
from hack_render.hair.groom import (
    Groom,
    StrandGroup,
    open_edge_vertices,
    root_points,
    triangle_frames,
)

#: Smallest distance a posed control point keeps outside the skin, metres.
MARGIN = 0.0002


def pose_group(group: StrandGroup, vertices: np.ndarray, faces: np.ndarray,
               body: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(S, K, 3) control points of ``group`` on posed ``vertices`` (N, 3). ``body``: the
    posed body's (points, normals) (:func:`body_surface`): the strands that can reach it
    (``group.near_body``) are pushed out of it to :data:`MARGIN`."""
    v = np.asarray(vertices, np.float64)
    frames = triangle_frames(v, faces[group.tri])
    root = root_points(v, faces, group.tri, group.bary)
    pts = root[:, None] + np.einsum("sij,ski->skj", frames, group.local)
    if body is not None and pts.shape[1] > 1:
        near = group.near_body if group.near_body is not None else slice(None)
        pts[near, 1:] = push_out(pts[near, 1:], *body)
    return pts


def body_surface(groom: Groom, vertices: np.ndarray) -> tuple[object, np.ndarray, np.ndarray]:
    """(k-d tree, points, outward normals) of the posed body below the head; the normals of
    the surface's open edges are zero (a point nearest to the edge is beyond it)."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    normals = vertex_normals(v, groom.faces[groom.skin])
    normals[open_edge_vertices(groom.faces[groom.skin])] = 0.0
    index = groom.body
    return cKDTree(v[index]), v[index], normals[index]


def push_out(points: np.ndarray, tree, surf: np.ndarray, normals: np.ndarray,
             margin: float = MARGIN) -> np.ndarray:
    """``points`` (..., 3) moved out along the nearest surface point's normal until they are
    ``margin`` outside its tangent plane (points farther than 8 cm from the surface are
    outside: the neck's radius is smaller)."""
    out = points.reshape(-1, 3).copy()
    todo = np.arange(len(out))
    for _ in range(3):  # a push out of one side of a concave corner can land in the other
        dist, i = tree.query(out[todo], distance_upper_bound=0.08, workers=-1)
        hit = np.isfinite(dist)
        todo, j = todo[hit], i[hit]
        lack = margin - np.sum((out[todo] - surf[j]) * normals[j], -1)
        inside = lack > 0
        todo, j, lack = todo[inside], j[inside], lack[inside]
        if len(todo) == 0:
            break
        out[todo] += lack[:, None] * normals[j]
    return out.reshape(points.shape)


def signed_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray
                    ) -> np.ndarray:
    """Signed distance (...,) of ``points`` to the mesh's nearest vertex tangent plane
    (positive outside); points nearest to the mesh's open edges (the bust's cut) are
    beyond it: +inf."""
    from scipy.spatial import cKDTree

    index = np.unique(faces)
    normals = vertex_normals(vertices, faces)
    edge = np.zeros(len(vertices), bool)
    edge[open_edge_vertices(faces)] = True
    edge = edge[index]
    normals = normals[index]
    surf = vertices[index]
    flat = points.reshape(-1, 3)
    _, i = cKDTree(surf).query(flat, workers=-1)
    d = np.sum((flat - surf[i]) * normals[i], -1)
    beyond = edge[i] | (flat[:, 1] < surf[:, 1].min())
    return np.where(beyond, np.inf, d).reshape(points.shape[:-1])


def pose_groom(groom: Groom, vertices: np.ndarray, *, collide: bool = True
               ) -> dict[str, np.ndarray]:
    """{group name: (S, K, 3)} of the groom on posed ``vertices`` (N, 3); ``collide``: keep
    the strands out of the body below the head (:func:`pose_group`)."""
    body = None
    if collide and groom.body is not None and len(groom.body):
        tree, surf, normals = body_surface(groom, vertices)
        body = (tree, surf, normals)
    return {g.name: pose_group(g, vertices, groom.faces, body) for g in groom.groups}


def pose_group_torch(group: StrandGroup, vertices, faces):
    """The torch twin of :func:`pose_group` without collisions: (B, S, K, 3) control points
    on ``vertices`` (B, N, 3), differentiable in the vertices (and so in every input of the
    geometry model). ``faces``: (F, 3) long tensor."""
    import torch

    dev, dt = vertices.device, vertices.dtype
    tri = torch.as_tensor(group.tri, device=dev)
    f = faces[tri]  # (S, 3)
    a, b, c = vertices[:, f[:, 0]], vertices[:, f[:, 1]], vertices[:, f[:, 2]]
    e1 = b - a
    n = torch.linalg.cross(e1, c - a, dim=-1)
    e1 = e1 / e1.norm(dim=-1, keepdim=True).clamp_min(1e-20)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-20)
    e2 = torch.linalg.cross(n, e1, dim=-1)
    bary = torch.as_tensor(group.bary, device=dev, dtype=dt)
    root = bary[None, :, 0:1] * a + bary[None, :, 1:2] * b + bary[None, :, 2:3] * c
    local = torch.as_tensor(group.local, device=dev, dtype=dt)  # (S, K, 3)
    return root[:, :, None] + local[None, ..., 0:1] * e1[:, :, None] + \
        local[None, ..., 1:2] * e2[:, :, None] + local[None, ..., 2:3] * n[:, :, None]
