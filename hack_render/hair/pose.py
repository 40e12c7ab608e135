"""Posing a groom on posed vertices, in NumPy (renders, exports) and in torch (gradients).

A strand's control points are stored in its root triangle's frame
(:func:`hack_render.hair.strands.triangle_frames`); posing rebuilds the frame on the posed
mesh and maps them back: ``p = root + frame^T local``. Strands therefore follow every input
of G(beta, psi, theta, eta, tau) through the skin they are rooted in.

Strands are rigid in their root's frame, so a long strand can swing into the neck or the
shoulders when the head turns or bends: :func:`pose_group` then pushes every control point
that lies less than :data:`MARGIN` outside the skin back out along the nearest skin
vertex's normal (the posed mesh's own, found by a k-d tree each call), which is what the
collision test (tests/test_hair.py) checks over poses sampled within the limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.geometry.nearest import PointTree
from hack_render.geometry.normals import norm3, vertex_normals
from hack_render.hair.groom import Groom, StrandGroup
from hack_render.hair.strands import open_edge_vertices, root_points, triangle_frames

#: Smallest distance a posed control point keeps outside the skin, metres.
MARGIN = 0.0002

#: Rounds of :func:`push_out`: a push out of one side of a crease (the nape at a corner of
#: the range) can land inside the other side; each round pushes what is still inside. With
#: model version 4, three rounds left a long-hair point 1.0 mm inside the nape with every
#: joint at its lower limits (tests/test_hair.py); four reach the margin there.
PUSH_ROUNDS = 6


def pose_group(group: StrandGroup, vertices: np.ndarray, faces: np.ndarray,
               body: Body | None = None) -> np.ndarray:
    """(S, K, 3) control points of ``group`` on posed ``vertices`` (N, 3). ``body``: the
    posed skin (:func:`body_surface`); points inside it are pushed out to :data:`MARGIN`.

    A point over the skull is tested against its anchor's tangent plane (its nearest skin
    vertex at rest, ``group.anchor``) while the anchor sits where the strand's root frame
    carries it (within :data:`ANCHOR_SLACK`: the skull moves with hair rooted on it, in
    any pose); everywhere else (over the face, the ears, the neck and the shoulders, which
    move against the head, or an anchor that strayed) the nearest vertex is searched
    afresh."""
    v = np.asarray(vertices, np.float64)
    frames = triangle_frames(v, faces[group.tri])
    root = root_points(v, faces, group.tri, group.bary)
    pts = root[:, None] + from_frames(frames, group.local)
    if body is None or pts.shape[1] < 2:
        return pts
    inner = pts[:, 1:]
    if group.anchor is None:
        pts[:, 1:] = push_out(inner, body)
        return pts
    anchor = group.anchor[:, 1:]
    expect = root[:, None] + from_frames(frames, group.anchor_local[:, 1:].astype(np.float64))
    held = (anchor >= 0) & (norm3(v[anchor] - expect) < ANCHOR_SLACK)
    lack = MARGIN - np.sum((inner - v[anchor]) * body.normals[anchor], -1)
    search = ~held | (lack > 0)
    if search.any():
        inner[search] = push_out(inner[search], body)
    pts[:, 1:] = inner
    return pts


def from_frames(frames: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(S, K, 3) points ``local`` (S, K, 3) given in frames (S, 3, 3) (rows: the axes) in
    the frames' space: ``np.einsum("sij,ski->skj", frames, local)``, the same bits in
    about two thirds of the time (the axes summed in the same order)."""
    f = frames[:, None]
    return (f[..., 0, :] * local[..., 0:1] + f[..., 1, :] * local[..., 1:2]) + \
        f[..., 2, :] * local[..., 2:3]


#: How far an anchor may sit from where its strand's frame carries it and still stand for
#: the skin under the point (metres).
ANCHOR_SLACK = 0.002


@dataclass
class Body:
    """The posed skin for collisions: a k-d tree of its vertices (``index`` into the mesh),
    and every mesh vertex's outward unit normal (zero on the skin's open edges: a point
    nearest to an edge is beyond the surface, not inside it)."""

    tree: object
    index: np.ndarray
    points: np.ndarray
    normals: np.ndarray


def body_surface(groom: Groom, vertices: np.ndarray) -> Body:
    """The :class:`Body` of ``groom``'s skin on posed ``vertices``."""
    v = np.asarray(vertices, np.float64)
    skin = groom.faces[groom.skin]
    normals = vertex_normals(v, skin)
    normals[open_edge_vertices(skin)] = 0.0
    index = groom.body if groom.body is not None else np.unique(skin)
    return Body(PointTree(v[index]), index, v[index], normals)


def push_out(points: np.ndarray, body: Body, margin: float = MARGIN) -> np.ndarray:
    """``points`` (..., 3) moved out along the nearest skin vertex's normal until they are
    ``margin`` outside its tangent plane (points farther than 8 cm from the skin are
    outside: the neck's radius is smaller)."""
    out = points.reshape(-1, 3).copy()
    todo = np.arange(len(out))
    normals = body.normals[body.index]
    # a point nearest to an open edge's vertex (zero normal) is beyond the surface: it is
    # not moved, so it is not searched again in the next round (it was, every round)
    has_normal = np.any(normals != 0.0, axis=1)
    for _ in range(PUSH_ROUNDS):
        dist, i = body.tree.query(out[todo], distance_upper_bound=0.08)
        hit = np.isfinite(dist)
        todo, j = todo[hit], i[hit]
        lack = margin - np.sum((out[todo] - body.points[j]) * normals[j], -1)
        inside = (lack > 0) & has_normal[j]
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
    index = np.unique(faces)
    normals = vertex_normals(vertices, faces)
    edge = np.zeros(len(vertices), bool)
    edge[open_edge_vertices(faces)] = True
    edge = edge[index]
    normals = normals[index]
    surf = vertices[index]
    flat = points.reshape(-1, 3)
    _, i = PointTree(surf).query(flat)
    d = np.sum((flat - surf[i]) * normals[i], -1)
    beyond = edge[i] | (flat[:, 1] < surf[:, 1].min())
    return np.where(beyond, np.inf, d).reshape(points.shape[:-1])


def pose_groom(groom: Groom, vertices: np.ndarray, *, collide: bool = True
               ) -> dict[str, np.ndarray]:
    """{group name: (S, K, 3)} of the groom on posed ``vertices`` (N, 3); ``collide``: keep
    the strands out of the body below the head (:func:`pose_group`)."""
    body = body_surface(groom, vertices) if collide else None
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
