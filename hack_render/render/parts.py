"""Splitting the head mesh into render parts (one Mitsuba mesh per material region).

Pure numpy. The model's mesh indexes UVs separately from vertices; Mitsuba needs one
UV per vertex, so each part splits vertices at UV seams and keeps a gather index into
the model's vertex array, so that per-frame updates are one ``vertices[gather]``.
Normals are computed on the whole mesh before gathering, so seams stay smooth.

Region ids (segmentation AOV): see :data:`REGIONS`. ICT's helper shells (``M_EyeBlend``,
``M_EyeOcclusion``) are not rendered: they are blending and ambient-occlusion layers meant
for alpha compositing with textures we do not ship, and drawn opaque they cover the eyes.
The outer eye shell (``M_Sclera*``) is opened over the cornea so that the inner eye
(``M_Iris*``, a sphere with the iris at its front) shows through; the corneal gloss is
given to the iris material (see ``materials.py``).

The bust cap (``bust_cap``, region ``bust``): ICT's skin ends in an open cut across the
chest and shoulders, whose inside (back faces, black) showed from behind and below. The
cap closes that boundary loop with a shallow cone: one triangle from each edge of the loop
to an apex :data:`CAP_APEX` beyond the loop's centroid, along the loop's outward normal
(:func:`cap_apex`, recomputed from the posed loop on every update, so it follows every
pose). A flat cap over the loop's own vertices (ear clipping in its best-fit plane, the
cap before) lay almost in the skin's own surface where the cut runs along it, at the
shoulders (the skin's last ring within 1 degree of the plane), and poked through the skin
by about a millimetre when a pose moved the cut; the cone slopes out of the body from
every rim edge. It is flat-shaded matte grey (``materials.py``), not anatomy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry.normals import vertex_normals  # noqa: F401  (re-exported)
from hack_render.geometry.rigid import kabsch

#: Segmentation labels, index = region id (0 is background). ``hair``: the strands of a
#: groom (``HeadScene(hair=...)``, curve shapes, not a part of the mesh); appended last so
#: the earlier ids stay.
REGIONS: tuple[str, ...] = ("background", "face", "back_head", "mouth", "teeth", "sclera",
                            "iris", "lacrimal", "eyelashes", "bust", "hair")

#: Part name -> (ICT materials, region, u offset subtracted, u scale applied after).
PART_SPECS: dict[str, tuple[tuple[str, ...], str, float, float]] = {
    "skin_face": (("M_Face",), "face", 0.0, 0.5),  # skin atlas: (u / 2, v)
    "skin_back": (("M_BackHead",), "back_head", 0.0, 0.5),
    "mouth": (("M_GumsTongue",), "mouth", 2.0, 1.0),
    "teeth": (("M_Teeth",), "teeth", 3.0, 1.0),
    "sclera": (("M_ScleraLeft", "M_ScleraRight"), "sclera", 0.0, 1.0),
    "iris": (("M_IrisLeft", "M_IrisRight"), "iris", 0.0, 1.0),
    "lacrimal": (("M_LacrimalFluid",), "lacrimal", 4.0, 0.5),
    "eyelashes": (("M_EyeLashes",), "eyelashes", 6.0, 1.0),
    "bust_cap": ((), "bust", 0.0, 1.0),  # built from the skin's boundary (split_parts)
}
SKIN_MATERIALS = ("M_Face", "M_BackHead")
HIDDEN_MATERIALS = ("M_EyeBlend", "M_EyeOcclusion")
#: Radius of the visible iris / cornea (limbus), metres (adult mean 11.7 mm diameter).
LIMBUS_RADIUS = 0.0058
PUPIL_RADIUS = 0.0017
#: How far the bust cap's apex lies beyond the cut's centroid, metres (:func:`cap_apex`):
#: the cone's faces slope 17-30 degrees out of the cut's plane (its radius 70-130 mm).
CAP_APEX = 0.04


@dataclass(frozen=True)
class Topology:
    """What the renderer needs of a head model besides its vertices.

    Attributes: faces (F, 3), uvs (T, 2) OpenGL convention (v up), uv_faces (F, 3),
    face_material (F,), material_names (M,), rest (N, 3): the model's rest vertices
    (``template``; None for an OBJ), where the eyes' axes are found (:func:`eye_axes`).
    """

    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    face_material: np.ndarray
    material_names: tuple[str, ...]
    rest: np.ndarray | None = field(default=None, compare=False)

    @property
    def num_vertices(self) -> int:
        return int(self.faces.max()) + 1

    @staticmethod
    def from_model(model) -> Topology:
        """From the geometry model (``faces``, ``uvs``, ``uv_faces``, ``face_material``,
        ``material_names``) or an ``ObjMesh`` (``materials``); torch tensors accepted."""
        def arr(x):
            return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)

        names = getattr(model, "material_names", None) or getattr(model, "materials", None)
        if names is None:
            raise HackError("head model: expected 'material_names' (or 'materials'), found "
                            "neither. Pass the geometry model or an ObjMesh.")
        rest = getattr(model, "template", None)   # the geometry model's rest vertices
        return Topology(arr(model.faces).astype(np.int64), arr(model.uvs).astype(np.float64),
                        arr(model.uv_faces).astype(np.int64),
                        arr(model.face_material).astype(np.int64), tuple(names),
                        None if rest is None else arr(rest).astype(np.float64))


@dataclass(frozen=True)
class Part:
    """One render mesh.

    Attributes:
        name: key of :data:`PART_SPECS`. region: index into :data:`REGIONS`.
        gather: (n,) model-vertex index of each part vertex.
        faces: (f, 3) indices into the part's vertices.
        texcoords: (n, 2) Mitsuba texture coordinates (v flipped: 1 - v).
        model_uv: (n, 2) the model's own (UDIM-style, v up) texture coordinates.
        flat: flat-shaded (no vertex normals: the bust cap, whose vertices are the skin's
            boundary, where the skin's normals point sideways).
        apex: metres: the part has one vertex more than ``gather``, last, at
            :func:`cap_apex` of the gathered ones (the bust cap's cone); 0: none.
    """

    name: str
    region: int
    gather: np.ndarray
    faces: np.ndarray
    texcoords: np.ndarray
    model_uv: np.ndarray
    flat: bool = False
    apex: float = 0.0

    @property
    def num_vertices(self) -> int:
        return len(self.gather) + (1 if self.apex else 0)

    def positions(self, vertices):
        """(num_vertices, 3) positions of the part in the posed mesh ``vertices`` (N, 3):
        the gathered ones, then the apex (:func:`cap_apex`). NumPy or torch (the
        differentiable render's bridge), either keeps its type and gradient."""
        p = vertices[self.gather]
        if not self.apex:
            return p
        out = p[[*range(len(p)), 0]]  # a copy, one row longer (autograd: a new tensor)
        out[-1] = cap_apex(p, self.apex)
        return out


EYE_SHELLS = ("M_ScleraLeft", "M_ScleraRight")
EYE_INNER = ("M_IrisLeft", "M_IrisRight")


def _sphere_axis(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, forward axis) of one eye's shell vertices: a least-squares sphere fit,
    and the direction to its front-most (+z) vertex."""
    sol = np.linalg.lstsq(np.c_[2 * v, np.ones(len(v))], (v ** 2).sum(1), rcond=None)[0]
    centre = sol[:3]
    front = v[np.argmax(v[:, 2])]
    return centre, (front - centre) / np.linalg.norm(front - centre)


def eye_axes(topo: Topology, vertices: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(centre, forward axis) of each eyeball (its ``M_Sclera*`` shell, one material per
    eye) in ``vertices`` (N, 3). Found where the head faces +z, on the model's rest
    vertices (``topo.rest``: a turned head's front-most shell vertex is not its cornea),
    and carried to ``vertices`` by the rigid (Kabsch) fit of that eye's shell and inner
    eye; without rest vertices (an OBJ), on ``vertices`` themselves."""
    names = topo.material_names
    out = []
    for shell, inner in zip(EYE_SHELLS, EYE_INNER):
        if shell not in names:
            continue
        idx = np.unique(topo.faces[topo.face_material == names.index(shell)])
        if len(idx) < 4:
            continue
        if topo.rest is None:
            out.append(_sphere_axis(vertices[idx]))
            continue
        rest = np.asarray(topo.rest, np.float64)
        centre, axis = _sphere_axis(rest[idx])
        mats = [names.index(m) for m in (shell, inner) if m in names]
        eye = np.unique(topo.faces[np.isin(topo.face_material, mats)])
        r, t = kabsch(rest[eye], np.asarray(vertices, np.float64)[eye])
        out.append((r @ centre + t, r @ axis))
    return out


def radial_eye_distance(points: np.ndarray, axes) -> tuple[np.ndarray, np.ndarray]:
    """For points (n, 3): distance from the nearest eye's optical axis, and the offset along
    it from the eye centre (positive in front). Both (n,), metres."""
    centres = np.stack([c for c, _ in axes])
    nearest = np.argmin(np.linalg.norm(points[:, None] - centres[None], axis=2), axis=1)
    axis = np.stack([a for _, a in axes])[nearest]
    d = points - centres[nearest]
    z = np.einsum("ij,ij->i", d, axis)
    r = np.linalg.norm(d - z[:, None] * axis, axis=1)
    return r, z


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary edges (edges of one face) of a triangle mesh (F, 3), each
    an array of vertex indices in order. Assumes a manifold boundary (two boundary edges
    per boundary vertex), as ICT's skin has."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    pair = np.sort(e, axis=1).astype(np.int64)
    # one integer per undirected edge: a 1-D unique, ~10x faster than unique rows
    key = pair[:, 0] * (int(pair.max(initial=0)) + 1) + pair[:, 1]
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    directed = e[counts[inv.ravel()] == 1]  # boundary edges, in their face's winding
    nxt = dict(zip(directed[:, 0].tolist(), directed[:, 1].tolist()))
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        if v == start and len(loop) >= 3:
            loops.append(np.array(loop, np.int64))
    return loops


def cap_apex(loop, depth: float):
    """The apex of the bust cap's cone over a closed loop (n, 3) in order: its centroid
    moved ``depth`` metres along the loop's Newell normal (the sum of r_i x r_i+1, whose
    sign follows the loop's winding; a negative depth goes against it). NumPy or torch."""
    q = loop[[*range(1, len(loop)), 0]]
    n = (loop[:, [1, 2, 0]] * q[:, [2, 0, 1]] - loop[:, [2, 0, 1]] * q[:, [1, 2, 0]]).sum(0)
    return loop.mean(0) + depth * n / (n * n).sum() ** 0.5


def bust_cap(topo: Topology, vertices: np.ndarray) -> Part | None:
    """The part closing the skin's lowest boundary loop (the chest/shoulder cut), or None
    when the skin has no boundary: a fan of one triangle per loop edge to the apex
    (:func:`cap_apex`, :data:`CAP_APEX` out of the body), facing away from the head."""
    ids = [topo.material_names.index(m) for m in SKIN_MATERIALS if m in topo.material_names]
    faces = topo.faces[np.isin(topo.face_material, ids)]
    loops = boundary_loops(faces)
    if not loops:
        return None
    loop = min(loops, key=lambda lp: vertices[lp, 1].mean())
    p = vertices[loop]
    # out of the body: away from the skin's centroid (the winding fixes the Newell
    # normal's side of the loop for every pose, so the sign is chosen once)
    out = np.sign(np.dot(cap_apex(p, 1.0) - p.mean(0), p.mean(0) - vertices[np.unique(faces)].mean(0)))
    depth = float(out or 1.0) * CAP_APEX
    n = len(loop)
    tri = np.stack([np.arange(n), np.roll(np.arange(n), -1), np.full(n, n)], 1)
    a = cap_apex(p, depth)
    f = np.concatenate([p, a[None]])[tri]
    if np.dot(np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0]).sum(0), a - p.mean(0)) < 0:
        tri = tri[:, ::-1].copy()
    zeros = np.zeros((n + 1, 2))
    return Part("bust_cap", REGIONS.index("bust"), loop, tri, zeros, zeros, flat=True,
                apex=depth)


def split_parts(topo: Topology, vertices: np.ndarray,
                cap: bool = False) -> tuple[list[Part], list]:
    """Build the render parts from the topology and rest vertices (N, 3) metres.

    Parts whose materials are absent are skipped (a model without eyes still renders);
    ``cap`` adds the bust cap (:func:`bust_cap`) closing the cut of the skin.
    Returns the parts and the eye axes [(centre (3,), forward axis (3,)), ...].
    """
    names = topo.material_names
    missing_skin = [m for m in ("M_Face", "M_BackHead") if m not in names]
    if len(missing_skin) == 2:
        raise HackError(f"head model: expected ICT materials M_Face/M_BackHead, found "
                        f"{', '.join(names)}. Use the HACK default model or its OBJ.")
    axes = eye_axes(topo, vertices)
    parts = []
    for pname, (mats, region, u_off, u_scale) in PART_SPECS.items():
        ids = [names.index(m) for m in mats if m in names]
        sel = np.isin(topo.face_material, ids)
        if pname == "sclera" and axes:
            # open the shell over the cornea: drop faces whose centroid lies inside the limbus
            r, z = radial_eye_distance(vertices[topo.faces].mean(1), axes)
            sel &= (r > LIMBUS_RADIUS) | (z < 0)
        if not mats or not sel.any():
            continue
        f, tf = topo.faces[sel], topo.uv_faces[sel]
        # (vertex, uv vertex) pairs as one integer each, ordered as the pairs (a 1-D
        # unique: ~10x faster than unique rows)
        stride = np.int64(len(topo.uvs))
        key, inverse = np.unique(f.ravel().astype(np.int64) * stride + tf.ravel(),
                                 return_inverse=True)
        uniq = np.stack([key // stride, key % stride], axis=1)
        uv = topo.uvs[uniq[:, 1]]
        tc = np.stack([(uv[:, 0] - u_off) * u_scale, 1.0 - uv[:, 1]], axis=1)
        parts.append(Part(pname, REGIONS.index(region), uniq[:, 0],
                          inverse.reshape(-1, 3).astype(np.int64), tc, uv))
    if cap:
        part = bust_cap(topo, vertices)
        if part is not None:
            parts.append(part)
    return parts, axes


def uv_islands(faces: np.ndarray, n: int) -> np.ndarray:
    """Connected components of a triangle mesh (F, 3) over ``n`` vertices: (n,) island id
    of each vertex (0, 1, ..., in order of first vertex; unused vertices get their own)."""
    label = np.arange(n)
    while True:  # propagate the smallest label across faces until nothing changes
        low = label[faces].min(axis=1)
        new = label.copy()
        np.minimum.at(new, faces.ravel(), np.repeat(low, 3))
        new = new[new]  # pointer jumping: converges in a few dozen rounds for lash cards
        if np.array_equal(new, label):
            break
        label = new
    return np.unique(label, return_inverse=True)[1].reshape(-1)


def lash_cards(part: Part, vertices: np.ndarray, axes) -> np.ndarray:
    """The lash cards' rectangles in texture space, from the ``eyelashes`` part.

    ICT's lash part is 12 cards (three layers per lid), each its own UV island: one
    texture direction (Mitsuba's v) runs from the lid margin (the root) to the lash tips,
    the other (u) along the lid. The root is the island's v end nearer the eyeball's
    centre (``axes``); without eye axes it is the lower v, as in ICT's layout.

    Args:
        part: the ``eyelashes`` part. vertices: (N, 3) model vertices, metres.
        axes: the eye axes of :func:`split_parts` ([(centre (3,), axis (3,)), ...]).
    Returns:
        (C, 4) float64: u0, u1 (u0 < u1), v_root, v_tip in Mitsuba texture coordinates; (0, 4)
        when the UVs are degenerate (an island thinner than 1e-3 in u or v).
    """
    tc = part.texcoords
    island = uv_islands(part.faces, len(tc))
    p = vertices[part.gather]
    centres = np.stack([c for c, _ in axes]) if axes else None
    cards = []
    for i in range(island.max() + 1):
        sel = island == i
        if sel.sum() < 3:
            continue
        u, v = tc[sel, 0], tc[sel, 1]
        lo, hi = v.min(), v.max()
        if u.max() - u.min() < 1e-3 or hi - lo < 1e-3:
            return np.zeros((0, 4))
        root, tip = lo, hi
        if centres is not None:
            q = p[sel]
            c = centres[np.argmin(np.linalg.norm(centres - q.mean(0), axis=1))]
            r = np.linalg.norm(q - c, axis=1)
            end = 0.1 * (hi - lo)
            if r[v > hi - end].mean() < r[v < lo + end].mean():
                root, tip = hi, lo
        cards.append((u.min(), u.max(), root, tip))
    return np.array(cards, np.float64).reshape(-1, 4)
