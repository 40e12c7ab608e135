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
    lo = np.floor(tri.min(1)).astype(np.int64) + 1  # first pixel centre >= min
    hi = np.floor(tri.max(1)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w - 1, h - 1])
    ext = hi - lo + 1
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]   # twice the signed area on screen
    ok = (z[F] > 1e-6).all(1) & (ext > 0).all(1) & (np.abs(det) > 1e-12)
    if closed is not None:
        # a camera looking along +z with y down: a triangle wound outward that faces it
        # has a negative signed area; outward winding where the closed part's signed
        # volume is positive (any winding of the file works)
        c = np.asarray(closed, bool)
        P = V[F[c]]
        out = np.sign(np.einsum("fc,fc->f", np.cross(P[:, 0], P[:, 1]), P[:, 2]).sum()) or 1.0
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
    side = ext[keep].max(1)
    order = np.argsort(side, kind="stable")         # small triangles first (into keep)
    bounds = np.searchsorted(side[order], np.arange(1, max(w, h) + 2))
    chunks = []
    for m in range(1, max(w, h) + 1):     # the triangles whose bounding box is m px at most
        s0, s1 = bounds[m - 1], bounds[m]  # wide or high, in chunks of ``budget`` pixels
        step = max(1, budget // (m * m))
        chunks += [order[s:min(s + step, s1)] for s in range(s0, s1, step)]
    inv_z = 1.0 / zs
    ext, lo = ext[keep], lo[keep]
    eps = -1e-5   # float32 edge tests: a pixel centre on a shared edge goes to both
    frag_pix, frag_tri, frag_l = [], [], []
    for ids in chunks:
        ew, eh = ext[ids].max(0)
        oy, ox = np.divmod(np.arange(eh * ew, dtype=np.float32), np.float32(ew))
        k = coef[ids]
        l1 = k[:, 0:1] * ox + k[:, 1:2] * oy + k[:, 2:3]      # (n, eh*ew)
        l2 = k[:, 3:4] * ox + k[:, 4:5] * oy + k[:, 5:6]
        inside = (l1 >= eps) & (l2 >= eps) & (l1 + l2 <= 1.0 - eps)
        r, q = np.nonzero(inside)
        t = ids[r]
        x = lo[t, 0] + ox[q].astype(np.int64)
        y = lo[t, 1] + oy[q].astype(np.int64)
        on = (x < w) & (y < h)
        r, q, t, x, y = r[on], q[on], t[on], x[on], y[on]
        l1, l2 = l1[r, q].astype(np.float64), l2[r, q].astype(np.float64)
        lz = np.stack([1.0 - l1 - l2, l1, l2], -1) * inv_z[F[keep[t]]]  # screen bary / z
        frag_pix.append(y * w + x)
        frag_tri.append(t)
        frag_l.append(lz)
    if not frag_pix:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    pix, t, lz = np.concatenate(frag_pix), np.concatenate(frag_tri), np.concatenate(frag_l)
    depth = 1.0 / lz.sum(1)
    zbuf = np.full(h * w, np.inf)
    np.minimum.at(zbuf, pix, depth)                # the z-buffer
    win = np.flatnonzero(depth <= zbuf[pix])
    # a tie (two triangles at one depth: a shared edge) keeps one fragment per pixel
    owner = np.full(h * w, -1, np.int64)
    owner[pix[win]] = win
    win = owner[owner >= 0]
    return pix[win], keep[t[win]], lz[win] * depth[win, None]


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
    corners = F[tri]                                   # (n, 3)
    p = np.einsum("nk,nkc->nc", b, V[corners])
    n = np.einsum("nk,nkc->nc", b, N[corners])

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
