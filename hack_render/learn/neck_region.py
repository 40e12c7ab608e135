"""The neck's skin region where the pose correctives act, its deformation measures, and
the stretch bound on it (:mod:`hack_render.learn.pose_energy` learns on it).

The bound (:func:`region_bound`) is :func:`hack_render.geometry.deformation.stretch_lower_bound`
restricted to the region: the anchors are the region's skin vertices rigid with one node
and bordering another node's vertices or a blended one, the paths run on the region's
edges with a blended end (or joining two anchors), as the model-level bound's do, so it
equals the model-level bound wherever those anchors and edges lie in the region (the
default model's do: ``tests/test_pose_space.py``). Shortest paths by Dijkstra (scipy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from hack_render.geometry.deformation import RigidAnchors, border_anchors


@dataclass
class NeckRegion:
    """The skin around the neck where correctives act, in local indices.

    Attributes:
        vertices: (V,) model vertex ids of every corner of the skin triangles that touch
            the corrective subset.
        subset: (M,) local ids of the corrective subset (where P, C and W are learned).
        faces: (T, 3) local triangles; edges (E, 2); pairs (Q, 2) adjacent triangles.
    """

    vertices: torch.Tensor
    subset: torch.Tensor
    faces: torch.Tensor
    edges: torch.Tensor
    pairs: torch.Tensor


def neck_region(faces: np.ndarray, skin_last: int, subset: np.ndarray) -> NeckRegion:
    """The :class:`NeckRegion` of a model's triangles (ids <= ``skin_last`` are skin)."""
    f = torch.as_tensor(np.asarray(faces), dtype=torch.long)
    f = f[(f <= skin_last).all(1)]
    n = int(f.max()) + 1
    sub = torch.as_tensor(np.asarray(subset), dtype=torch.long)
    insub = torch.zeros(n, dtype=torch.bool)
    insub[sub] = True
    f = f[insub[f].any(1)]
    verts = torch.unique(f)
    loc = -torch.ones(n, dtype=torch.long)
    loc[verts] = torch.arange(len(verts))
    f = loc[f]
    half = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).sort(1).values
    edges = torch.unique(half, dim=0)
    fid = torch.arange(len(f)).repeat(3)
    order = torch.argsort(half[:, 0] * (len(verts) + 1) + half[:, 1])
    hs, fs = half[order], fid[order]
    same = (hs[1:] == hs[:-1]).all(1)
    pairs = torch.stack([fs[:-1][same], fs[1:][same]], 1)
    return NeckRegion(vertices=verts, subset=loc[sub], faces=f, edges=edges, pairs=pairs)


def _unit(x: torch.Tensor) -> torch.Tensor:
    return x / x.norm(dim=-1, keepdim=True).clamp(min=1e-12)


def _normals(v: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    return torch.cross(v[..., f[:, 1], :] - v[..., f[:, 0], :], v[..., f[:, 2], :] - v[..., f[:, 0], :], dim=-1)


def _nearest_rotation(m: torch.Tensor) -> torch.Tensor:
    u, _, vh = torch.linalg.svd(m)
    d = torch.linalg.det(u @ vh)
    return torch.cat([u[..., :2], u[..., 2:] * d[..., None, None]], -1) @ vh


def skin_measures(region: NeckRegion, rest: torch.Tensor, posed: torch.Tensor,
                  rel_rot: torch.Tensor, face_weights: torch.Tensor):
    """Per pose: edge strain r (B, E), fold cosines (B, T) and adjacent-normal cosines
    (B, Q) of posed (B, V, 3) against rest (B, V, 3); rel_rot (B, K+1, 3, 3)."""
    e, f, q = region.edges, region.faces, region.pairs
    l0 = (rest[:, e[:, 0]] - rest[:, e[:, 1]]).norm(dim=-1).clamp(min=1e-12)
    r = (posed[:, e[:, 0]] - posed[:, e[:, 1]]).norm(dim=-1) / l0 - 1
    n0, n = _unit(_normals(rest, f)), _unit(_normals(posed, f))
    with torch.no_grad():  # the SVD's gradient is unstable at repeated singular values
        carry = _nearest_rotation(torch.einsum("tk,bkij->btij", face_weights, rel_rot))
    cos_fold = (n * torch.einsum("btij,btj->bti", carry, n0)).sum(-1)
    bend = (n[:, q[:, 0]] * n[:, q[:, 1]]).sum(-1) - (n0[:, q[:, 0]] * n0[:, q[:, 1]]).sum(-1)
    return r, cos_fold, bend


def region_anchors(region: NeckRegion, weights: torch.Tensor) -> RigidAnchors:
    """The :class:`~hack_render.geometry.deformation.RigidAnchors` of a region with (V, K + 1)
    skinning weights, in its local indices (the rule of
    :func:`~hack_render.geometry.deformation.rigid_anchors`, on the region's edges)."""
    return border_anchors(weights, region.edges)


def anchor_path_lengths(rest: np.ndarray, anchors: RigidAnchors) -> np.ndarray:
    """(S, S) shortest path lengths between the anchors along ``anchors.edges`` on the
    region's (V, 3) rest vertices (Dijkstra: the same lengths as
    :func:`~hack_render.geometry.deformation.anchor_paths`' Bellman-Ford, test_09, at 36 ms
    an identity against 0.5 s: the learner needs one per sampled identity)."""
    e = anchors.edges.numpy()
    length = np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    n = len(rest)
    graph = coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    ids = anchors.vertices.numpy()
    return dijkstra(graph, directed=False, indices=ids)[:, ids]


def region_bound(rest: torch.Tensor, transforms: torch.Tensor, anchors: RigidAnchors,
                 paths: torch.Tensor) -> torch.Tensor:
    """(B,) the stretch bound of rows with rest region (B, V, 3), node transforms
    (B, K + 1, 4, 4) (rest to posed) and anchor paths (B, S, S) (:func:`anchor_path_lengths`
    of each row's rest): the largest ``d / L - 1`` over anchor pairs on different nodes, d
    their posed distance, L their rest path."""
    m = transforms[:, anchors.node]  # (B, S, 4, 4)
    p0 = rest[:, anchors.vertices]
    p = torch.einsum("bsij,bsj->bsi", m[..., :3, :3], p0) + m[..., :3, 3]
    other = anchors.node[:, None] != anchors.node[None]
    ratio = torch.cdist(p, p) / paths.clamp(min=1e-12)
    return torch.where(other, ratio, torch.zeros_like(ratio)).amax((1, 2)) - 1
