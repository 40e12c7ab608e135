"""Growing a groom: a :class:`~hack_render.hair.style.HairStyle` turned into strands rooted
on the model's skin.

Every strand is rooted by barycentric coordinates on one skin triangle and stores its control
points in that triangle's frame (:func:`triangle_frames`: the first edge, the normal and
their cross product). Posing (:mod:`hack_render.hair.pose`) rebuilds each frame on the posed
mesh, so strands follow identity, expression (brows lift with AU1/AU2, beards move with the
jaw, lashes with the lids), the neck's pose and the larynx with no extra work.

Strands are grown once, on the model's mean rest mesh (``template_vertices``), by walking
each strand from its root: the first step follows the style's flow (away from the parting,
back from the crown), lifted off the scalp by ``volume``; later steps bend down with
``gravity``; each step is pushed out of the body to a per-strand shell (the hair's volume)
by the signed distance to the skin's nearest vertex. Curl is a helix about the strand added
after, pushed out again. The surface and the scalp's and beard's regions are
:mod:`hack_render.hair.regions`'s; the brows' band and the lids' margins are drawn below,
beside the strands they root. All are found on the mean mesh from its 68 landmarks and
head-frame angles; they are procedural, not segmented from data.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import numpy as np

from hack_render.geometry.nearest import PointTree
from hack_render.geometry.normals import cross3, norm3
from hack_render.hair.regions import HeadSurface, beard_mask, scalp_mask
from hack_render.hair.strands import (
    BodyProxy,
    Nearest,
    closest_on_triangles,
    cut_strands,
    polyline_distance,
    root_points,
    sample_triangles,
    tangent,
    triangle_frames,
    unit,
)
from hack_render.hair.style import HairStyle, pigment

#: Scalp strands at ``density`` 1 and ``lod`` 1 over the full scalp (hairline 0).
SCALP_STRANDS = 60_000
BROW_STRANDS = 650  # per brow
LASH_STRANDS = (110, 45)  # per eye: upper, lower lid
BEARD_STRANDS = {"stubble": 24_000, "goatee": 6_000, "full": 14_000}
#: Whorl (crown) of the flow, metres, model frame (y up, z forward, x the subject's left).
CROWN = np.array([0.0, 0.125, -0.06])
#: Where a ponytail / a bun gathers the hair.
PONYTAIL_GATHER = np.array([0.0, 0.055, -0.108])
BUN_GATHER = np.array([0.0, 0.105, -0.095])
DOWN = np.array([0.0, -1.0, 0.0])

#: The skin posed strands collide with: rest y under this, metres (all of it: another
#: identity's skull and forehead move against strands held in their roots' frames, and the
#: jaw's and neck's skin follow the neck's skinning).
BODY_BELOW = np.inf
#: Rest y (metres) above which the skin is skull: rigid with the hair rooted on it.
SKULL_ABOVE = 0.05
#: Strands end this far above the lowest skin point at rest (the bust's cut): below it the
#: model has no body to lie on (a longer strand is cut there, its last points gathered).
CUT_MARGIN = 0.03


@dataclass
class StrandGroup:
    """Strands of one kind (``scalp``, ``brows``, ``lashes``, ``beard``).

    tri (S,) face index of each root; bary (S, 3) its barycentric coordinates; local
    (S, K, 3) control points in the root triangle's frame, the first at the root (0);
    radius (K,) metres root to tip; melanin (S, 2) eumelanin, pheomelanin per strand."""

    name: str
    tri: np.ndarray
    bary: np.ndarray
    local: np.ndarray
    radius: np.ndarray
    melanin: np.ndarray
    #: (S, K) each control point's nearest skin vertex at rest, and (S, K, 3) where that
    #: vertex lies in the root's frame: posing tests a point against its anchor's tangent
    #: plane while the anchor moves with the strand, and searches afresh where it does not
    #: (:func:`hack_render.hair.pose.pose_group`)
    anchor: np.ndarray | None = None
    anchor_local: np.ndarray | None = None
    #: the draws its melanin is made of (``style.pigment``: (S, 1) tone, (S,) greying draw,
    #: the group's factors); :func:`recolour` makes another person's colour from them
    tone: np.ndarray | None = None
    white_draw: np.ndarray | None = None
    darker: float = 1.0
    grey: float = 1.0

    @property
    def num_strands(self) -> int:
        return int(self.tri.shape[0])

    @property
    def points_per_strand(self) -> int:
        return int(self.local.shape[1])


@dataclass
class Groom:
    """A style grown on a head surface: its strand groups and the faces they root in."""

    style: HairStyle
    groups: list[StrandGroup]
    faces: np.ndarray
    #: skin face indices (the collision proxy's vertices are theirs)
    skin: np.ndarray
    #: the skin vertices below the head (neck, chest, under the jaw) that posed strands are
    #: kept out of; the skull moves with the strands rooted on it
    body: np.ndarray | None = None

    @property
    def num_strands(self) -> int:
        return sum(g.num_strands for g in self.groups)

    def group(self, name: str) -> StrandGroup | None:
        return next((g for g in self.groups if g.name == name), None)


# --------------------------------------------------------------------------- growth
def _walk(proxy: BodyProxy, root: np.ndarray, normal: np.ndarray, d0: np.ndarray,
          length: np.ndarray, k: int, gravity: float, shell: np.ndarray,
          target: np.ndarray | None = None) -> np.ndarray:
    """Strands (S, K, 3) from ``root`` in direction ``d0``: ``k - 1`` equal steps of
    ``length / (k - 1)``, bending down with ``gravity``, each pushed out to ``shell``.
    ``target`` (3,): steer towards it (a ponytail's gather point) while farther than 1 cm."""
    s = len(root)
    pts = np.empty((s, k, 3))
    pts[:, 0] = root
    step = (length / (k - 1))[:, None]
    p = root + normal * np.minimum(shell, 0.0005)[:, None]
    d = d0
    reached = np.zeros((s, 1), bool)
    # each point is a step from the last, which is outside the skin: a point farther than a
    # step, the shell and a margin for the mesh's edges from every skin vertex is outside
    bound = float(step.max() + np.max(shell) + 0.01)
    for j in range(1, k):
        u = j / (k - 1)
        if target is not None:
            to = target - p
            reached |= (norm3(to) < 0.012)[:, None]
            d = np.where(reached, unit(d + 1.5 * DOWN), unit(0.4 * d + unit(to)))
        d = unit(d + gravity * (0.15 + 0.6 * u) * DOWN)
        q = proxy.push_out(p + step * d, shell, bound)
        d = unit(q - p)
        pts[:, j] = q
        p = q
    return pts


def _curl(pts: np.ndarray, amount: float, rng: np.random.Generator) -> np.ndarray:
    """A helix about each strand: radius and frequency grow with ``amount``, the root's
    first 1 cm eased in; phase random per strand."""
    if amount <= 0:
        return pts
    s = pts.shape[0]
    seg = norm3(np.diff(pts, axis=1))
    arc = np.concatenate([np.zeros((s, 1)), np.cumsum(seg, axis=1)], axis=1)
    tangent = unit(_gradient(pts))
    # the helper axis: y, or x where the tangent is nearly along y
    helper = np.zeros_like(tangent)
    along_y = np.abs(tangent[..., 1]) < 0.9
    helper[..., 1] = along_y
    helper[..., 0] = ~along_y
    u = unit(cross3(tangent, helper))
    w = cross3(tangent, u)
    radius = amount * (0.0008 + 0.0045 * amount) * np.clip(arc / 0.01, 0, 1)
    period = 0.09 - 0.078 * amount
    phase = rng.uniform(0, 2 * np.pi, (s, 1)) + 2 * np.pi * arc / period
    # pts + radius (cos u + sin w), in place (the same operations: the same bits)
    u *= np.cos(phase)[..., None]
    w *= np.sin(phase)[..., None]
    u += w
    u *= radius[..., None]
    u += pts
    return u


def _gradient(pts: np.ndarray) -> np.ndarray:
    """``np.gradient(pts, axis=1)`` (unit spacing, first-order edges): the same bits
    without its general set-up."""
    out = np.empty_like(pts)
    np.subtract(pts[:, 2:], pts[:, :-2], out=out[:, 1:-1])
    out[:, 1:-1] /= 2.0
    np.subtract(pts[:, 1], pts[:, 0], out=out[:, 0])
    np.subtract(pts[:, -1], pts[:, -2], out=out[:, -1])
    return out


def _to_local(v: np.ndarray, faces: np.ndarray, tri: np.ndarray, bary: np.ndarray,
              pts: np.ndarray, keep_root: bool = False) -> np.ndarray:
    frames = triangle_frames(v, faces[tri])
    root = root_points(v, faces, tri, bary)
    # np.einsum("sij,skj->ski", frames, d), its sum in the order it takes here (x and z,
    # then y): the same bits, without its set-up
    d = pts - root[:, None]
    f = frames[:, None]
    local = (f[..., 0] * d[..., 0:1] + f[..., 2] * d[..., 2:3]) + f[..., 1] * d[..., 1:2]
    if not keep_root:
        local[:, 0] = 0.0
    return local


def _melanin(style: HairStyle, s: int, rng: np.random.Generator, darker: float = 1.0,
             grey: float = 1.0) -> dict:
    """``s`` strands' draws and melanin (keywords of :class:`StrandGroup`)."""
    tone = rng.uniform(-1, 1, (s, 1))
    white_draw = rng.random(s)
    return {"melanin": pigment(style, tone, white_draw, darker, grey), "tone": tone,
            "white_draw": white_draw, "darker": darker, "grey": grey}


def recolour(groom: Groom, style: HairStyle) -> Groom:
    """``groom`` in ``style``'s colour: what :func:`grow` makes of ``style`` (bit for bit)
    when ``groom`` was grown from a style that differs only in :data:`COLOUR_FIELDS`. The
    strands' arrays are shared, not copied (nothing changes them in place)."""
    if groom.style.uncoloured() != style.uncoloured():
        raise ValueError("recolour: the styles differ in more than their colour.")
    groups = [g if g.tone is None else
              replace(g, melanin=pigment(style, g.tone, g.white_draw, g.darker, g.grey))
              for g in groom.groups]
    return replace(groom, style=style, groups=groups)


def body_vertices(surface: HeadSurface) -> np.ndarray:
    """Skin vertex indices of the body below the head (:data:`BODY_BELOW`)."""
    index = surface.skin_vertices
    return index if BODY_BELOW == np.inf else index[surface.vertices[index, 1] < BODY_BELOW]


def _group(name, surface, tri, bary, pts, radius, melanin,
           known: Nearest | None = None) -> StrandGroup:
    """The group of strands ``pts`` (S, K, 3) with each point's anchor (its nearest body
    vertex at rest). ``known``: the nearest skin vertices of ``pts[:, 1:]`` as the last
    push out found them (:meth:`BodyProxy.push_out`); only the points it does not hold
    unchanged (the roots, the points it moved, a cut strand's) are searched again, in the
    proxy's own tree where the body is its vertices (the same answer). ``melanin``: (S, 2),
    or :func:`_melanin`'s pigment with its draws."""
    body = body_vertices(surface)
    flat = pts.reshape(-1, 3)
    near = np.full(len(flat), -1, np.int64)
    tree = surface.skin_tree if body is surface.skin_vertices else None
    if known is not None and np.array_equal(known.proxy.index, body):
        tree = known.proxy.tree
        same = np.zeros(pts.shape[:2], bool)
        same[:, 1:] = (known.index >= 0) & np.all(known.points == pts[:, 1:], -1)
        idx = np.zeros(pts.shape[:2], np.int64)
        idx[:, 1:] = np.maximum(known.index, 0)
        near[same.reshape(-1)] = idx[same]
    todo = near < 0
    if todo.any():
        tree = tree if tree is not None else PointTree(surface.vertices[body])
        near[todo] = tree.query(flat[todo])[1]
    anchor = body[near].reshape(pts.shape[:2]).astype(np.int32)
    v, f = surface.vertices, surface.faces
    # only the skull moves with the strands rooted on it: points over the face, the jaw,
    # the ears, the neck and the shoulders are searched afresh in every pose (-1)
    anchor = np.where(v[anchor, 1] > SKULL_ABOVE, anchor, -1).astype(np.int32)
    colour = melanin if isinstance(melanin, dict) else {"melanin": melanin}
    return StrandGroup(name, tri, bary, _to_local(v, f, tri, bary, pts),
                       np.asarray(radius, np.float64), anchor=anchor,
                       anchor_local=_to_local(v, f, tri, bary, v[np.maximum(anchor, 0)],
                                              keep_root=True).astype(np.float32), **colour)


def _taper(r: float, k: int, tip: float = 0.45) -> np.ndarray:
    return r * np.linspace(1.0, tip, k)


def _scalp(surface: HeadSurface, style: HairStyle, proxy: BodyProxy,
           rng: np.random.Generator) -> StrandGroup | None:
    if style.bald:
        return None
    full = scalp_mask(surface, HairStyle(lod=style.lod))
    cand, weight = scalp_mask(surface, style)
    v, f = surface.vertices, surface.faces
    area = lambda c, w: float(np.sum(w * 0.5 * norm3(cross3(
        v[f[c, 1]] - v[f[c, 0]], v[f[c, 2]] - v[f[c, 0]]))))
    count = round(SCALP_STRANDS * style.density * style.lod *
                      area(cand, weight) / max(area(*full), 1e-12))
    tri, bary = sample_triangles(v, f, cand, count, rng, weight)
    if len(tri) == 0:
        return None
    root = root_points(v, f, tri, bary)
    normal = unit(np.einsum("sk,skc->sc", bary, surface.normals[f[tri]]))
    arch = style.archetype
    length = style.length * rng.uniform(0.85, 1.1, len(tri))
    short = style.length < 0.02
    # the flow: away from the parting at the top front, back and down from the crown
    radial = root - CROWN
    if style.parting == "none" or arch in ("ponytail", "bun"):
        flow = radial * [0.3, 0.2, 0.3] + np.array([0.0, -0.3, -1.0])
    else:
        xp = {"left": 0.03, "right": -0.03, "centre": 0.0}[style.parting]
        side = np.sign(root[:, 0] - xp + 1e-9)[:, None]
        top_front = np.clip((root[:, 2:3] + 0.02) / 0.06, 0, 1) * \
            np.clip((root[:, 1:2] - 0.08) / 0.03, 0, 1)
        flow = top_front * (side * [1.0, 0.0, 0.0] + [0.0, -0.15, -0.45]) + \
            (1 - top_front) * unit(radial * [1.0, 1.0, 0.25] + [0.0, -0.04, -0.03])
    t = tangent(flow, normal)
    lift = 0.08 + 0.55 * style.volume if arch != "afro" else 0.9
    d0 = unit((1 - lift) * t + lift * normal)
    curly = style.curl > 0.3
    seg = 0.004 if short else (0.006 if curly else 0.016)
    k = int(np.clip(round(style.length / seg) + 1, 4, 40))
    layer = rng.random(len(tri))
    # off the mean scalp by >= 3 mm (what another identity's skull moves against a strand
    # held in its root's frame), 0.4 mm for the shortest hair
    shell = (0.0004 if short else 0.003) + (0.002 + 0.012 * style.volume) * layer * (not short)
    target = {"ponytail": PONYTAIL_GATHER, "bun": BUN_GATHER}.get(arch)
    gravity = style.gravity * (0.0 if short else 1.0)
    if target is not None:
        reach = norm3(root - target) * 1.15
        length = np.maximum(length, reach + 0.02)
        k = max(k, 24)
        shell = 0.003 + 0.002 * layer
    pts = _walk(proxy, root, normal, d0, length, k, gravity, shell, target)
    if arch == "bun":
        pts = _bun(pts, root, rng)
    pts = _curl(pts, style.curl, rng)
    pts[:, 1:], known = proxy.push_out(pts[:, 1:], shell[:, None] * 0.5 + 0.0003, index=True)
    pts = cut_strands(pts, v[surface.skin_vertices, 1].min() + CUT_MARGIN)
    return _group("scalp", surface, tri, bary, pts, _taper(style.strand_radius, k),
                  _melanin(style, len(tri), rng), known)


def _bun(pts: np.ndarray, root: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The points past the gather wound round a ball behind it (a bun)."""
    s, k, _ = pts.shape
    gathered = norm3(pts - BUN_GATHER) < 0.014
    first = np.where(gathered.any(1), gathered.argmax(1), k - 1)
    centre = BUN_GATHER + np.array([0.0, 0.008, -0.024])
    axis = unit(rng.normal(size=(s, 3)))
    start = unit(BUN_GATHER - centre)[None].repeat(s, 0)
    u = tangent(start, axis)
    w = cross3(axis, u)
    radius = rng.uniform(0.016, 0.027, s)
    out = pts.copy()
    for j in range(k):
        a = np.clip(j - first, 0, None) * 0.45
        ring = centre + radius[:, None] * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * w)
        out[:, j] = np.where((j > first)[:, None], ring, pts[:, j])
    return out


def _brows(surface: HeadSurface, style: HairStyle, proxy: BodyProxy,
           rng: np.random.Generator) -> StrandGroup | None:
    count = round(BROW_STRANDS * style.brow_density * style.lod)
    if count <= 0:
        return None
    v, f, lm = surface.vertices, surface.faces, surface.vertices[surface.landmarks]
    cent = surface.skin_centroids
    front = cent[:, 2] > 0.05
    tris, barys, pts_all = [], [], []
    for idx, lateral in ((range(17, 22), -1.0), (range(22, 27), 1.0)):
        line = lm[list(idx), :2].copy()
        s_line = np.linspace(0, 1, len(line))
        line[:, 1] += 0.004 * style.brow_arch * np.sin(np.pi * s_line) - 0.0015
        dist, s = polyline_distance(cent[:, :2], line)
        # medial end (s=1 for the right brow's 17..21, s=0 for the left's 22..26) thicker
        medial = s if lateral < 0 else 1 - s
        half = 0.0032 * style.brow_thickness * (0.55 + 0.45 * medial)
        inside = front & (dist < half) & (np.abs(cent[:, 0]) > 0.006)
        cand = surface.skin[inside]
        tri, bary = sample_triangles(v, f, cand, count, rng)
        if len(tri) == 0:
            continue
        root = root_points(v, f, tri, bary)
        normal = unit(np.einsum("sk,skc->sc", bary, surface.normals[f[tri]]))
        _, s_root = polyline_distance(root[:, :2], line)
        medial = s_root if lateral < 0 else 1 - s_root
        d = lateral * np.array([1.0, 0.0, 0.0])[None] * (1 - 0.7 * medial[:, None]) + \
            np.array([0.0, 1.0, 0.0])[None] * (0.25 + 0.8 * medial[:, None])
        d0 = unit(tangent(d, normal) + 0.25 * normal)
        length = 0.0075 * rng.uniform(0.7, 1.2, len(tri))
        pts = _walk(proxy, root, normal, d0, length, 4, 0.0, np.full(len(tri), 0.0004))
        tris.append(tri)
        barys.append(bary)
        pts_all.append(pts)
    if not tris:
        return None
    tri, bary, pts = np.concatenate(tris), np.concatenate(barys), np.concatenate(pts_all)
    return _group("brows", surface, tri, bary, pts, _taper(style.strand_radius * 1.1, 4, 0.3),
                  _melanin(style, len(tri), rng, darker=1.15, grey=0.5))


def _lashes(surface: HeadSurface, style: HairStyle, rng: np.random.Generator
            ) -> StrandGroup | None:
    if style.lash_length <= 0 or style.lod <= 0:
        return None
    v, f, lm = surface.vertices, surface.faces, surface.vertices[surface.landmarks]
    tris, barys, pts_all = [], [], []
    lids = (((36, 37, 38, 39), 1), ((42, 43, 44, 45), 1), ((39, 40, 41, 36), -1),
            ((45, 46, 47, 42), -1))
    for idx, up in lids:
        n = max(4, round(LASH_STRANDS[0 if up > 0 else 1] * min(style.lod, 1.5)))
        line = lm[list(idx)]
        cum = np.r_[0, np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=-1))]
        s = np.sort(rng.uniform(0.06, 0.94, n)) * cum[-1]
        anchor = np.stack([np.interp(s, cum, line[:, c]) for c in range(3)], -1)
        tri, bary = closest_on_triangles(v, f, surface.skin, anchor, surface.centroid_tree)
        root = root_points(v, f, tri, bary)
        t = s / cum[-1]
        middle = np.sin(np.pi * t)[:, None]  # longest in the middle of the lid
        length = (0.0095 if up > 0 else 0.006) * style.lash_length * (0.55 + 0.45 * middle[:, 0])
        out = unit(root - np.array([np.sign(root[:, 0].mean()) * 0.031, 0.035, 0.06]))
        d0 = unit(np.array([0.0, 0.0, 1.0]) + out * 0.6 + up * np.array([0.0, 0.35, 0.0]))
        k = 5
        pts = np.empty((len(tri), k, 3))
        bend = up * style.lash_curl * 1.1
        for j in range(k):
            u = j / (k - 1)
            ang = bend * u * u
            dj = unit(d0 * np.cos(ang) + np.array([0.0, 1.0, 0.0]) * np.sin(ang))
            pts[:, j] = root + length[:, None] * u * dj
        tris.append(tri)
        barys.append(bary)
        pts_all.append(pts)
    tri, bary, pts = np.concatenate(tris), np.concatenate(barys), np.concatenate(pts_all)
    return _group("lashes", surface, tri, bary, pts, _taper(style.strand_radius * 1.2, 5, 0.3),
                  _melanin(style, len(tri), rng, darker=1.4, grey=0.3))


def _beard(surface: HeadSurface, style: HairStyle, proxy: BodyProxy,
           rng: np.random.Generator) -> StrandGroup | None:
    if style.beard == "none":
        return None
    v, f = surface.vertices, surface.faces
    cand = beard_mask(surface, style.beard)
    count = round(BEARD_STRANDS[style.beard] * style.lod)
    tri, bary = sample_triangles(v, f, cand, count, rng)
    if len(tri) == 0:
        return None
    root = root_points(v, f, tri, bary)
    normal = unit(np.einsum("sk,skc->sc", bary, surface.normals[f[tri]]))
    stubble = style.beard == "stubble"
    length = (0.0012 if stubble else style.beard_length) * rng.uniform(0.7, 1.2, len(tri))
    d0 = unit(tangent(np.broadcast_to(DOWN + [0, 0, 0.3], root.shape), normal) +
               (0.6 if stubble else 0.35) * normal)
    k = 4 if stubble else int(np.clip(round(style.beard_length / 0.004) + 1, 4, 12))
    shell = np.full(len(tri), 0.0003) if stubble else 0.0004 + 0.004 * rng.random(len(tri))
    pts = _walk(proxy, root, normal, d0, length, k, 0.0 if stubble else 0.3, shell)
    known = None
    if not stubble:
        pts = _curl(pts, 0.35, rng)
        pts[:, 1:], known = proxy.push_out(pts[:, 1:], 0.0003, index=True)
    return _group("beard", surface, tri, bary, pts,
                  _taper(style.strand_radius * (1.0 if stubble else 1.3), k, 0.4),
                  _melanin(style, len(tri), rng, grey=1.3), known)


class GroomCache:
    """Grooms grown on surfaces, remembered by their strands' key (the surface and the
    style without its colour, :meth:`HairStyle.uncoloured`) for the last ``size`` keys: a
    style whose strands were grown is only recoloured (:func:`recolour`). Thread-safe."""

    def __init__(self, size: int):
        self.size = int(size)
        self._grooms: dict = {}
        self._lock = threading.Lock()

    def get(self, surface: HeadSurface, style: HairStyle) -> Groom:
        key = (surface.digest, style.uncoloured())
        with self._lock:
            known = self._grooms.get(key)
        if known is not None:
            return recolour(known, style)
        groom = grow(surface, style)
        with self._lock:
            while self._grooms and len(self._grooms) >= self.size:
                self._grooms.pop(next(iter(self._grooms)))
            self._grooms.update({key: groom} if self.size > 0 else {})
        return groom


_CACHE = GroomCache(4)


def grow_cached(surface: HeadSurface, style: HairStyle) -> Groom:
    """:func:`grow`, remembered for this process's last few strands' keys (renders reuse)."""
    return _CACHE.get(surface, style)


def grow(surface: HeadSurface, style: HairStyle) -> Groom:
    """The groom of ``style`` on ``surface`` (deterministic in ``style.seed``)."""
    rng = np.random.default_rng(style.seed)
    proxy = BodyProxy.of(surface)
    groups = [g for g in (_scalp(surface, style, proxy, rng),
                          _brows(surface, style, proxy, rng),
                          _lashes(surface, style, rng),
                          _beard(surface, style, proxy, rng)) if g is not None]
    return Groom(style, groups, surface.faces, surface.skin, body_vertices(surface))
