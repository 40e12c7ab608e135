"""The parts' vertex colours solved against the photo (``final.part_solve``): steps of
bounded linear least squares after the per-vertex passes of :mod:`part_bake`.

The per-vertex passes scale each vertex's colour by the photo over the render at the
vertex's own pixel. Where a part's vertices are denser than the pixels (an iris a few
pixels across) or sparser (the whites' shell, the teeth), and where the pixel filter
mixes a pixel's neighbours into it (Mitsuba's Gaussian gives a pixel's own cell 47 % of
its weight), a pixel's colour is no one vertex's and the passes converge slowly or not
at all. Here the render is taken as what it is, linear in the parts' colours: a pixel
whose first surface is a part (the G-buffer's ``prim`` and ``position``: the triangle
and the barycentric weights ``b``) has the light

    S * (b . colours of the triangle's vertices)

``S`` its shading: the render with the parts' colours white minus the render with them
black (the veil, :mod:`part_bake`), both rendered once with the fitted geometry, light
and camera, over the share of the filter's weight that falls on part pixels. The
render is the veil plus those lights spread by the pixel filter (:func:`filter_weights`)
over the part pixels and the pixels within its reach. The denoiser and what varies
within a pixel are left out of the model; each step therefore starts from the photo
minus the current render (a Gauss-Newton step with this Jacobian ``J``), and the steps'
renders correct what the model misses.

A step solves, per channel, for the colours ``c + d`` of the vertices some row sees:

    min  sum_rows  g^2 (photo - render - J d)^2  +  s (MU |E (c + d)|^2  +  LAM |d|^2)

with ``c + d`` in [0, 1]: ``g`` the sRGB curve's slope at the pixel (the error the
score and the eye see: a dark iris's pixels weigh as much as the whites'), ``E`` the
parts' mesh edges (neighbouring colours alike where the pixels do not say otherwise),
``LAM`` holding vertices few pixels see, ``s`` the data term's mean diagonal (the same
weights under a bright or a dim light). The bounds are kept by an active set
(:func:`bounded_solve`). Which rows: the part pixels and those within the filter's
reach, not an occluder's (the person's own eye and mouth openings excepted, as in
:func:`part_bake.view_samples`); the pupil's vertices stay black. A grey photo solves
one luminance per vertex, its hue kept.

Measured on six real photos' kept fits: see docs/fit.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.fit import part_bake
from hack_render.fit.bake_weights import mask_at, photo_at
from hack_render.render.materials import VERTEX_COLOUR_PARTS
from hack_render.render.parts import PART_SPECS, REGIONS

#: weight of the colours' differences across the parts' mesh edges
MU = 3e-3
#: weight of a colour's change (holds vertices few pixels see)
LAM = 1e-2
#: the sRGB slope is taken at linear values no darker than this
SLOPE_FLOOR = 0.003
#: active-set rounds of :func:`bounded_solve`
ROUNDS = 12
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(n, 3) barycentric weights of points ``p`` (n, 3) in triangles ``a, b, c`` (n, 3
    each), projected onto the triangles' planes, clipped to the triangle and summing
    to 1."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 1e-30, d00 * d11 - d01 * d01, 1e-30)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    out = np.clip(np.stack([1.0 - v - w, v, w], 1), 0.0, 1.0)
    s = out.sum(1, keepdims=True)
    return np.where(s > 0, out / np.maximum(s, 1e-12), 1.0 / 3.0)


def slope(x: np.ndarray) -> np.ndarray:
    """d sRGB / d linear at ``x`` (held at :data:`SLOPE_FLOOR`)."""
    x = np.maximum(x, SLOPE_FLOOR)
    return np.where(x <= 0.0031308, 12.92, 1.055 / 2.4 * x ** (1.0 / 2.4 - 1.0))


def bounded_solve(H, g: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  rounds: int = ROUNDS) -> np.ndarray:
    """argmin 0.5 x'Hx - g'x with lo <= x <= hi (``H`` sparse, symmetric positive
    definite): an active set, each round solving the free variables with the bound ones
    held and moving the violators to their bound, or freeing a bound one whose gradient
    points inside."""
    from scipy.sparse.linalg import spsolve

    H = H.tocsc()
    n = len(g)
    x = np.clip(np.zeros(n), lo, hi)
    at = np.zeros(n, np.int8)            # 0 free, -1 at lo, +1 at hi
    for _ in range(max(1, rounds)):
        free = at == 0
        x = np.where(at < 0, lo, np.where(at > 0, hi, x))
        if free.any():
            rhs = g[free] - H[free][:, ~free] @ x[~free]
            x[free] = np.atleast_1d(spsolve(H[free][:, free], rhs))
        below, above = free & (x < lo), free & (x > hi)
        grad = H @ x - g                  # > 0 at lo: wants lower (stay); < 0: free it
        release = ((at < 0) & (grad < -1e-12)) | ((at > 0) & (grad > 1e-12))
        if not (below.any() or above.any() or release.any()):
            break
        at[below], at[above], at[release] = -1, 1, 0
    return np.clip(x, lo, hi)


class ViewRows:
    """One view's rows of the solve: the pixels (``pixels``, (rows, 2) row, col) that
    show a baked part or lie within the pixel filter's reach of one, not an occluder's,
    and per channel the sparse map ``J[ch]`` (rows x the parts' stacked vertices) from
    the vertices' colours to those pixels' light: the part pixels' barycentric weights
    (``B``: the first surface's triangle), times their shading, spread by the pixel
    filter (:func:`filter_weights`: Mitsuba's Gaussian, or none for the box filter).
    The shading of a part pixel is ``white - veil`` there over the share of the filter's
    weight that falls on part pixels (1 inside a part, less at its edge)."""

    def __init__(self, view, gbuffer: dict, head, layout: Layout,
                 white: np.ndarray, veil: np.ndarray, pixel_filter: str = "gaussian"):
        import scipy.sparse as sp
        from scipy.ndimage import binary_dilation

        seg = np.asarray(gbuffer["segmentation"])
        h, w = seg.shape
        allowed = np.ones((h, w), bool)
        if view.occluder is not None:
            occ = mask_at(view.occluder, h, w)
            for opening in (view.eye_opening, view.mouth_opening):
                if opening is not None:
                    occ &= ~mask_at(opening, h, w)
            allowed = ~occ
        rows, cols, vals, pix = [], [], [], []
        k = 0
        for name, off in layout.offsets.items():
            ys, xs = np.nonzero(seg == REGIONS.index(PART_SPECS[name][1]))
            if len(ys) == 0:
                continue
            pos = np.asarray(head.params[f"{name}.vertex_positions"], np.float64).reshape(-1, 3)
            faces = layout.faces[name]
            prim = np.asarray(gbuffer["prim"])[ys, xs]
            ok = (prim >= 0) & (prim < len(faces))
            ys, xs, tri = ys[ok], xs[ok], faces[prim[ok]]
            b = barycentric(np.asarray(gbuffer["position"], np.float64)[ys, xs],
                            pos[tri[:, 0]], pos[tri[:, 1]], pos[tri[:, 2]])
            r = np.arange(k, k + len(ys))
            for j in range(3):
                rows.append(r)
                cols.append(tri[:, j] + off)
                vals.append(b[:, j])
            pix.append(np.stack([ys, xs], 1))
            k += len(ys)
        part = np.concatenate(pix) if pix else np.zeros((0, 2), int)
        self.B = sp.csr_matrix((np.concatenate(vals) if vals else [],
                                (np.concatenate(rows) if rows else [],
                                 np.concatenate(cols) if cols else [])),
                               shape=(k, layout.n))
        # the rows: the part pixels and their filter's reach, without the occluders
        taps = filter_weights(pixel_filter)
        reach = len(taps) // 2
        shown = np.zeros((h, w), bool)
        shown[part[:, 0], part[:, 1]] = True
        near = binary_dilation(shown, np.ones((2 * reach + 1,) * 2, bool)) if reach else shown
        ry, rx = np.nonzero(near & allowed)
        self.pixels = np.stack([ry, rx], 1)
        row_of = -np.ones((h, w), np.int64)
        row_of[ry, rx] = np.arange(len(ry))
        kr, kc, kv = [], [], []
        share = np.zeros(k)   # the filter's weight about each part pixel on part pixels
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                y, x = part[:, 0] + dy, part[:, 1] + dx
                inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
                j = np.full(len(part), -1)
                j[inside] = row_of[y[inside], x[inside]]
                on = j >= 0
                tap = taps[dy + reach] * taps[dx + reach]
                kr.append(j[on])
                kc.append(np.nonzero(on)[0])
                kv.append(np.full(on.sum(), tap))
                hit = np.zeros(k, bool)
                hit[inside] = shown[y[inside], x[inside]]
                share += hit * tap
        K = sp.csr_matrix((np.concatenate(kv), (np.concatenate(kr), np.concatenate(kc))),
                          shape=(len(ry), k))
        # a part pixel's own shading: white - veil over the filter's share on part pixels
        own = (white[..., :3] - veil[..., :3])[part[:, 0], part[:, 1]].astype(np.float64)
        shading = own / np.maximum(share, 0.25)[:, None]
        self.J = [(K @ sp.diags(shading[:, ch]) @ self.B).tocsr() for ch in range(3)]


def filter_weights(pixel_filter: str) -> np.ndarray:
    """The weights of a pixel's neighbours along one axis (offsets -2..2, summing to 1)
    in the render of a scene with ``pixel_filter``: Mitsuba's ``gaussian`` (standard
    deviation 0.5 px, radius 2 px) over each neighbour's cell; ``box``: the pixel
    alone."""
    from scipy.special import erf

    if pixel_filter != "gaussian":
        return np.ones(1)
    edges = (np.arange(-2, 4) - 0.5) / 0.5           # the cells' edges in deviations
    cdf = 0.5 * (1 + erf(edges / np.sqrt(2)))
    taps = np.diff(cdf)
    return taps / taps.sum()


@dataclass
class Layout:
    """The baked parts a scene holds with per-vertex colours, stacked: each part's first
    index (``offsets``), the total ``n``, each part's triangles (``faces``, the part's own
    indices) and the vertices held (``fixed``: the pupils, :func:`part_bake.pupil`)."""

    offsets: dict
    n: int
    faces: dict
    fixed: np.ndarray

    @classmethod
    def of(cls, head) -> Layout:
        offsets, faces, n = {}, {}, 0
        for name in VERTEX_COLOUR_PARTS:
            if f"{name}.vertex_color" in head.params:
                offsets[name] = n
                faces[name] = np.asarray(head.params[f"{name}.faces"], np.int64).reshape(-1, 3)
                n += len(head.params[f"{name}.vertex_positions"]) // 3
        fixed = np.zeros(n, bool)
        if "iris" in offsets:
            pos = np.asarray(head.params["iris.vertex_positions"], np.float64).reshape(-1, 3)
            fixed[offsets["iris"]:offsets["iris"] + len(pos)] = part_bake.pupil(
                pos, head.eye_axes)
        return cls(offsets, n, faces, fixed)


def solve_step(state, part_rgb: dict, rows: list, renders: list,
               layout: Layout) -> tuple[dict, dict]:
    """One step: (new ``part_rgb``, report). ``rows``: each view's :class:`ViewRows`
    (None: the view shows no part); ``renders``: each view's render with ``part_rgb``
    (linear RGB at the G-buffer's size); ``layout``: the stacked parts (the first
    view's scene's: the views share the model's parts)."""
    import scipy.sparse as sp

    offsets, n, fixed = layout.offsets, layout.n, layout.fixed
    c = np.zeros((n, 3))
    for name, off in offsets.items():
        c[off:off + len(part_rgb[name])] = part_rgb[name]
    used = [r for r in rows if r is not None and len(r.pixels)]
    if not used:
        return part_rgb, {"pixels": 0}
    grey = all(v.photo.is_grey for v, r in zip(state.views, rows) if r is not None)
    seen = np.zeros(n, bool)
    for r in used:
        seen |= np.asarray(sum(abs(j) for j in r.J).sum(0)).ravel() > 0
    U = np.nonzero(seen & ~fixed)[0]
    if len(U) == 0:
        return part_rgb, {"pixels": 0}
    idx = -np.ones(n, int)
    idx[U] = np.arange(len(U))
    E = _edges(layout, idx)
    L = (E.T @ E) if E is not None else sp.csr_matrix((len(U), len(U)))
    resid, blocks = [], []
    for v, r, rend in zip(state.views, rows, renders):
        if r is None or not len(r.pixels):
            continue
        h, w = rend.shape[:2]
        photo = photo_at(v, h, w).astype(np.float64)
        yy, xx = r.pixels.T
        p, cur = photo[yy, xx], np.asarray(rend, np.float64)[yy, xx, :3]
        if grey:
            p, cur = p @ _LUMA, cur @ _LUMA
            p, cur = p[:, None], cur[:, None]
        resid.append((p - cur) * slope(np.maximum(p, cur)))
        blocks.append((r, slope(np.maximum(p, cur))))
    res = np.concatenate(resid)
    before = float(np.sqrt((res ** 2).mean()))
    new = c.copy()
    if grey:
        lum = np.maximum(c @ _LUMA, 1e-6)
        A = sp.vstack([sp.diags(gw[:, 0]) @ sum(_LUMA[ch] * r.J[ch][:, U]
                                                 @ sp.diags(c[U, ch] / lum[U])
                                                 for ch in range(3))
                       for r, gw in blocks]).tocsr()
        x = lum[U]
        hi = lum[U] / np.maximum(c[U].max(1), 1e-6)
        d = _step(A, res[:, 0], L, x, -x, hi - x)
        new[U] = c[U] * ((x + d) / lum[U])[:, None]
    else:
        for ch in range(3):
            A = sp.vstack([sp.diags(gw[:, ch]) @ r.J[ch][:, U]
                           for r, gw in blocks]).tocsr()
            x = c[U, ch]
            d = _step(A, res[:, ch], L, x, -x, 1.0 - x)
            new[U, ch] = x + d
    new = np.clip(new, 0.0, 1.0)
    out = {name: new[off:off + len(part_rgb[name])].astype(np.float32)
           for name, off in offsets.items()}
    return out, {"pixels": len(res), "vertices": len(U),
                 "srgb_rms_before": round(before * 255.0, 3)}


def _step(A, r: np.ndarray, L, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The bounded change ``d`` of one channel: min |r - A d|^2 + s (MU (x+d)'L(x+d) +
    LAM |d|^2), lo <= d <= hi; ``s`` the mean of A'A's diagonal (the weights relative to
    the data's, whatever the light's scale)."""
    import scipy.sparse as sp

    AtA = (A.T @ A).tocsc()
    s = float(AtA.diagonal().mean()) if AtA.shape[0] else 1.0
    s = s if s > 0 else 1.0
    H = (AtA + s * (MU * L + LAM * sp.identity(len(x)))).tocsc()
    g = A.T @ r - s * MU * (L @ x)
    return bounded_solve(H, g, lo, hi)


def _edges(layout: Layout, idx: np.ndarray):
    """The incidence matrix (edges x unknowns) of the parts' mesh edges whose two ends are
    both unknowns (``idx`` >= 0), or None."""
    import scipy.sparse as sp

    a_all, b_all = [], []
    for name, off in layout.offsets.items():
        faces = layout.faces[name]
        for i, j in ((0, 1), (1, 2), (2, 0)):
            a_all.append(faces[:, i] + off)
            b_all.append(faces[:, j] + off)
    if not a_all:
        return None
    a, b = np.concatenate(a_all), np.concatenate(b_all)
    keep = (idx[a] >= 0) & (idx[b] >= 0)
    a, b = np.unique(np.sort(np.stack([a[keep], b[keep]], 1), 1), axis=0).T
    m = len(a)
    if m == 0:
        return None
    r = np.arange(m)
    return sp.csr_matrix((np.r_[np.ones(m), -np.ones(m)], (np.r_[r, r], np.r_[idx[a], idx[b]])),
                         shape=(m, int((idx >= 0).sum())))
