"""A groom (:mod:`hack_render.hair`) as Mitsuba curve shapes with the ``hair`` BSDF.

Each strand group (scalp, brows, lashes, beard) is split by melanin into a few shapes:
Mitsuba's ``hair`` BSDF takes one ``eumelanin`` / ``pheomelanin`` pair per shape, so
per-strand colour variation is given by quantile buckets of the group's melanin
(:data:`GROUP_BUCKETS`; each shape the mean of its strands), and the unpigmented strands of
greying (:attr:`HairStyle.greying`: melanin scaled to 2 %) get a white shape of their own.
Each bucket costs render time: a vectorised call on a BSDF pointer runs the ``hair``
BSDF once for every distinct BSDF among a packet's lanes, and a packet of rays into the
scalp meets all its buckets (the short groom, 256 px, 49 spp: 0.3 CPU s per scalp bucket,
a bald render being 1.8; docs/hair.md), so the scalp gets two and the small groups
(brows, lashes) one.

Strands are linear curves (``linearcurve``: Embree's round linear curves, cones between
the control points, on the CPU), control points ``x y z radius``, so a strand starts at
its root on the skin and ends at its tip. Cubic B-splines (``bsplinecurve``) were the
first choice (smooth, at the same cost per segment), but Mitsuba 3.9's B-spline curves
crashed the process (a segmentation fault inside ``mi.render``, reproducible for a long
groom at 256 px and 4 spp, not at 1 or 2) where linear curves of the same points render.

A curve shape loads only from a text file (one line per control point, a blank line
between curves); the file is written once per shape to a temporary folder and removed
after loading. Later poses write the traversed ``<id>.control_points`` (flat x, y, z, r in
file order) and ``params.update()`` rebuilds the curves' BVH.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hack_render.hair.groom import BEARD_STRANDS, BROW_STRANDS, LASH_STRANDS, SCALP_STRANDS

#: Quantile buckets of pigmented strands in the scalp's group (each a shape of its mean
#: melanin), and in each group (:data:`GROUP_BUCKETS`; 1 for a group not named there).
MELANIN_BUCKETS = 2
GROUP_BUCKETS = {"scalp": MELANIN_BUCKETS, "beard": 2}
#: A strand is "white" (greyed) when its melanin is under this fraction of its group's
#: median (greying scales a strand's melanin to 2 %, :func:`hack_render.hair.groom._melanin`).
WHITE_FRACTION = 0.1
#: The ``hair`` BSDF's roughness: longitudinal and azimuthal (Mitsuba's defaults, 0.3).
LONGITUDINAL_ROUGHNESS = 0.3
AZIMUTHAL_ROUGHNESS = 0.3
#: Cuticle scale tilt, degrees (Mitsuba's default: 2).
SCALE_TILT = 2.0
#: Most control points rendered per strand: a longer strand is
#: resampled to this many of its points, evenly along its index, root and tip kept. A
#: long groom's 20 points per strand are 1.1 M curve segments for 60k strands, and the
#: rays' cost grows with them; 12 points keep a 30 cm strand's segments under 3 cm.
MAX_CONTROL_POINTS = 12
#: Shortest segment between a strand's control points, metres: a groom's cut strands
#: gather their last points in one place (``hair.strands.cut_strands``: 96k zero-length segments in
#: a long groom); they are opened to this length along the strand's last direction, so no
#: curve segment is degenerate.
MIN_SEGMENT = 5e-5
#: Russian roulette from this path depth in a scene with hair (5 without): a path in
#: dark hair carries little light after a few events; measured on the portrait with a
#: short groom at 128 px, 16 spp: 0.67x the CPU time for 1.12x the squared error (1.33x
#: the samples per unit of error).
HAIR_RR_DEPTH = 2
#: ``hack_path``'s ``hair_rr`` in a scene with hair: Russian roulette right after a path's
#: first event on hair, whatever its depth (without it every path that meets the hair at
#: its first or second vertex traces one more ray, the roulette starting at depth 2). Dark
#: hair keeps little of the light it scatters, so most such paths end there; light hair
#: keeps most of them. Unbiased (no energy is cut, unlike a budget of hair events,
#: ``hair_depth``); measured with ``bench/bench_render.py --only hair`` (docs/hair.md).
HAIR_RR = True
#: The prefix of every hair shape's id (``hair_<group>_<bucket>``).
PREFIX = "hair_"
#: The strand groups a groom may hold (``hack_render.hair.groom.grow``'s).
GROUPS = ("scalp", "brows", "lashes", "beard")
#: An empty slot's strand (:func:`placeholder_points`): its length and radius, metres.
PLACEHOLDER_LENGTH = 1e-6
PLACEHOLDER_RADIUS = 1e-9


@dataclass(frozen=True)
class HairShape:
    """One curve shape: its id, group name, strand indices in the group, mean melanin."""

    id: str
    group: str
    strands: np.ndarray
    eumelanin: float
    pheomelanin: float


def buckets(melanin: np.ndarray, n: int = MELANIN_BUCKETS) -> list[np.ndarray]:
    """Strand indices of each melanin bucket of a group (``melanin`` (S, 2)): the white
    strands (below :data:`WHITE_FRACTION` of the median total) first, if any, then ``n``
    quantile buckets of the rest by total melanin (empty ones dropped)."""
    m = np.asarray(melanin, np.float64).reshape(-1, 2)
    total = m.sum(1)
    med = float(np.median(total)) if len(total) else 0.0
    white = total < WHITE_FRACTION * med if med > 0 else np.zeros(len(m), bool)
    out = [np.flatnonzero(white)] if white.any() else []
    rest = np.flatnonzero(~white)
    if len(rest):
        order = rest[np.argsort(total[rest], kind="stable")]
        out += [b for b in np.array_split(order, min(n, len(order))) if len(b)]
    return out


def hair_shapes(groom) -> list[HairShape]:
    """The shapes of a groom: per group, per melanin bucket (:func:`buckets`,
    :data:`GROUP_BUCKETS`)."""
    shapes = []
    for g in groom.groups:
        if g.num_strands == 0:
            continue
        for i, idx in enumerate(buckets(g.melanin, GROUP_BUCKETS.get(g.name, 1))):
            eu, pheo = np.asarray(g.melanin, np.float64)[idx].mean(0)
            shapes.append(HairShape(f"{PREFIX}{g.name}_{i}", g.name, np.sort(idx),
                                    float(eu), float(pheo)))
    return shapes


def slot_ids() -> list[str]:
    """Every shape id :func:`hair_shapes` can give a groom: per group of :data:`GROUPS`,
    its melanin buckets (:data:`GROUP_BUCKETS`) and a white one. A scene holding a shape
    for each (``HeadScene(..., hair_slots=...)``) takes a groom in place
    (``HeadScene.set_hair``)."""
    return [f"{PREFIX}{g}_{i}" for g in GROUPS for i in range(GROUP_BUCKETS.get(g, 1) + 1)]


def needed_segments(groom) -> dict[str, int]:
    """{slot id: curve segments} that ``groom``'s shapes fill (0: a slot it leaves empty)."""
    out = dict.fromkeys(slot_ids(), 0)
    for sh in hair_shapes(groom) if groom is not None else []:
        k = min(groom.group(sh.group).points_per_strand, MAX_CONTROL_POINTS)
        out[sh.id] = len(sh.strands) * (k - 1)
    return out


def slots_take(groom, capacity: dict[str, int] | None = None) -> bool:
    """Whether a scene with hair slots of ``capacity`` ({slot id: segments}; None: any)
    takes ``groom`` (``HeadScene.set_hair``): it has lashes (such a scene renders no lash
    cards), each of its shapes has a slot and, given ``capacity``, fits in it."""
    if groom is None or groom.group("lashes") is None:
        return False
    need = needed_segments(groom)
    if set(need) != set(slot_ids()):
        return False
    return capacity is None or all(need[k] <= capacity.get(k, 0) for k in need)


def slot_capacity(groom=None, margin: float = 1.0, at_least: dict[str, int] | None = None
                  ) -> dict[str, int]:
    """{slot id: segments} for a scene with hair slots: every slot of a group the same
    number, at least 1, ``margin`` times the most any slot of the group needs for
    ``groom`` (:func:`needed_segments`; a group's strands move between its melanin buckets
    from one groom to the next) and at least ``at_least``'s for any slot of the group."""
    need = needed_segments(groom)
    base = at_least or {}
    out = {}
    for g in GROUPS:
        ids = [k for k in need if k.startswith(f"{PREFIX}{g}_")]
        n = max(1, int(np.ceil(margin * max(need[k] for k in ids))),
                *(int(base.get(k, 0)) for k in ids))
        out.update(dict.fromkeys(ids, n))
    return out


#: The most a style's density times its scalp area (over the full scalp's) reaches in the
#: population sampler (``hair.style.sample_style``: density up to 1.1; 1.10 measured over
#: 300 draws), with room: :func:`slot_bound`'s scalp.
SCALP_FACTOR = 1.25
#: The same for the brows (the sampler's ``brow_density`` up to 1.4).
BROW_FACTOR = 1.4


def slot_bound(lod: float) -> dict[str, int]:
    """{slot id: segments} that hold every groom the population sampler draws at ``lod``
    (``hair.style.sample_style``; a style outside its ranges may need more:
    :func:`slots_take` says so): n strands at most in a group (``hair.groom``'s counts at
    this level of detail), each of at most ``MAX_CONTROL_POINTS - 1`` segments; the first
    slot of a group (its white strands, or its first melanin bucket) may take all n, each
    other (a quantile bucket) at most n / buckets. A constant of the level of detail, so a
    scene's slots, hence its pixels, do not depend on which grooms came before."""
    lod = float(lod)
    most = {"scalp": SCALP_STRANDS * lod * SCALP_FACTOR,
            "brows": 2 * BROW_STRANDS * lod * BROW_FACTOR,
            "lashes": 2 * sum(max(4, round(n * min(lod, 1.5))) for n in LASH_STRANDS),
            "beard": max(BEARD_STRANDS.values()) * lod}
    out = {}
    for g in GROUPS:
        n, b = int(np.ceil(most[g])), GROUP_BUCKETS.get(g, 1)
        for i in range(b + 1):
            out[f"{PREFIX}{g}_{i}"] = max(1, (n if i == 0 else -(-n // b)) *
                                          (MAX_CONTROL_POINTS - 1))
    return out


def padding_points(centre, segments: int, invalid: bool = True) -> np.ndarray:
    """(segments + 1, 4) float32 control points of one strand of ``segments`` segments
    that fills a slot's unused capacity. ``invalid``: its first point at ``centre``, the
    others NaN, so every segment is invalid and Embree drops it when it builds the
    acceleration structure (a slot padded with valid segments rebuilt it in 0.75 s a
    sample against 0.1 s; measured at 256 px); the one finite point keeps an empty slot's
    bounds those of a point inside the scene's (the mesh's centroid), so the bounds and
    the lights' sampling are those of the scene without it. Not ``invalid`` (a curve
    file, which Mitsuba refuses with NaN): every point within
    :data:`PLACEHOLDER_LENGTH` of ``centre``, zig-zagging, :data:`PLACEHOLDER_RADIUS`
    thick (a ray meets one with a probability of about 1e-12 a pixel)."""
    c = np.asarray(centre, np.float64).reshape(3)
    out = np.zeros((segments + 1, 4), np.float32)
    out[:, :3] = c
    out[1::2, 1] += PLACEHOLDER_LENGTH
    out[:, 3] = PLACEHOLDER_RADIUS
    if invalid:
        out[1:, :3] = np.nan
    return out


def segment_indices(num_strands: int, points_per_strand: int) -> np.ndarray:
    """The first control point of every curve segment of ``num_strands`` strands of
    ``points_per_strand`` points each, in file order (what a ``linearcurve`` loads from
    :func:`write_curves`' file: its ``segment_indices``)."""
    first = np.arange(num_strands, dtype=np.int64)[:, None] * points_per_strand
    return (first + np.arange(points_per_strand - 1)).astype(np.uint32).ravel()


def slot_content(cp: np.ndarray | None, capacity: int, centre) -> tuple[np.ndarray, np.ndarray]:
    """(control points (P, 4) float32, segment indices (capacity,) uint32) of a slot of
    ``capacity`` segments holding strands ``cp`` ((S, K, 4), :func:`control_points`; None:
    none): the strands, then one :func:`padding_points` strand over the rest. The
    segment count is the slot's, whatever the groom: Mitsuba's ``linearcurve`` compiles
    its segment count into the render kernel (``dr::width(m_indices)`` in its
    ``compute_surface_interaction``), so a scene whose counts change compiles again."""
    cp = np.zeros((0, 2, 4), np.float32) if cp is None else cp
    s, k = cp.shape[:2]
    pad = capacity - s * (k - 1)
    if pad < 0 or capacity < 1:
        raise ValueError(f"a slot of {capacity} segments cannot hold {s * (k - 1)}")
    first = s * k
    points = [cp.reshape(-1, 4)] + ([padding_points(centre, pad)] if pad else [])
    tail = np.arange(first, first + pad, dtype=np.uint32)
    return np.concatenate(points), np.concatenate([segment_indices(s, k), tail])


def control_points(points: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(S, M, 4) float32 curve control points (x, y, z, r) of strands ``points`` (S, K, 3)
    with radii ``radius`` (K,): M = min(K, :data:`MAX_CONTROL_POINTS`) of the points, root
    and tip kept, no segment shorter than :data:`MIN_SEGMENT` (:func:`open_segments`)."""
    p = np.asarray(points, np.float64)
    r = np.asarray(radius, np.float64)
    k = p.shape[1]
    if k > MAX_CONTROL_POINTS:
        keep = np.unique(np.round(np.linspace(0, k - 1, MAX_CONTROL_POINTS)).astype(int))
        p, r = p[:, keep], r[keep]
    p = open_segments(p)
    out = np.empty(p.shape[:2] + (4,), np.float32)
    out[..., :3] = p
    out[..., 3] = r[None]
    return out


def open_segments(p: np.ndarray, eps: float = MIN_SEGMENT) -> np.ndarray:
    """Strands ``p`` (S, K, 3) with every segment at least ``eps`` long: a point too near
    the one before it is moved to ``eps`` from it along the strand's last direction (the
    first segment's fallback: down)."""
    p = np.array(p, np.float64)
    direction = np.tile([0.0, -1.0, 0.0], (p.shape[0], 1))
    for j in range(1, p.shape[1]):
        d = p[:, j] - p[:, j - 1]
        n = np.linalg.norm(d, axis=-1)
        short = n < eps
        direction[~short] = d[~short] / n[~short, None]
        p[short, j] = p[short, j - 1] + eps * direction[short]
    return p


def write_curves(path: Path, cp: np.ndarray) -> None:
    """Write control points (S, K, 4) as Mitsuba's curve text file."""
    s, k, _ = cp.shape
    line = "%.9g %.9g %.9g %.9g\n"  # float32 to the bit
    with open(path, "w") as fh:
        fh.write(((line * k) + "\n") * s % tuple(cp.ravel().tolist()))


def hair_bsdf(shape: HairShape | None) -> dict:
    """The ``hair`` BSDF of a shape (None: an empty slot's, melanin 0)."""
    eu, pheo = (shape.eumelanin, shape.pheomelanin) if shape is not None else (0.0, 0.0)
    return {"type": "hair", "eumelanin": eu, "pheomelanin": pheo,
            "longitudinal_roughness": LONGITUDINAL_ROUGHNESS,
            "azimuthal_roughness": AZIMUTHAL_ROUGHNESS, "scale_tilt": SCALE_TILT}


def load_shapes(groom, posed: dict[str, np.ndarray] | None, shapes: list[HairShape],
                capacity: dict[str, int] | None = None, centre=None) -> dict:
    """{shape id: loaded Mitsuba ``linearcurve`` shape with its ``hair`` BSDF} of the
    groom's strands posed at ``posed`` ({group: (S, K, 3)}, :func:`pose_groom`); with
    ``capacity`` ({slot id: segments}), one shape per slot instead, each loaded as one
    short strand at ``centre`` (a curve file holds no NaN, and a slot's million segments
    as text took seconds to write and parse): the scene then writes the slots' content
    (:func:`write_slots`) before its first render."""
    import mitsuba as mi

    active = {sh.id: sh for sh in shapes}
    out = {}
    with tempfile.TemporaryDirectory(prefix="hack-hair-") as tmp:
        for sid in active if capacity is None else capacity:
            sh = active.get(sid)
            path = Path(tmp) / f"{sid}.txt"
            if capacity is None:
                write_curves(path, control_points(posed[sh.group][sh.strands],
                                                  groom.group(sh.group).radius))
            else:
                write_curves(path, padding_points(centre, 1, invalid=False)[None])
            shape = mi.load_dict({"type": "linearcurve", "filename": str(path),
                                  "bsdf": hair_bsdf(sh)})
            shape.set_id(sid)
            out[sid] = shape
    return out


def aligned_float(values: np.ndarray):
    """``mi.Float`` of float32 ``values`` from a 64-byte-aligned copy. Dr.Jit reads a
    curve's control points four at a time (a packet gather) only from an aligned buffer,
    and takes a NumPy array's memory as it is: an array at an address that happens not to
    be aligned gives other kernel code, which compiles again (about 1 s at every new
    groom or pose, measured); aligned, a new groom of the same slots reuses the kernels."""
    import mitsuba as mi

    a = np.ascontiguousarray(values, np.float32).ravel()
    buf = np.empty(a.nbytes + 64, np.uint8)
    start = (-buf.ctypes.data) % 64
    out = buf[start:start + a.nbytes].view(np.float32)
    out[:] = a
    return mi.Float(out)


def write_slots(params, groom, posed: dict[str, np.ndarray] | None, shapes: list[HairShape],
                capacity: dict[str, int], centre, structure: bool) -> None:
    """Write a groom into a scene's hair slots (``params``: the scene's traversed
    parameters; ``capacity``: {slot id: segments}, :func:`slot_content`): each of
    ``shapes`` (the groom's, :func:`hair_shapes`) its strands posed at ``posed``, padded
    at ``centre``. ``structure``: the segments, control point counts and melanin too, not
    only the positions (a new groom). The melanin is written as opaque values, so a new
    groom compiles no kernel again. The caller updates the parameters."""
    import drjit as dr
    import mitsuba as mi

    active = {sh.id: sh for sh in shapes}
    for sid, cap in capacity.items():
        sh = active.get(sid)
        cp = None if sh is None else \
            control_points(posed[sh.group][sh.strands], groom.group(sh.group).radius)
        points, index = slot_content(cp, cap, centre)
        params[f"{sid}.control_points"] = aligned_float(points)
        if not structure:
            continue
        params[f"{sid}.segment_indices"] = mi.UInt32(index)
        params[f"{sid}.control_point_count"] = len(points)
        for key, value in zip(("eumelanin", "pheomelanin"),
                              (0.0, 0.0) if sh is None else (sh.eumelanin, sh.pheomelanin)):
            x = mi.Float(value)
            dr.make_opaque(x)
            params[f"{sid}.bsdf.{key}"] = x


def shape_control_points(groom, posed: dict[str, np.ndarray], sh: HairShape) -> np.ndarray:
    """The flat float32 control points (x, y, z, r) of one shape at ``posed``."""
    g = groom.group(sh.group)
    return control_points(posed[sh.group][sh.strands], g.radius).ravel()
