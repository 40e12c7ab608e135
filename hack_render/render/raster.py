"""A triangle mesh rasterised in NumPy (z-buffer, one sample at each pixel centre), shaded
as :meth:`~hack_render.render.mesh_views.MeshViews.render` shades its ray cast: grey
diffuse albedo lit by an ambient term and the key light above and to the left of the
camera, Lambert, no shadows, back faces lit as front ones.

For previews drawn once per frame of a clip (``hack-render track``'s ``overlay.mp4``):
the ray caster rebuilds its scene's acceleration structure whenever the mesh moves
(about 0.3 s a frame of the 52k-triangle model at 512 px on 2 cores, more than the
tracking itself); this draws the same image in tens of milliseconds, with no Mitsuba.
"""

from __future__ import annotations

import numpy as np

from hack_render.geometry.normals import vertex_normals
from scenes.cameras import Camera

#: the grey of :class:`~hack_render.render.mesh_views.MeshViews`' mesh without colours
GREY = 0.6


def key_light(cam: Camera) -> np.ndarray:
    """The key light's position: up and to the left of the camera by half its distance
    to the world origin (as ``MeshViews``)."""
    d = float(np.linalg.norm(cam.t)) or 1.0
    right, down = cam.R[0], cam.R[1]
    return cam.center + 0.5 * d * (-down - 0.6 * right)


def fragments(vertices: np.ndarray, faces: np.ndarray, cam: Camera,
              closed: np.ndarray | None = None, budget: int = 1 << 19):
    """The nearest triangle at each covered pixel centre: (pixel (n,) int64 row-major
    flat indices, triangle (n,) int64, perspective-correct barycentric weights (n, 3)
    float64). See :func:`rasterize`."""
    h, w = cam.height, cam.width
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    Xc = V @ cam.R.T + cam.t
    z = Xc[:, 2]
    K = cam.K
    zs = np.maximum(z, 1e-9)
    px = np.stack([K[0, 0] * Xc[:, 0] / zs + K[0, 2] - 0.5,
                   K[1, 1] * Xc[:, 1] / zs + K[1, 2] - 0.5], -1)  # pixel-centre units
    tri = px[F]                                     # (F, 3, 2)
    c0, c1, c2 = tri[:, 0], tri[:, 1], tri[:, 2]
    # (three-way minimum and maximum by pairs: numpy's reductions over an axis of 3 are
    # several times slower)
    lo = np.floor(np.minimum(np.minimum(c0, c1), c2)).astype(np.int64) + 1  # first centre
    hi = np.floor(np.maximum(np.maximum(c0, c1), c2)).astype(np.int64)      # >= min
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w - 1, h - 1])
    ext = hi - lo + 1
    e1, e2 = c1 - c0, c2 - c0
    det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]   # twice the signed area on screen
    front = z > 1e-6
    ok = (front[F[:, 0]] & front[F[:, 1]] & front[F[:, 2]] & (ext[:, 0] > 0)
          & (ext[:, 1] > 0) & (np.abs(det) > 1e-12))
    if closed is not None:
        # a camera looking along +z with y down: a triangle wound outward that faces it
        # has a negative signed area; outward winding where the closed part's signed
        # volume is positive (any winding of the file works)
        c = np.asarray(closed, bool)
        a, b_, d = (V[F[c, k]].T for k in range(3))   # (3, n) each: the corners
        vol = (d[0] * (a[1] * b_[2] - a[2] * b_[1]) + d[1] * (a[2] * b_[0] - a[0] * b_[2])
               + d[2] * (a[0] * b_[1] - a[1] * b_[0])).sum()   # sum of (a x b) . d
        out = np.sign(vol) or 1.0
        ok &= ~(c & (out * det > 0))
    keep = np.flatnonzero(ok)
    # per triangle, its barycentrics as affine functions of the pixel offset (ox, oy)
    # from the corner ``lo`` of its box: l1 = A1 ox + B1 oy + C1 (l2 alike, l0 = 1 - l1 - l2)
    inv = 1.0 / det[keep]
    e1, e2 = e1[keep], e2[keep]
    A1, B1 = e2[:, 1] * inv, -e2[:, 0] * inv
    A2, B2 = -e1[:, 1] * inv, e1[:, 0] * inv
    ox0, oy0 = lo[keep, 0] - tri[keep, 0, 0], lo[keep, 1] - tri[keep, 0, 1]
    coef = np.stack([A1, B1, A1 * ox0 + B1 * oy0, A2, B2, A2 * ox0 + B2 * oy0],
                    1).astype(np.float32)
    ext, lo = ext[keep], lo[keep]
    side = np.maximum(ext[:, 0], ext[:, 1])
    inv_z = 1.0 / zs
    izk = inv_z[F[keep]]                            # (k, 3) each triangle's corners' 1 / z
    iz0, iz1, iz2 = izk[:, 0], izk[:, 1], izk[:, 2]
    d1, d2 = iz1 - iz0, iz2 - iz0
    scan = _Scan(coef, ext, lo, side, w, h, budget)
    if closed is not None and c[keep].any() and not c[keep].all():
        # the closed skin first; then the other parts (eyes, teeth, tongue, lashes) but
        # those the skin hides over their whole box: seen only through the skin's holes,
        # or in front of it, they were two fifths of the work
        ck = c[keep]
        skin = scan(np.flatnonzero(ck))
        sbuf = np.zeros(h * w)
        np.maximum.at(sbuf, skin[0], iz0[skin[1]] + skin[2] * d1[skin[1]]
                      + skin[3] * d2[skin[1]])
        rest = np.flatnonzero(~ck)
        near = np.maximum(np.maximum(iz0[rest], iz1[rest]), iz2[rest])
        rest = rest[~_hidden(sbuf.reshape(h, w), lo[rest], lo[rest] + ext[rest] - 1, near)]
        parts = [skin, scan(rest)]
    else:
        parts = [scan(np.arange(len(keep)))]
    if not any(len(p[0]) for p in parts):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    pix, t = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    l1 = np.concatenate([p[2] for p in parts]).astype(np.float64)
    l2 = np.concatenate([p[3] for p in parts]).astype(np.float64)
    s = iz0[t] + l1 * d1[t] + l2 * d2[t]            # 1 / depth (affine on the screen)
    sbuf = np.zeros(h * w)
    np.maximum.at(sbuf, pix, s)                    # the z-buffer (as 1 / z: the nearest)
    win = np.flatnonzero(s >= sbuf[pix])
    # a tie (two triangles at one depth: a shared edge) keeps one fragment per pixel
    owner = np.full(h * w, -1, np.int64)
    owner[pix[win]] = win
    win = owner[owner >= 0]
    tw, l1, l2 = t[win], l1[win], l2[win]
    inv = 1.0 / s[win]
    lz = np.stack([(1.0 - l1 - l2) * iz0[tw], l1 * iz1[tw], l2 * iz2[tw]], -1) * inv[:, None]
    return pix[win], keep[tw], lz   # perspective-correct barycentrics


#: the tile (px) of :func:`_hidden`'s coarse depth test
TILE = 8


def _hidden(sbuf: np.ndarray, lo: np.ndarray, hi: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(n,) bool: triangles whose pixel box ``lo`` .. ``hi`` (inclusive, (n, 2) x, y) lies
    within 2 x 2 tiles of :data:`TILE` px where every pixel's nearest surface so far
    (``sbuf`` (H, W), 1 / z; 0: none) is nearer than the triangle's nearest corner
    (``near``, 1 / z): no pixel of theirs can win the depth test. Conservative: larger
    boxes are never hidden."""
    h, w = sbuf.shape
    th, tw = -(-h // TILE), -(-w // TILE)
    pad = np.full((th * TILE, tw * TILE), np.inf)   # outside the frame: nothing is drawn
    pad[:h, :w] = sbuf
    tile = np.full((th + 1, tw + 1), np.inf)
    tile[:th, :tw] = pad.reshape(th, TILE, tw, TILE).min((1, 3))
    block = np.minimum(np.minimum(tile[:-1, :-1], tile[1:, :-1]),
                       np.minimum(tile[:-1, 1:], tile[1:, 1:]))   # (th, tw)
    t0, t1 = lo // TILE, hi // TILE
    small = ((t1 - t0) <= 1).all(1)
    # the float32 edge tests admit pixels a hair outside a triangle: a margin on its depth
    return small & (near * (1 + 1e-4) < block[t0[:, 1], t0[:, 0]])


class _Scan:
    """The pixel centres inside a set of triangles (indices into the kept triangles):
    (pixel (n,), triangle (n,), l1 (n,), l2 (n,) float32 screen barycentrics). Triangles
    are taken by the size of their box, in chunks of about ``budget`` pixels."""

    def __init__(self, coef, ext, lo, side, w, h, budget):
        self.coef, self.ext, self.lo, self.side = coef, ext, lo, side
        self.w, self.h, self.budget = w, h, budget

    def __call__(self, sel: np.ndarray):
        w, h, ext, lo, coef = self.w, self.h, self.ext, self.lo, self.coef
        side = self.side[sel]
        order = sel[np.argsort(side, kind="stable")]    # small triangles first
        bounds = np.searchsorted(np.sort(side, kind="stable"),
                                 np.arange(1, max(w, h) + 2))
        chunks = []
        for m in range(1, max(w, h) + 1):  # the triangles whose box is m px at most wide or
            s0, s1 = bounds[m - 1], bounds[m]   # high, in chunks of ``budget`` pixels
            step = max(1, self.budget // (m * m))
            chunks += [order[s:min(s + step, s1)] for s in range(s0, s1, step)]
        eps = -1e-5   # float32 edge tests: a pixel centre on a shared edge goes to both
        out = [], [], [], []
        for ids in chunks:
            ew, eh = ext[ids].max(0)
            oy, ox = np.divmod(np.arange(eh * ew, dtype=np.int64), ew)
            oxf, oyf = ox.astype(np.float32), oy.astype(np.float32)
            k = coef[ids]
            l1 = k[:, 0:1] * oxf + k[:, 1:2] * oyf + k[:, 2:3]      # (n, eh*ew)
            l2 = k[:, 3:4] * oxf + k[:, 4:5] * oyf + k[:, 5:6]
            inside = (l1 >= eps) & (l2 >= eps) & (l1 + l2 <= 1.0 - eps)
            r, q = np.nonzero(inside)
            t = ids[r]
            x = lo[t, 0] + ox[q]
            y = lo[t, 1] + oy[q]
            on = (x < w) & (y < h)
            for acc, a in zip(out, ((y * w + x)[on], t[on], l1[r, q][on], l2[r, q][on])):
                acc.append(a)
        if not chunks:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32),
                    np.zeros(0, np.float32))
        return tuple(np.concatenate(a) for a in out)


def rasterize(vertices: np.ndarray, faces: np.ndarray, cam: Camera,
              closed: np.ndarray | None = None, budget: int = 1 << 19):
    """The nearest triangle at each pixel centre: (triangle index (H, W) int64, -1 where
    none; perspective-correct barycentric weights (H, W, 3) float64). Pixel (i, j)'s
    centre is at (j + 0.5, i + 0.5) in the camera's continuous image coordinates (as the
    ray caster's and OpenCV-style ``cam.project`` with the principal point at the
    centre). Triangles behind the camera are skipped; ``closed`` (F,) bool: triangles of
    closed surfaces seen from outside (the skin), whose back faces are never the nearest
    and are culled (a third of the work on the head); the others are drawn both ways."""
    h, w = cam.height, cam.width
    pix, tri, bary = fragments(vertices, faces, cam, closed, budget)
    index = np.full(h * w, -1, np.int64)
    out = np.zeros((h * w, 3))
    index[pix], out[pix] = tri, bary
    return index.reshape(h, w), out.reshape(h, w, 3)


def render_shaded(vertices: np.ndarray, faces: np.ndarray, cam: Camera,
                  normals: np.ndarray | None = None,
                  closed: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 4) linear RGBA (straight = premultiplied: alpha is 0 or 1) of the grey mesh
    seen by ``cam``, shaded as ``MeshViews(vertices, faces).render(cam, supersample=1)``:
    albedo 0.6 times (0.25 + 0.85 Lambert) with the key light (:func:`key_light`) and the
    interpolated vertex normals, turned to face the camera. ``closed``: as
    :func:`rasterize`'s."""
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    N = vertex_normals(V, F) if normals is None else np.asarray(normals, np.float64)
    pix, tri, b = fragments(V, F, cam, closed)
    rgba = np.zeros((cam.height * cam.width, 4), np.float32)
    if len(pix) == 0:
        return rgba.reshape(cam.height, cam.width, 4)
    VN = np.concatenate([V, N], 1)                     # position and normal, together
    corners = F[tri]                                   # (n, 3)
    pn = (b[:, 0:1] * VN[corners[:, 0]] + b[:, 1:2] * VN[corners[:, 1]]
          + b[:, 2:3] * VN[corners[:, 2]])
    p, n = pn[:, :3], pn[:, 3:]

    def unit(x):
        return x / np.maximum(np.sqrt(np.einsum("nc,nc->n", x, x)), 1e-12)[:, None]

    n = unit(n)
    to_light = unit(key_light(cam) - p)
    facing = np.einsum("nc,nc->n", n, cam.center - p) < 0
    n[facing] *= -1.0                                  # back faces lit as front
    lambert = np.clip(np.einsum("nc,nc->n", n, to_light), 0, None)
    rgba[pix, :3] = (GREY * (0.25 + 0.85 * lambert))[:, None]
    rgba[pix, 3] = 1.0
    return rgba.reshape(cam.height, cam.width, 4)
