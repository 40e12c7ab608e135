"""HACK's surface on a character of another topology, by closest-point correspondence.

Used for glTF targets of `hack-render transfer` (:mod:`.transfer`); everything it makes is
derived data (the file's metadata says so):

1. **Alignment** (:func:`align_hack`). The person's rest surface (``export.rig`` base) is
   laid onto the character's rest pose: HACK's 9 skeleton nodes move to the points at the
   same relative arc length along the character's neck chain (the vertices follow by
   their skinning weights, as :func:`.character.long_neck_character` lengthens a neck),
   then the skull (blended by the o-c1 weight) is scaled per axis and moved by a
   two-sided ICP onto the vertices skinned to the character's head bone. Both stand in
   rest pose, Y up, facing +Z (HACK's and glTF's convention); no rotation is estimated.
2. **Correspondence** (:func:`closest_points`). Every query point (a texel's surface
   point, a vertex) takes its closest point on the aligned HACK skin: triangle and
   barycentric coordinates, exact projection onto the triangles of its nearest samples.
3. **Maps** (:func:`bake_maps`). HACK's skin maps read (bilinear) at that point's atlas
   coordinates: diffuse, specular intensity and roughness as they are; the normal map
   re-expressed from HACK's tangent frame into the character's (OpenGL, +Y along +v).
   Empty texels take their nearest covered texel (seams filter cleanly).
4. **Displacements** (:func:`transfer_displacements`). The person's morph targets
   (expressions, larynx size and slide) interpolated at that point, scaled as the skull
   was, and faded out between ``r0`` and ``r1`` from HACK's skin, so a vertex far from
   any HACK surface (a body, a tail) does not move.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from appearance.uv import rasterize_uv
from hack_render.errors import HackError
from hack_render.io.image import sample_bilinear
from hack_render.render.parts import Topology, vertex_normals

SKIN_MATERIALS = ("M_Face", "M_BackHead")


@dataclass
class HackSurface:
    """HACK's skin laid onto a character.

    Attributes:
        vertices: (N, 3) aligned vertices, metres (all the model's vertices).
        faces: (F, 3) the skin's triangles (model vertex ids).
        uv: (F, 3, 2) their atlas coordinates (u in [0, 2], v up, ``appearance.uv``).
        scale: (N, 3) per-vertex per-axis scale of the alignment (for displacements).
        info: what the alignment found (skull scale and shift, ICP residual).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    scale: np.ndarray
    info: dict = field(default_factory=dict)


def skin_faces(model) -> tuple[np.ndarray, np.ndarray]:
    """The model's skin triangles (F, 3) and their atlas coordinates (F, 3, 2)."""
    topo = Topology.from_model(model)
    sel = np.isin(topo.face_material, [topo.material_names.index(m) for m in SKIN_MATERIALS
                                       if m in topo.material_names])
    if not sel.any():
        raise HackError(f"head model: no skin triangles (materials {SKIN_MATERIALS}); the "
                        "maps and expressions are read from the skin.")
    return topo.faces[sel], topo.uvs[topo.uv_faces[sel]]


def chain_points(chain: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points (len(s), 3) at relative arc lengths ``s`` in [0, 1] along the polyline
    ``chain`` (B, 3)."""
    seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    cum = np.r_[0.0, np.cumsum(seg)]
    u = np.asarray(s, np.float64) * cum[-1]
    return np.stack([np.interp(u, cum, chain[:, k]) for k in range(3)], 1)


def _relative_arc(p: np.ndarray) -> np.ndarray:
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    return s / max(s[-1], 1e-12)


def align_hack(base: np.ndarray, weights: np.ndarray, nodes: np.ndarray, chain: np.ndarray,
               head_points: np.ndarray, faces: np.ndarray, iterations: int = 40
               ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Lay HACK's rest surface onto a character (module docstring, step 1).

    Args:
        base: (N, 3) HACK's rest vertices. weights: (N, 9) skinning weights (root first).
        nodes: (9, 3) HACK's rest nodes (root at c7-t1, then c7-t1 ... o-c1).
        chain: (B, 3) the character's neck chain at rest (world), base to head.
        head_points: (M, 3) the character's head surface (vertices skinned to its head).
        faces: HACK's skin triangles (which vertices take part in the ICP).
    Returns:
        aligned vertices (N, 3), per-vertex per-axis scale (N, 3), info.
    """
    from scipy.spatial import cKDTree

    joints = nodes[1:]
    moved = chain_points(chain, _relative_arc(joints))
    moved = np.concatenate([moved[:1], moved])
    v = base + weights @ (moved - nodes)
    head = weights[:, -1]
    skull = np.zeros(len(v), bool)
    skull[np.unique(faces)] = True
    skull &= head > 0.99
    src = v[skull]
    centre = moved[-1]
    s, t = np.ones(3), np.zeros(3)
    tree_c = cKDTree(head_points)
    resid = np.nan
    for _ in range(iterations if len(head_points) >= 10 else 0):
        cur = centre + s * (src - centre) + t
        d1, i1 = tree_c.query(cur)
        d2, i2 = cKDTree(cur).query(head_points)
        x = np.concatenate([src, src[i2]]) - centre  # (pairs, 3): HACK side, unscaled
        y = np.concatenate([head_points[i1], head_points]) - centre
        d = np.concatenate([d1, d2])
        keep = d <= np.quantile(d, 0.9)  # trimmed: a snout or horns have no partner
        x, y = x[keep], y[keep]
        for k in range(3):  # y = s x + t per axis, least squares
            a = np.stack([x[:, k], np.ones(len(x))], 1)
            s[k], t[k] = np.linalg.lstsq(a, y[:, k], rcond=None)[0]
        s = np.clip(s, 0.2, 5.0)
        resid = float(np.sqrt(np.mean(d[keep] ** 2)))
    scale = 1.0 + head[:, None] * (s - 1.0)
    v = v + head[:, None] * ((centre + s * (v - centre) + t) - v)
    info = {"skull_scale": s.round(4).tolist(), "skull_shift_m": t.round(5).tolist(),
            "icp_rms_m": round(resid, 6) if np.isfinite(resid) else None,
            "neck_length_ratio": round(float(
                np.linalg.norm(np.diff(moved[1:], axis=0), axis=1).sum()
                / max(np.linalg.norm(np.diff(joints, axis=0), axis=1).sum(), 1e-12)), 4)}
    return v, scale, info


def hack_surface(model, rig, chain: np.ndarray, head_points: np.ndarray) -> HackSurface:
    """The person's rest surface (``rig``: ``export.rig.ExportRig``) aligned onto a
    character with neck chain ``chain`` (B, 3) and head surface ``head_points`` (M, 3)."""
    faces, uv = skin_faces(model)
    w = model.skinning_weights.double().numpy()
    v, scale, info = align_hack(rig.base, w, rig.rest_nodes, chain, head_points, faces)
    return HackSurface(v, faces, uv, scale, info)


def _samples(v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points on every triangle (centroid and three inner points) and their triangle."""
    bary = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]], np.float64)
    bary /= bary.sum(1, keepdims=True)
    p = np.einsum("sk,fkc->fsc", bary, v[faces]).reshape(-1, 3)
    return p, np.repeat(np.arange(len(faces)), len(bary))


def closest_points(v: np.ndarray, faces: np.ndarray, query: np.ndarray, k: int = 8,
                   chunk: int = 65536) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point on a triangle mesh for each query point (Q, 3): triangle (Q,),
    barycentric coordinates (Q, 3) and distance (Q,). Candidates: the triangles of the
    ``k`` nearest surface samples; each projected exactly (``trimesh.triangles``)."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point, points_to_barycentric

    pts, owner = _samples(v, faces)
    tree = cKDTree(pts)
    q = np.asarray(query, np.float64)
    tri = np.zeros(len(q), np.int64)
    bary = np.zeros((len(q), 3))
    dist = np.zeros(len(q))
    for s in range(0, len(q), chunk):
        qq = q[s:s + chunk]
        _, idx = tree.query(qq, k=k, workers=-1)
        cand = owner[idx]  # (n, k)
        tris = v[faces[cand.ravel()]]
        cp = closest_point(tris, np.repeat(qq, k, 0))
        d = np.linalg.norm(cp - np.repeat(qq, k, 0), axis=1).reshape(-1, k)
        best = d.argmin(1)
        rows = np.arange(len(qq))
        f = cand[rows, best]
        pick = best + rows * k
        tri[s:s + chunk] = f
        b = points_to_barycentric(tris[pick], cp[pick])
        b = np.clip(b, 0.0, None)
        bary[s:s + chunk] = b / np.maximum(b.sum(1, keepdims=True), 1e-12)
        dist[s:s + chunk] = d[rows, best]
    return tri, bary, dist


def sample_atlas(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """A skin map (H, 2H, C) at atlas coordinates uv (Q, 2) (u in [0, 2], v up)."""
    h = img.shape[0]
    return sample_bilinear(np.asarray(img, np.float64), uv[:, 0] * h - 0.5, (1 - uv[:, 1]) * h - 0.5)


def tangent_frames(v: np.ndarray, faces: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Per-triangle unit tangent (+u) and bitangent (+v) directions (F, 2, 3) from the
    triangles' texture coordinates uv (F, 3, 2) (v up)."""
    p = v[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    det = np.where(np.abs(det) > 1e-20, det, 1e-20)
    t = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / det[:, None]
    b = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) / det[:, None]
    out = np.stack([t, b], 1)
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-20)


def _frame(tb: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Orthonormal (Q, 3, 3) rows T, B, N: the tangent made normal to n, B = +-N x T on
    the side of the triangle's bitangent."""
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    t = tb[:, 0] - (tb[:, 0] * n).sum(1, keepdims=True) * n
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-20)
    b = np.cross(n, t)
    b *= np.where((b * tb[:, 1]).sum(1, keepdims=True) < 0, -1.0, 1.0)
    return np.stack([t, b, n], 1)


def _vertex_normals(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return vertex_normals(v, faces)


def rasterize_atlas(uv_tris: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """A glTF atlas (uv (F, 3, 2) in [0, 1], v down: image row 0 at v = 0) rasterised at
    size x size: triangle per texel (S, S) (-1: none) and barycentrics (S, S, 3)."""
    up = np.stack([uv_tris[..., 0], 1.0 - uv_tris[..., 1]], -1)  # image rows as the atlas'
    face, bary = rasterize_uv(up, int(size))
    return face[:, :size], bary[:, :size]


def bake_maps(surface: HackSurface, maps, positions: np.ndarray, faces: np.ndarray,
              uv: np.ndarray, size: int) -> tuple[dict, dict]:
    """HACK's maps baked onto a character primitive's atlas.

    Args:
        surface: the aligned HACK skin. maps: ``render.materials.SkinMaps``.
        positions: (V, 3) the primitive's rest vertices (world). faces: (F, 3).
        uv: (V, 2) its TEXCOORD_0 (glTF: [0, 1], v down).
        size: atlas size in texels.
    Returns:
        ({diffuse (S, S, 3), specular (S, S, 1), roughness (S, S, 1), normal (S, S, 3) or
        None}, stats: covered texel fraction, distance to HACK's skin (median, p95, max)).
    """
    from scipy import ndimage

    face, bary = rasterize_atlas(uv[faces], size)
    cov = face >= 0
    if not cov.any():
        raise HackError(f"bake: no texel of the {size} x {size} atlas lies in a triangle; "
                        "its UVs are degenerate.")
    f = face[cov]
    b = bary[cov].astype(np.float64)
    tri = faces[f]
    pts = np.einsum("qk,qkc->qc", b, positions[tri])
    hf, hb, dist = closest_points(surface.vertices, surface.faces, pts)
    huv = np.einsum("qk,qkc->qc", hb, surface.uv[hf])
    out = {}
    for key in ("diffuse", "specular", "roughness", "normal"):
        src = getattr(maps, key)
        if src is None:
            out[key] = None
            continue
        val = sample_atlas(src, huv)
        if key == "normal":
            val = _retangent(val, surface, hf, hb, positions, faces, uv, f, b)
        img = np.zeros((size, size, val.shape[1]))
        img[cov] = val
        out[key] = img
    _, (ii, jj) = ndimage.distance_transform_edt(~cov, return_indices=True)
    for key, img in out.items():
        if img is not None:
            out[key] = img[ii, jj].astype(np.float32)
    stats = {"size": int(size), "covered_fraction": round(float(cov.mean()), 4),
             "distance_to_hack_skin_m": {"median": float(np.median(dist)),
                                         "p95": float(np.quantile(dist, 0.95)),
                                         "max": float(dist.max())}}
    return out, stats


def _retangent(nrm, surface, hf, hb, positions, faces, uv, f, b) -> np.ndarray:
    """Tangent-space normals (Q, 3) from HACK's frames at its closest points into the
    character's frames at the texels (both OpenGL: +Y along +v, v up)."""
    hv = surface.vertices
    hn = np.einsum("qk,qkc->qc", hb, _vertex_normals(hv, surface.faces)[surface.faces[hf]])
    h_frame = _frame(tangent_frames(hv, surface.faces, surface.uv)[hf], hn)
    uv_up = np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1)
    cn = np.einsum("qk,qkc->qc", b, _vertex_normals(positions, faces)[faces[f]])
    c_frame = _frame(tangent_frames(positions, faces, uv_up[faces])[f], cn)
    n = np.einsum("qi,qic->qc", nrm, h_frame)  # SkinMaps: unit vectors in [-1, 1]
    t = np.einsum("qc,qjc->qj", n, c_frame)
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-20)


def fade(dist: np.ndarray, r0: float, r1: float) -> np.ndarray:
    """1 within r0, 0 beyond r1, smoothstep between."""
    x = np.clip((np.asarray(dist) - r0) / max(r1 - r0, 1e-12), 0.0, 1.0)
    return 1.0 - x * x * (3 - 2 * x)


def transfer_displacements(surface: HackSurface, targets: np.ndarray, points: np.ndarray,
                           r0: float = 0.01, r1: float = 0.03
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Morph targets (K, N, 3) of HACK moved onto points (V, 3) of a character:
    (K, V, 3) float32 and the distance of each point to HACK's skin (V,)."""
    hf, hb, dist = closest_points(surface.vertices, surface.faces, points)
    near = np.flatnonzero(dist < r1)  # the others do not move
    out = np.zeros((len(targets), len(points), 3), np.float32)
    tri, hb = surface.faces[hf[near]], hb[near]
    scale = np.einsum("qk,qkc->qc", hb, surface.scale[tri]) * fade(dist[near], r0, r1)[:, None]
    out[:, near] = np.einsum("qk,tqkc->tqc", hb, targets[:, tri]) * scale[None]
    return out, dist
