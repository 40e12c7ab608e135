"""How much a pose deforms the skin: edge stretch and compression, folded triangles, and
the pose samplers that cover the joint space (singly and combined).

Used by the pose-space stress test (``bench/bench_pose_space.py``,
``tests/test_pose_space.py``) and by the pose-corrective learner. Torch and numpy only.

Definitions (per pose, over the skin triangles: vertex groups ``face`` and
``head_and_neck``):

* stretch: the largest ``|e| / |e0| - 1`` over skin edges, posed edge e against the same
  identity's and expression's edge e0 at zero pose;
* compression: the largest ``1 - |e| / |e0|``;
* folded triangles: those whose posed normal points against their rest normal carried by
  the triangle's rigid rotation: the rotation nearest (polar decomposition) to the blend of
  the node rotations by the summed skinning weights of its corners, so skin turned inside
  out counts, and skin merely turned with the head or the neck does not;
* stretch lower bound: what no corrective or neck weighting can get below while the skin
  rigid with the skull and with the thorax stays so (:func:`stretch_lower_bound`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
from hack_render.geometry.rotations import euler_to_axis_angle
from hack_render.geometry.skeleton import distribute_head_rotation, rotation_limits

#: vertex groups whose triangles count as skin (HackModel.group_names 0 and 1)
SKIN_GROUPS = ("face", "head_and_neck")


@dataclass
class SkinTopology:
    """Skin triangles and edges of a model, and each triangle's skinning weights.

    Attributes:
        faces: (T, 3) int64 skin triangles.
        edges: (E, 2) int64 unique skin edges.
        weights: (T, K + 1) the corners' mean skinning weights (root first).
    """

    faces: torch.Tensor
    edges: torch.Tensor
    weights: torch.Tensor


def skin_topology(model) -> SkinTopology:
    """The skin triangles, edges and triangle weights of a :class:`HackModel`."""
    groups = [model.group_names.index(g) for g in SKIN_GROUPS]
    skin_v = torch.isin(model.vertex_group, torch.tensor(groups))
    faces = model.faces[skin_v[model.faces].all(1)]
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).sort(1).values
    edges = torch.unique(e, dim=0)
    return SkinTopology(faces=faces, edges=edges, weights=model.skinning_weights[faces].mean(1))


@dataclass
class DeformationStats:
    """Per pose (B,): largest skin-edge stretch and compression (fractions), and the number
    of folded skin triangles."""

    stretch: torch.Tensor
    compression: torch.Tensor
    folded: torch.Tensor


def _normals(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    return torch.cross(v[..., faces[:, 1], :] - v[..., faces[:, 0], :],
                       v[..., faces[:, 2], :] - v[..., faces[:, 0], :], dim=-1)


def deformation_stats(rest: torch.Tensor, posed: torch.Tensor, node_rotations: torch.Tensor,
                      topo: SkinTopology) -> DeformationStats:
    """Skin deformation of posed meshes against their zero-pose meshes.

    Args:
        rest: (B, N, 3) or (N, 3) the same identity and expression at zero pose (posed
            by the root's rotation alone is fine: lengths and rotated normals compare).
        posed: (B, N, 3) posed vertices.
        node_rotations: (B, K + 1, 3, 3) world rotation of each node (root first), the
            rotation part of the skinning transforms.
        topo: :func:`skin_topology` of the model.
    """
    rest = rest.expand_as(posed)
    a, b = topo.edges[:, 0], topo.edges[:, 1]
    l0 = (rest[:, a] - rest[:, b]).norm(dim=-1).clamp(min=1e-12)
    ratio = (posed[:, a] - posed[:, b]).norm(dim=-1) / l0
    folded = fold_mask(rest, posed, node_rotations, topo).sum(1)
    return DeformationStats(stretch=ratio.max(1).values - 1, compression=1 - ratio.min(1).values,
                            folded=folded)


def fold_mask(rest: torch.Tensor, posed: torch.Tensor, node_rotations: torch.Tensor,
              topo: SkinTopology) -> torch.Tensor:
    """(B, T) bool: the skin triangles whose posed normal faces away from their rest normal
    carried by the skinning's rotation (:func:`deformation_stats`'s folds; arguments as
    there, ``rest`` expanded to ``posed``)."""
    rest = rest.expand_as(posed)
    n0 = _normals(rest, topo.faces)  # (B, T, 3)
    w = topo.weights.to(node_rotations.dtype)
    # a triangle skinned to one node turns with it; the others by the polar factor (the
    # nearest rotation) of their blended rotation
    rigid = w.max(1).values >= 1 - 1e-6
    rot = node_rotations[:, w.argmax(1)]  # (B, T, 3, 3)
    blend = torch.einsum("tk,bkij->btij", w[~rigid], node_rotations)
    u, _, vh = torch.linalg.svd(blend)
    d = torch.linalg.det(u @ vh)
    u = torch.cat([u[..., :2], u[..., 2:] * d[..., None, None]], -1)
    rot[:, ~rigid] = u @ vh
    carried = torch.einsum("btij,btj->bti", rot, n0)
    return (_normals(posed, topo.faces) * carried).sum(-1) < 0


def model_deformation(model, beta: torch.Tensor, theta: torch.Tensor, psi=None,
                      topo: SkinTopology | None = None, chunk: int = 64) -> DeformationStats:
    """:func:`deformation_stats` of one identity over many poses.

    Args:
        model: a :class:`HackModel`.
        beta: (1, S) identity.
        theta: (P, 8, 3) poses.
        psi: optional (E,) or (1, E) expression held over the poses (and in the reference).
    """
    topo = topo or skin_topology(model)
    person = model.personalize(beta)
    out = {"stretch": [], "compression": [], "folded": []}
    with torch.no_grad():
        psi1 = None if psi is None else torch.as_tensor(psi, dtype=model.template.dtype).reshape(1, -1)
        rest = person(psi=psi1).vertices
        for s in range(0, theta.shape[0], chunk):
            th = theta[s:s + chunk].to(model.template.dtype)
            f = th.shape[0]
            posed = person(psi=None if psi1 is None else psi1.expand(f, -1), theta=th).vertices
            rot = local_rotations(th, th.new_zeros(f, 3))
            j = person.joints.expand(f, -1, -1)
            _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(model.parents))
            st = deformation_stats(rest, posed, rel[..., :3, :3], topo)
            for k, acc in out.items():
                acc.append(getattr(st, k))
    return DeformationStats(**{k: torch.cat(v) for k, v in out.items()})


def head_rotation_range_deg() -> torch.Tensor:
    """(3, 2) whole-neck range per axis (flexion X, axial Y, lateral Z): the sums of the
    joints' limits, degrees (what :func:`distribute_head_rotation` reaches unclamped)."""
    return torch.rad2deg(rotation_limits(torch.float64).sum(0))


def sample_joint_poses(n: int, generator: torch.Generator, dtype=torch.float64) -> torch.Tensor:
    """(n, 8, 3) axis-angle poses, every joint's three Euler angles uniform within its
    limits, independently (combined flexion, lateral bend and axial rotation everywhere)."""
    lim = rotation_limits(dtype)
    u = torch.rand(n, 8, 3, generator=generator, dtype=dtype)
    return euler_to_axis_angle(lim[..., 0] + u * (lim[..., 1] - lim[..., 0]))


def sample_head_poses(n: int, generator: torch.Generator, axes: str = "xyz",
                      dtype=torch.float64) -> torch.Tensor:
    """(n, 8, 3) whole-head rotations uniform up to each axis's full range on the named
    axes (zero on the others), shared out by :func:`distribute_head_rotation`."""
    rng = torch.deg2rad(head_rotation_range_deg()).to(dtype)
    u = torch.rand(n, 3, generator=generator, dtype=dtype)
    ang = rng[:, 0] + u * (rng[:, 1] - rng[:, 0])
    keep = torch.tensor([a in axes for a in "xyz"], dtype=dtype)
    return distribute_head_rotation(ang * keep)


def sample_corner_head_poses(n: int, generator: torch.Generator, dtype=torch.float64,
                             outer: float = 0.25) -> torch.Tensor:
    """(n, 8, 3) whole-head rotations near the box's corners: on every axis uniform within
    the ``outer`` fraction of the range at one of its two ends (a fair coin per axis),
    shared out by :func:`distribute_head_rotation`: full flexion with a full bend, where the
    expression's folds were (docs/model.md)."""
    rng = torch.deg2rad(head_rotation_range_deg()).to(dtype)
    u = outer * torch.rand(n, 3, generator=generator, dtype=dtype)
    high = torch.rand(n, 3, generator=generator) < 0.5
    u = torch.where(high, 1 - u, u)
    return distribute_head_rotation(rng[:, 0] + u * (rng[:, 1] - rng[:, 0]))


def sample_pose_space(n: int, seed: int, dtype=torch.float64) -> dict[str, torch.Tensor]:
    """The stress test's pose families, seeded: per-joint uniform (half), whole-head
    rotations on each axis alone (a twelfth each) and on all three combined (the rest)."""
    g = torch.Generator().manual_seed(seed)
    fam = {"joints_uniform": sample_joint_poses(n // 2, g, dtype)}
    for ax in "xyz":
        fam[f"head_{ax}"] = sample_head_poses(n // 12, g, ax, dtype)
    fam["head_xyz"] = sample_head_poses(n - sum(len(v) for v in fam.values()), g, "xyz", dtype)
    return fam


@dataclass
class RigidAnchors:
    """Skin vertices that every pose carries rigidly with one node (skinning rows with one
    weight of 1: the face with the skull, the chest rim with the thorax) and that border
    skin not rigid with that node: the pairs of them on different nodes bound the stretch
    (:func:`stretch_lower_bound`). Rigid vertices inside a rigid patch add nothing: a
    shortest path from one leaves the patch through a border vertex, and its rigid part
    keeps its length.

    Attributes:
        vertices: (S,) vertex ids; node: (S,) the node each is rigid with (0 = root, the
            thorax; K = o-c1, the skull).
        edges: (E, 2) the skin edges the bounding paths run on: those with an end not
            rigid, and those joining two anchors (paths through the inside of a rigid
            patch are left out: fewer paths only weaken the bound, and it stays cheap).
    """

    vertices: torch.Tensor
    node: torch.Tensor
    edges: torch.Tensor


def rigid_anchors(model, topo: SkinTopology | None = None) -> RigidAnchors:
    """The :class:`RigidAnchors` of a :class:`HackModel`'s skin."""
    topo = topo or skin_topology(model)
    w = model.skinning_weights
    skin = torch.zeros(w.shape[0], dtype=torch.bool)
    skin[topo.faces.unique()] = True
    return border_anchors(w, topo.edges, skin)


def border_anchors(weights: torch.Tensor, edges: torch.Tensor,
                   skin: torch.Tensor | None = None) -> RigidAnchors:
    """:class:`RigidAnchors` of vertices with skinning weights (N, K + 1) joined by skin
    ``edges`` (E, 2) (``skin`` (N,) bool: the vertices that may be anchors; None: all)."""
    w = weights
    rigid = w.max(1).values >= 1 - 1e-6
    node = torch.where(rigid if skin is None else skin & rigid, w.argmax(1), -1)
    a, b = edges[:, 0], edges[:, 1]
    differ = node[a] != node[b]
    border = torch.zeros(len(node), dtype=torch.bool)
    border[a[differ & (node[a] >= 0)]] = True
    border[b[differ & (node[b] >= 0)]] = True
    ids = border.nonzero()[:, 0]
    free = (node[a] < 0) | (node[b] < 0) | (border[a] & border[b])
    return RigidAnchors(vertices=ids, node=node[ids], edges=edges[free])


def edge_path_lengths(vertices: torch.Tensor, edges: torch.Tensor, sources: torch.Tensor,
                      max_rounds: int = 100000) -> torch.Tensor:
    """(S, N) length of the shortest path along ``edges`` from each source to every vertex
    of (N, 3) ``vertices`` (inf where unreachable): Bellman-Ford relaxation over all edges
    at once, until nothing shortens."""
    n = vertices.shape[0]
    ln = (vertices[edges[:, 0]] - vertices[edges[:, 1]]).norm(dim=-1)
    i = torch.cat([edges[:, 0], edges[:, 1]])
    j = torch.cat([edges[:, 1], edges[:, 0]])
    ln = torch.cat([ln, ln])
    dist = torch.full((len(sources), n), float("inf"), dtype=vertices.dtype)
    dist[torch.arange(len(sources)), sources] = 0.0
    for _ in range(max_rounds):
        new = dist.scatter_reduce(1, j.expand(len(sources), -1), dist[:, i] + ln, "amin")
        if torch.equal(new, dist):
            break
        dist = new
    return dist


def stretch_lower_bound(rest: torch.Tensor, transforms: torch.Tensor, anchors: RigidAnchors,
                        paths: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) a lower bound on the largest skin-edge stretch (:func:`deformation_stats`) of
    any deformation that keeps the anchors rigid with their nodes.

    For two anchors s and t on different nodes, the shortest edge path between them at
    rest has length L_st; posed, its edges span at least the straight distance d_st between
    the two rigidly carried ends, so one of its edges is stretched by at least
    d_st / L_st - 1. Whatever the correctives or the weights of the skin between, the
    largest stretch is at least the largest of these.

    Args:
        rest: (N, 3) the identity (and expression) at zero pose.
        transforms: (B, K + 1, 4, 4) node skinning transforms (rest to posed).
        anchors: :func:`rigid_anchors`.
        paths: (S, S) rest path lengths between the anchors, if already computed
            (:func:`anchor_paths`).
    """
    if paths is None:
        paths = anchor_paths(rest, anchors)
    paths = paths.to(rest.dtype)
    m = transforms.to(rest.dtype)[:, anchors.node]  # (B, S, 4, 4)
    p = torch.einsum("bsij,sj->bsi", m[..., :3, :3], rest[anchors.vertices]) + m[..., :3, 3]
    other = anchors.node[:, None] != anchors.node[None]
    ratio = torch.cdist(p, p) / paths.clamp(min=1e-12)
    return torch.where(other, ratio, torch.zeros_like(ratio)).amax((1, 2)) - 1


def anchor_paths(rest: torch.Tensor, anchors: RigidAnchors) -> torch.Tensor:
    """(S, S) shortest path lengths between the anchors along ``anchors.edges`` on (N, 3)
    ``rest``."""
    return edge_path_lengths(rest, anchors.edges, anchors.vertices)[:, anchors.vertices]


def model_stretch_bound(model, beta: torch.Tensor, theta: torch.Tensor, psi=None,
                        topo: SkinTopology | None = None, anchors: RigidAnchors | None = None,
                        chunk: int = 256) -> torch.Tensor:
    """(P,) :func:`stretch_lower_bound` of one identity (beta (1, S), expression psi held)
    over poses theta (P, 8, 3): what no corrective or neck weighting can get below while
    the face stays rigid with the skull and the chest rim with the thorax."""
    topo = topo or skin_topology(model)
    anchors = anchors or rigid_anchors(model, topo)
    person = model.personalize(beta)
    with torch.no_grad():
        psi1 = None if psi is None else torch.as_tensor(psi, dtype=model.template.dtype).reshape(1, -1)
        rest = person(psi=psi1).vertices[0].double()
        paths = anchor_paths(rest, anchors)
        out = []
        for s in range(0, theta.shape[0], chunk):
            th = theta[s:s + chunk].double()
            f = th.shape[0]
            rot = local_rotations(th, th.new_zeros(f, 3))
            j = person.joints.double().expand(f, -1, -1)
            _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(model.parents))
            out.append(stretch_lower_bound(rest, rel, anchors, paths))
    return torch.cat(out).to(model.template.dtype)
