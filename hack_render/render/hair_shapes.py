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
#: gather their last points in one place (``hair.groom._cut``: 96k zero-length segments in
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
    line = "%.7g %.7g %.7g %.7g\n"
    with open(path, "w") as fh:
        fh.write(((line * k) + "\n") * s % tuple(cp.ravel().tolist()))


def hair_bsdf(shape: HairShape) -> dict:
    return {"type": "hair", "eumelanin": shape.eumelanin, "pheomelanin": shape.pheomelanin,
            "longitudinal_roughness": LONGITUDINAL_ROUGHNESS,
            "azimuthal_roughness": AZIMUTHAL_ROUGHNESS, "scale_tilt": SCALE_TILT}


def load_shapes(groom, posed: dict[str, np.ndarray], shapes: list[HairShape]) -> dict:
    """{shape id: loaded Mitsuba ``linearcurve`` shape with its ``hair`` BSDF} of the
    groom's strands posed at ``posed`` ({group: (S, K, 3)}, :func:`pose_groom`)."""
    import mitsuba as mi

    out = {}
    with tempfile.TemporaryDirectory(prefix="hack-hair-") as tmp:
        for sh in shapes:
            g = groom.group(sh.group)
            cp = control_points(posed[sh.group][sh.strands], g.radius)
            path = Path(tmp) / f"{sh.id}.txt"
            write_curves(path, cp)
            shape = mi.load_dict({"type": "linearcurve", "filename": str(path),
                                  "bsdf": hair_bsdf(sh)})
            shape.set_id(sh.id)
            out[sh.id] = shape
    return out


def shape_control_points(groom, posed: dict[str, np.ndarray], sh: HairShape) -> np.ndarray:
    """The flat float32 control points (x, y, z, r) of one shape at ``posed``."""
    g = groom.group(sh.group)
    return control_points(posed[sh.group][sh.strands], g.radius).ravel()
