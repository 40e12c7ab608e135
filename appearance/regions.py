"""Region labels of the skin atlas, derived from the template geometry in UV space.

Each valid texel of the atlas (see :mod:`appearance.uv`) gets one label from
:data:`REGIONS`, decided from its template surface point (centimetres) relative to the
68 Multi-PIE landmark vertices of ICT-FaceKit (DATA.md): lips inside the outer lip
contour, eyelids in ellipses around the eye contours, brows along the brow polylines,
the nose between the bridge and the alae, and so on. The sockets (mouth and eye socket
vertex groups) are labelled from the vertex ranges. The labels are geometric
approximations (e.g. the hairline is a smooth curve, the ears a box around the pinna of
the template) meant for regional statistics in the generator and for segmentation masks;
they are not hand-painted.

The scalp is decided from the 3-D point by one hairline for both atlas tiles, so that
texels meeting at the UV seam between the face tile and the back-of-head tile (which
runs over the crown and down the temples in front of the ears) get the same label
(:func:`hairline_y`): above the forehead a parabola in x, about 5.6 cm above the brows
in the middle and lower at the temples, and at the sides no lower than the top of the
ear (:data:`EAR_TOP_Y`), rising 1 cm per cm forward of z = :data:`SIDEBURN_Z` (a
temple / sideburn line). On the back tile the hair also comes down behind the ears to
the nape, :func:`nape_y`, about ear-lobe height (y = -1 cm) behind z = -2 cm, rising
towards the ears; the nape only ever lowers the hairline, so the front of the crown on
the back tile is scalp like the face tile's scalp strip next to it (an earlier nape curve
rose without bound towards the front and labelled that strip ``neck``: a light band
across the top of the forehead in the renders).
"""

from __future__ import annotations

import numpy as np

from appearance.uv import UVLayout, default_template, rasterize_layout

#: label id -> name; 0 is "outside the skin islands".
REGIONS = ("none", "forehead", "brows", "eyelids", "nose", "cheeks", "lips", "upper_lip",
           "chin", "jaw", "ears", "scalp", "neck", "sockets")
REGION_ID = {n: i for i, n in enumerate(REGIONS)}

#: Multi-PIE 68 landmark vertex indices of the ICT-FaceKit template (DATA.md).
LANDMARK_VERTICES = np.array([
    1225, 1888, 1052, 367, 1719, 1722, 2199, 1447, 966, 3661, 4390, 3927, 3924, 2608, 3272,
    4088, 3443, 268, 493, 1914, 2044, 1401, 3615, 4240, 4114, 2734, 2509, 978, 4527, 4942,
    4857, 1140, 2075, 1147, 4269, 3360, 1507, 1542, 1537, 1528, 1518, 1511, 3742, 3751,
    3756, 3721, 3725, 3732, 5708, 5695, 2081, 0, 4275, 6200, 6213, 6346, 6461, 5518, 5957,
    5841, 5702, 5711, 5533, 6216, 6207, 6470, 5517, 5966])
SOCKET_VERTICES = (11248, 14061)  # mouth socket and eye sockets, inclusive (DATA.md)
#: Template height (cm) of the top of the ears: the box of the ``ears`` label ends here,
#: and the hair at the temples comes down to it.
EAR_TOP_Y = 5.5
#: Depth (cm) behind which the temple hairline stays at :data:`EAR_TOP_Y`; the UV seam
#: at the temples runs at z = -0.3 to 0.3 cm.
SIDEBURN_Z = 0.5


def hairline_y(x: np.ndarray, z: np.ndarray, brow_y: float) -> np.ndarray:
    """Height (cm) of the hairline over the template point (x, z), both atlas tiles.

    Args:
        x, z: (N,) template coordinates, cm.
        brow_y: height of the highest brow landmark, cm.
    Returns:
        (N,) y, cm: a parabola about 5.6 cm above the brows at x = 0, lower at the
        temples, but above the ears no lower than :data:`EAR_TOP_Y` plus 1 cm per cm
        forward of :data:`SIDEBURN_Z`.
    """
    front = brow_y + 5.6 - 0.07 * x ** 2
    side = EAR_TOP_Y + np.clip(z - SIDEBURN_Z, 0, None)
    return np.minimum(front, side)


def nape_y(z: np.ndarray) -> np.ndarray:
    """(N,) height (cm) of the hairline at the back of the head, at template depth z (cm).

    About ear-lobe height (-1 cm) behind z = -2 cm, rising towards the ears. Used only to
    lower the hairline (:func:`hairline_y`) on the back-of-head tile.
    """
    return -1.0 + 0.25 * np.clip(z + 2.0, 0, None) ** 2


def _inside(poly_xy: np.ndarray, pts: np.ndarray, radius: float = 0.0) -> np.ndarray:
    # deferred (~0.1 s): the labelling runs once per atlas height, then comes from the
    # caches (``generator.atlas_context``, the dataset's label atlas)
    from matplotlib.path import Path as MplPath

    return MplPath(poly_xy).contains_points(pts, radius=radius)


def _seg_dist(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance from (N, 2) points to a 2-D polyline (M, 2)."""
    d = np.full(len(pts), np.inf)
    for a, b in zip(poly[:-1], poly[1:]):
        ab = b - a
        t = np.clip(((pts - a) @ ab) / max(ab @ ab, 1e-12), 0, 1)
        d = np.minimum(d, np.linalg.norm(pts - (a + t[:, None] * ab), axis=1))
    return d


def region_labels(layout: UVLayout | int) -> np.ndarray:
    """(H, 2H) uint8 region label per texel (0 outside the skin), see :data:`REGIONS`.

    Args:
        layout: a :class:`UVLayout` or an atlas height H.
    """
    lay = rasterize_layout(layout) if isinstance(layout, (int, np.integer)) else layout
    lm = default_template().vertices[LANDMARK_VERTICES]
    lab = np.zeros(lay.mask.shape, np.uint8)
    p = lay.position[lay.mask].astype(np.float64)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    xy = p[:, :2]
    face = lay.tile[lay.mask] == 0
    vert = lay.vertex[lay.mask]
    out = np.zeros(len(p), np.uint8)

    def put(name, sel):
        free = out == 0
        out[free & sel] = REGION_ID[name]

    front = face & (z > 2.0)
    put("sockets", (vert >= SOCKET_VERTICES[0]) & (vert <= SOCKET_VERTICES[1]))
    put("lips", front & _inside(lm[48:60, :2], xy, radius=-0.12) & (z > lm[48, 2] - 1.5))
    for eye in (lm[36:42], lm[42:48]):
        c = eye[:, :2].mean(0)
        half_w = 0.5 * np.ptp(eye[:, 0]) * 1.35
        dy = y - c[1]
        ry = np.where(dy > 0, 1.25, 0.85)
        put("eyelids", front & (((x - c[0]) / half_w) ** 2 + (dy / ry) ** 2 < 1.0))
    brow_d = np.minimum(_seg_dist(xy - [0, 0.2], lm[17:22, :2]),
                        _seg_dist(xy - [0, 0.2], lm[22:27, :2]))
    put("brows", front & (brow_d < 0.55))
    y_top, y_base = lm[27, 1], lm[33, 1] - 0.25
    alar = np.abs(lm[[31, 35], 0]).max() + 0.55
    t = np.clip((y_top - y) / max(y_top - y_base, 1e-6), 0, 1)
    put("nose", front & (y <= y_top + 0.3) & (y >= y_base) & (np.abs(x) < 0.8 + t ** 2 * (alar - 0.8)))
    mouth_w = np.abs(lm[[48, 54], 0]).max() + 0.6
    put("upper_lip", front & (y < y_base + 0.1) & (y > lm[51, 1]) & (np.abs(x) < mouth_w))
    put("chin", front & (y <= lm[57, 1]) & (y > lm[8, 1] - 0.8) & (np.abs(x) < 2.6))
    # The jaw line (landmarks 0-16) separates the face from the neck, a bit below the contour.
    jaw = lm[3:14]
    jaw_y = np.interp(x, jaw[:, 0], jaw[:, 1]) - 0.8
    put("neck", face & (y < jaw_y) & (np.abs(x) < np.abs(jaw[0, 0])))
    put("neck", face & (y < lm[8, 1] - 1.2))
    # Hairline, the same on both tiles at the seam (see the module docstring).
    brow_y = lm[17:27, 1].max()
    hair_y = hairline_y(x, z, brow_y)
    put("scalp", face & (y > hair_y))
    put("forehead", face & (y > brow_y - 0.2) & (np.abs(x) < np.abs(lm[0, 0]) + 0.3))
    put("cheeks", face & (y > lm[57, 1] - 0.3))
    put("jaw", face)
    back = ~face
    put("ears", back & (y > -1.5) & (y < EAR_TOP_Y) & (z > -3.5) & (z < 1.0)
        & (np.abs(x) > 7.0))
    # Back of the head: the hairline, lowered behind the ears down to the nape.
    put("scalp", back & (y > np.minimum(hair_y, nape_y(z))))
    put("neck", back)
    lab[lay.mask] = out
    return lab
