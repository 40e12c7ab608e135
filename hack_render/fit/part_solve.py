"""The parts' vertex colours solved against the photo (``final.part_solve``): steps of
bounded linear least squares after the per-vertex passes of :mod:`part_bake`.

The per-vertex passes scale each vertex's colour by the photo over the render at the
vertex's own pixel. Where a part's vertices are denser than the pixels (an iris a few
pixels across) or sparser (the whites' shell, the teeth), a pixel's colour is the
interpolation of three vertices' and the passes converge slowly or not at all. Here the
render is taken as what it is, linear in the parts' colours: at a pixel whose first
surface is a part (``G-buffer`` ``prim`` and ``position``: the triangle and its
barycentric weights ``b``),

    render = veil + shading * (b . colours of the triangle's vertices)

``veil`` the render with the parts' colours black (:mod:`part_bake`), ``shading`` the
render with them white minus the veil: both rendered once, with the fitted geometry,
light and camera. The pixel filter's spread and the denoiser are left out of the model;
each step therefore starts from the photo minus the current render (a Gauss-Newton step
with this Jacobian), and the steps' renders correct what the model misses.

A step solves, per channel, for the colours of the vertices some pixel sees:

    min  sum_px  g^2 (photo - render - shading * B d)^2  +  MU |E (c + d)|^2  +  LAM |d|^2

with ``c + d`` in [0, 1]: ``g`` the sRGB curve's slope at the pixel (the error the
score and the eye see: a dark iris's pixels weigh as much as the whites'), ``E`` the
parts' mesh edges (neighbouring colours alike where the pixels do not say otherwise),
``LAM`` holding vertices few pixels see. The bounds are kept by an active set
(:func:`bounded_solve`): a vertex whose colour the unbounded solution pushes past 0 or 1
is held there and the rest solved again. Which pixels: those whose first surface
(through the lash cards) is a baked part, not an occluder of the photo's (the person's
own eye and mouth openings excepted, as in :func:`part_bake.view_samples`); the pupil's
vertices stay black. A grey photo solves one luminance per vertex, its hue kept.

Measured on kept fits (2 steps after the 8 per-vertex passes): see docs/fit.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.fit import part_bake
from hack_render.fit.bake_weights import mask_at, photo_at
from hack_render.render.materials import VERTEX_COLOUR_PARTS
from hack_render.render.parts import PART_SPECS, REGIONS

#: weight of the colours' differences across the parts' mesh edges
MU = 1e-4
#: weight of a colour's change (holds vertices few pixels see)
LAM = 1e-4
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
    """One view's pixels whose first surface is a baked part: their (row, col), the
    sparse map ``B`` (pixels x all parts' vertices, barycentric weights) and the
    shading ``white - veil`` there (pixels, 3)."""

    def __init__(self, view, gbuffer: dict, head, layout: Layout,
                 white: np.ndarray, veil: np.ndarray):
        import scipy.sparse as sp

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
            m = (seg == REGIONS.index(PART_SPECS[name][1])) & allowed
            ys, xs = np.nonzero(m)
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
        self.pixels = np.concatenate(pix) if pix else np.zeros((0, 2), int)
        self.B = sp.csr_matrix((np.concatenate(vals) if vals else [],
                                (np.concatenate(rows) if rows else [],
                                 np.concatenate(cols) if cols else [])),
                               shape=(k, layout.n))
        yy, xx = self.pixels.T if k else (np.zeros(0, int), np.zeros(0, int))
        self.shading = (white[..., :3] - veil[..., :3])[yy, xx].astype(np.float64)


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
        seen |= np.asarray(abs(r.B).sum(0)).ravel() > 0
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
        A = sp.vstack([sp.diags(gw[:, 0]) @ sum(sp.diags(r.shading[:, ch] * _LUMA[ch])
                                                 @ r.B[:, U] @ sp.diags(c[U, ch] / lum[U])
                                                 for ch in range(3))
                       for r, gw in blocks]).tocsr()
        x = lum[U]
        hi = lum[U] / np.maximum(c[U].max(1), 1e-6)
        d = _step(A, res[:, 0], L, x, -x, hi - x)
        new[U] = c[U] * ((x + d) / lum[U])[:, None]
    else:
        for ch in range(3):
            A = sp.vstack([sp.diags(r.shading[:, ch] * gw[:, ch]) @ r.B[:, U]
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
    """The bounded change ``d`` of one channel: min |r - A d|^2 + MU (x+d)'L(x+d) +
    LAM |d|^2, lo <= d <= hi."""
    import scipy.sparse as sp

    H = (A.T @ A + MU * L + LAM * sp.identity(len(x))).tocsc()
    g = A.T @ r - MU * (L @ x)
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
