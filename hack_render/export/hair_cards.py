"""Hair, brows, lashes and beards as alpha-textured cards for the rigged glTF (issue 61).

Game engines, three.js and Blender's glTF importer take hair as *cards*: ribbons of
triangles with a texture whose alpha draws strands and leaves gaps. A groom
(:mod:`hack_render.hair.groom`: strands rooted by barycentric coordinates on skin
triangles) becomes cards here, per strand group (scalp, brows, lashes, beard):

- clumps: the group's strands are clustered (k-means on the root position and the
  strand's initial direction, :func:`clump_labels`) into about one card per
  :data:`STRANDS_PER_CARD` strands;
- a card per clump: a ribbon of two columns along the clump's mean strand (moved so that
  it starts at the root of the clump's most central strand, a point on the skin), as wide
  as the clump's spread across it (:data:`CARD_WIDTH` bounds), lying across the skin's
  normal at its root (a ribbon seen from above the scalp, not turned to any camera; the
  material is two-sided). The root row's two vertices are the skin points nearest to the
  ribbon's edges, each with its own triangle and barycentric coordinates; the rows above
  are kept :data:`SHELL` outside the skin at rest;
- skinning: every vertex of a card's column takes the barycentric blend of its root
  triangle's skin weights (the model's, then kept to the file's 4 or 8 influences as the
  head's are, :func:`hack_render.export.rig.top_weights`), and the same blend of the
  triangle's morph deltas in every morph target: so a card moves rigidly with the skin
  point it is rooted in under expressions (brows lift with AU1/AU2, beards follow the
  jaw), the larynx and the pose correctives, as well as the joints. Cards do not bend
  with the skin; the roots stay on it;
- the texture: a procedural RGBA strand image per group (:func:`strand_texture`), strand
  colours drawn from the group's own per-strand melanin (greying included) through
  :func:`melanin_rgb`, alpha 0 between strands (``alphaMode`` MASK, two-sided).

Colour: an approximate melanin to linear-RGB mapping, not a render of the hair BSDF:
the absorption coefficient of Blender's Principled Hair BSDF (after d'Eon et al. 2011,
"An energy-conserving hair reflectance model"), ``sigma_a = eumelanin * (0.506, 0.841,
1.653) + pheomelanin * (0.343, 0.733, 1.924)``, and the colour ``exp(-sigma_a * PATH)``
(plus :data:`MELANIN_FLOOR`) with :data:`MELANIN_PATH` chosen so that the named colours of ``--hair-color`` read as
their names as a base colour (eumelanin 0.3 blonde, 1.3 brown, 8 black).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.export.rig import top_weights
from hack_render.hair.groom import Groom, grow_cached
from hack_render.hair.pose import pose_groom
from hack_render.hair.regions import HeadSurface
from hack_render.hair.strands import BodyProxy, closest_on_triangles, triangle_frames
from hack_render.hair.style import NAMED_COLOURS, HairStyle
from hack_render.render.hair_options import hair_style as resolve_hair_style

#: Strands per card, by group: about 2,000 scalp cards for a full head at lod 1.
STRANDS_PER_CARD = {"scalp": 30, "brows": 6, "lashes": 4, "beard": 10}
#: (min, max) card width, metres, by group.
CARD_WIDTH = {"scalp": (0.004, 0.035), "brows": (0.002, 0.012), "lashes": (0.0015, 0.006),
              "beard": (0.003, 0.02)}
#: Widest card relative to its length, by group (short hair: stubble, brows, crew cuts).
MAX_ASPECT = {"scalp": 0.6, "brows": 0.5, "lashes": 0.6, "beard": 0.7}
#: Most rows per card (a long strand's control points are resampled to these).
MAX_ROWS = 10
#: Rows above the root are kept this far outside the skin at rest, metres.
SHELL = 0.0008
#: Absorption of eumelanin and pheomelanin (Blender's Principled Hair BSDF, d'Eon 2011).
EUMELANIN_SIGMA = np.array([0.506, 0.841, 1.653])
PHEOMELANIN_SIGMA = np.array([0.343, 0.733, 1.924])
#: Path length (in units of the absorption's) of the colour ``exp(-sigma_a * path)``:
#: chosen by eye, so that eumelanin 0.3 reads blonde, 1.3 brown, 8 black.
MELANIN_PATH = 2.5
#: What a fibre returns whatever its pigment (its surface, light from its neighbours):
#: chosen, so that dark brown is not read as red (eumelanin 8 stays near black).
MELANIN_FLOOR = 0.015
#: Texture size (width across the card, height root to tip) and strands drawn across.
TEXTURE_SIZE = (128, 512)
#: Per group: strands drawn across the texture and their half width at the root (min,
#: max), texels: dense scalp cards, sparser brows and beards, a few lashes.
TEXTURE_STRANDS = {"scalp": (40, 1.1, 2.0), "brows": (26, 0.9, 1.5), "lashes": (6, 6.0, 9.0),
                   "beard": (34, 1.0, 1.7)}
#: Perceptual roughness of the cards' material.
HAIR_ROUGHNESS = 0.45
#: Alpha below which a card's texel is cut (glTF ``alphaMode`` MASK): under 0.5, so the
#: strands still cover where a renderer's mipmaps average them with the gaps.
HAIR_ALPHA_CUTOFF = 0.35


def melanin_rgb(eumelanin, pheomelanin) -> np.ndarray:
    """Approximate linear RGB (..., 3) in [0, 1] of hair with these melanin concentrations
    (see the module docstring): melanin 0 is white, eumelanin 8 near black."""
    eu = np.asarray(eumelanin, np.float64)[..., None]
    pheo = np.asarray(pheomelanin, np.float64)[..., None]
    absorbed = np.exp(-(eu * EUMELANIN_SIGMA + pheo * PHEOMELANIN_SIGMA) * MELANIN_PATH)
    return MELANIN_FLOOR + (1.0 - MELANIN_FLOOR) * absorbed


def hair_style(spec: str | None, colour: str | None, params_hair=None) -> HairStyle | None:
    """The style `export --hair SPEC --hair-color COLOUR` asks for, or None (no hair).

    The options mean what they mean for `render` and `turntable`
    (:func:`hack_render.render.hair_options.hair_style`, which checks them): ``spec`` an
    archetype name, ``none``, or a JSON/YAML file whose ``hair`` section (or, without
    one, the whole mapping) is the style; None: the parameter file's ``hair`` section
    ``params_hair`` if it has one, else no hair. ``colour``: a name or
    ``EUMELANIN,PHEOMELANIN`` that replaces the style's melanin. A bald style without
    brows, lashes or beard has no cards: None."""
    style = resolve_hair_style(spec, colour, params_hair)
    if style is None or (style.bald and not _has_facial_hair(style)):
        return None
    return style


def _has_facial_hair(style: HairStyle) -> bool:
    """A bald style still has brows and lashes (and perhaps a beard)."""
    return style.brow_density > 0 or style.lash_length > 0 or style.beard != "none"


@dataclass
class CardGroup:
    """One strand group's cards (V vertices, T triangles, C cards).

    Attributes:
        name: ``scalp``, ``brows``, ``lashes`` or ``beard``.
        positions: (V, 3) rest positions (the rig's base mesh), metres.
        normals: (V, 3) unit; uv: (V, 2) u across the card (0 left, 1 right), v along it
            (0 root, 1 tip).
        faces: (T, 3) vertex indices.
        tri: (V,) the skin triangle (model face index) each vertex's column is rooted in;
            bary: (V, 3) the root's barycentric coordinates in it.
        root: (V,) True on each card's first row (the points on the skin).
        card: (V,) card index of each vertex.
        texture: (H, W, 4) linear RGB + alpha, the strands' image.
        strands: strands in the group; melanin: (2,) the group's mean (eumelanin,
            pheomelanin).
    """

    name: str
    positions: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    tri: np.ndarray
    bary: np.ndarray
    root: np.ndarray
    card: np.ndarray
    texture: np.ndarray
    strands: int
    melanin: np.ndarray

    @property
    def num_cards(self) -> int:
        return int(self.card.max()) + 1 if len(self.card) else 0

    def skin_weights(self, weights: np.ndarray, faces: np.ndarray, influences: int
                     ) -> tuple[np.ndarray, np.ndarray]:
        """(joints (V, I), weights (V, I)): the barycentric blend of the root triangle's
        vertices' skin weights ``weights`` (N, J), kept to ``influences`` as the head's."""
        return top_weights(blend(weights, faces, self.tri, self.bary), influences)

    def morph(self, delta: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(V, 3) a morph target's deltas on the cards: the root point's (the blend of its
        triangle's vertex deltas ``delta`` (N, 3))."""
        return blend(delta, faces, self.tri, self.bary)


def blend(values: np.ndarray, faces: np.ndarray, tri: np.ndarray, bary: np.ndarray
          ) -> np.ndarray:
    """Barycentric blend (P, C) of per-vertex ``values`` (N, C) over triangles ``tri``."""
    v = np.asarray(values)
    return np.einsum("pk,pkc->pc", bary.astype(np.float64), v[faces[tri]].astype(np.float64))


def clump_labels(features: np.ndarray, k: int, rng: np.random.Generator, iterations: int = 8
                 ) -> np.ndarray:
    """Cluster labels (S,) in 0..k'-1 (k' <= k, no empty cluster) of ``features`` (S, D):
    k-means (Lloyd) from k distinct random strands."""
    from scipy.spatial import cKDTree

    s = len(features)
    k = max(1, min(k, s))
    centres = features[rng.choice(s, k, replace=False)]
    labels = np.zeros(s, np.int64)
    for _ in range(iterations):
        _, labels = cKDTree(centres).query(features, workers=-1)
        counts = np.bincount(labels, minlength=len(centres))
        keep = counts > 0
        sums = np.stack([np.bincount(labels, features[:, d], len(centres))
                         for d in range(features.shape[1])], 1)
        centres = sums[keep] / counts[keep, None]
    _, labels = cKDTree(centres).query(features, workers=-1)
    return np.unique(labels, return_inverse=True)[1].reshape(-1)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def strand_texture(melanin: np.ndarray, rng: np.random.Generator,
                   size: tuple[int, int] = TEXTURE_SIZE,
                   strands: tuple[int, float, float] = TEXTURE_STRANDS["scalp"]
                   ) -> np.ndarray:
    """A procedural strand image (H, W, 4), linear RGB + alpha: ``strands`` (count, half
    width at the root: min, max texels) tapered,
    slightly wavy strands from the root (row 0) to the tip, each coloured as one strand
    of ``melanin`` (S, 2) drawn at random (so greying shows as white strands), darker at
    the root; alpha 0 between them. The gaps take the strands' mean colour (no dark
    fringes where a renderer filters across the alpha's edge)."""
    w, h = size
    strands, thin, thick = strands
    x = np.arange(w)[None, :] + 0.5
    v = (np.arange(h)[:, None] + 0.5) / h
    alpha = np.zeros((h, w))
    rgb = np.zeros((h, w, 3))
    pick = melanin[rng.integers(0, len(melanin), strands)]
    colours = melanin_rgb(pick[:, 0], pick[:, 1]) * rng.uniform(0.8, 1.15, (strands, 1))
    slots = (np.arange(strands) + rng.uniform(0.2, 0.8, strands)) * w / strands
    for j in range(strands):
        length = rng.uniform(0.7, 1.0)
        half = rng.uniform(thin, thick) * np.clip(1.0 - 0.7 * v / length, 0.0, 1.0)
        wave = rng.uniform(0.5, 2.0) * np.sin(2 * np.pi * (rng.uniform(0.5, 2.0) * v
                                                           + rng.uniform()))
        cover = np.clip(half + 0.5 - np.abs(x - slots[j] - wave), 0.0, 1.0)
        cover = np.where(v <= length, cover, 0.0)
        shade = 0.75 + 0.25 * np.clip(v / 0.15, 0.0, 1.0)  # darker near the root
        on = cover > alpha
        rgb = np.where(on[..., None], np.clip(colours[j] * shade[..., None], 0, 1), rgb)
        alpha = np.maximum(alpha, cover)
    mean = colours.mean(0).clip(0, 1)
    rgb = np.where((alpha > 0)[..., None], rgb, mean)
    return np.concatenate([rgb, alpha[..., None]], -1)


def groom_for(model, style: HairStyle) -> Groom:
    """The style's groom on the model's mean rest mesh (cached per process)."""
    return grow_cached(HeadSurface.from_model(model), style)


def build_cards(groom: Groom, base: np.ndarray, faces: np.ndarray, seed: int = 0
                ) -> list[CardGroup]:
    """Cards of every strand group of ``groom`` posed on the rest mesh ``base`` (N, 3)
    (the rig's: the person's identity baked in); ``faces`` the model's (F, 3)."""
    base = np.asarray(base, np.float64)
    posed = pose_groom(groom, base)
    proxy = BodyProxy(base, faces, groom.skin)
    frames = triangle_frames(base, faces)
    out = []
    for i, g in enumerate(groom.groups):
        if g.num_strands == 0:
            continue
        rng = np.random.default_rng([seed, i])
        out.append(_cards(g, posed[g.name], base, faces, groom.skin, frames, proxy, rng))
    return out


def _cards(g, pts: np.ndarray, base, faces, skin, frames, proxy, rng) -> CardGroup:
    if pts.shape[1] > MAX_ROWS:  # long strands: fewer rows (every row costs morph data)
        t = np.linspace(0.0, pts.shape[1] - 1, MAX_ROWS)
        lo = np.minimum(t.astype(np.int64), pts.shape[1] - 2)
        a = (t - lo)[None, :, None]
        pts = (1 - a) * pts[:, lo] + a * pts[:, lo + 1]
    s, k = pts.shape[:2]
    radius = np.interp(np.linspace(0, 1, k), np.linspace(0, 1, len(g.radius)), g.radius)
    root = pts[:, 0]
    direction = _unit(pts[:, min(1, k - 1)] - root)
    n_cards = max(1, round(s / STRANDS_PER_CARD.get(g.name, 20)))
    labels = clump_labels(np.concatenate([root, 0.01 * direction], 1), n_cards, rng)
    order = np.argsort(labels, kind="stable")
    starts = np.r_[0, np.flatnonzero(np.diff(labels[order])) + 1, s]
    wmin, wmax = CARD_WIDTH.get(g.name, (0.003, 0.02))
    lines, halves, sides, anchors = [], [], [], []
    for c in range(len(starts) - 1):
        m = order[starts[c]:starts[c + 1]]
        mean = pts[m].mean(0)  # (K, 3)
        centre = m[np.argmin(np.linalg.norm(root[m] - mean[0], axis=1))]
        line = mean - mean[0] + root[centre]
        normal = frames[g.tri[centre], 2]
        tangent = _unit(np.gradient(line, axis=0)) if k > 1 else normal[None]
        side = np.cross(tangent, normal)
        spread = root[m] - root[m].mean(0)
        axis = np.linalg.svd(spread, full_matrices=False)[2][0] if len(m) > 2 else \
            frames[g.tri[centre], 0]
        across = axis - np.sum(axis * tangent, -1, keepdims=True) * tangent
        weak = np.linalg.norm(side, axis=-1) < 0.3
        side = np.where(weak[:, None], across, side)
        side = np.where((np.linalg.norm(side, axis=-1) < 1e-6)[:, None],
                        frames[g.tri[centre], 0], side)
        side = _unit(side)
        for r in range(1, k):  # one orientation along the card
            if np.dot(side[r], side[r - 1]) < 0:
                side[r] = -side[r]
        offset = np.abs(np.einsum("skc,kc->sk", pts[m] - mean, side))  # (S_c, K)
        width = np.clip(2.0 * np.percentile(offset, 80, axis=0) + 2 * radius, wmin, wmax)
        length = np.linalg.norm(np.diff(line, axis=0), axis=1).sum()
        width = np.minimum(width, max(wmin, MAX_ASPECT.get(g.name, 0.6) * length))  # no square patches
        lines.append(line)
        halves.append(width / 2)
        sides.append(side)
        anchors.append(centre)
    line, half, side = np.stack(lines), np.stack(halves), np.stack(sides)  # (C, K, ...)
    n = len(line)
    edges = np.stack([line - half[..., None] * side, line + half[..., None] * side], 2)
    # the root row: the skin points nearest to the ribbon's two root corners
    tri, bary = closest_on_triangles(base, faces, skin, edges[:, 0].reshape(-1, 3))
    edges[:, 0] = np.einsum("pk,pkc->pc", bary, base[faces[tri]]).reshape(n, 2, 3)
    if g.name != "lashes" and k > 1:  # lashes grow off the lid margin, over no skin
        edges[:, 1:] = proxy.push_out(edges[:, 1:], SHELL)
    # vertices: card c, row r, column j at (c * K + r) * 2 + j
    positions = edges.reshape(-1, 3)
    tri_v = np.broadcast_to(tri.reshape(n, 1, 2), (n, k, 2)).reshape(-1)
    bary_v = np.broadcast_to(bary.reshape(n, 1, 2, 3), (n, k, 2, 3)).reshape(-1, 3)
    along = np.gradient(edges.mean(2), axis=1) if k > 1 else side
    normal = np.cross(side, along)
    skin_n = frames[g.tri[np.asarray(anchors)], 2]
    # where a strand's last points were gathered (cut at the bust) the rows coincide and
    # the card has no normal of its own: the skin's
    flat = np.linalg.norm(normal, axis=-1, keepdims=True) < 1e-9
    normal = _unit(np.where(flat, skin_n[:, None], normal))
    flip = np.sum(normal * skin_n[:, None], -1) < 0
    normal = np.where(flip[..., None], -normal, normal)
    # shading normals: the skin's at the root (cards shade like the scalp under them, not
    # as a patchwork of tilted tiles), the card's own at the tip
    a = (np.arange(k) / max(k - 1, 1))[None, :, None]
    normal = _unit((1 - a) * skin_n[:, None] + a * normal)
    normals = np.repeat(normal[:, :, None], 2, 2).reshape(-1, 3)
    rows = np.arange(k) / max(k - 1, 1)
    uv = np.stack(np.broadcast_arrays(np.array([0.0, 1.0])[None, None, :],
                                      rows[None, :, None] + np.zeros((n, 1, 1))), -1)
    idx = np.arange(n * k * 2).reshape(n, k, 2)
    a, b = idx[:, :-1, 0], idx[:, :-1, 1]
    c2, d = idx[:, 1:, 1], idx[:, 1:, 0]
    tris = np.concatenate([np.stack([a, b, c2], -1), np.stack([a, c2, d], -1)], 1)
    rootrow = np.zeros((n, k, 2), bool)
    rootrow[:, 0] = True
    return CardGroup(
        name=g.name, positions=positions, normals=normals, uv=uv.reshape(-1, 2),
        faces=tris.reshape(-1, 3).astype(np.int64), tri=tri_v.astype(np.int64),
        bary=bary_v, root=rootrow.reshape(-1),
        card=np.repeat(np.arange(n), 2 * k),
        texture=strand_texture(g.melanin, rng, TEXTURE_SIZE,
                               TEXTURE_STRANDS.get(g.name, TEXTURE_STRANDS["scalp"])),
        strands=s, melanin=g.melanin.mean(0))


def colour_names() -> str:
    """The named colours of ``--hair-color``, for help texts."""
    return ", ".join(NAMED_COLOURS)
