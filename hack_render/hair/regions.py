"""Where hair grows on the head: the surface strands are rooted in
(:class:`HeadSurface`: the model's mean rest mesh, its skin triangles and 68 landmarks) and
the regions on it: the scalp above a hairline (:func:`hairline_height`,
:func:`scalp_mask`) and the beard (:func:`beard_mask`). Growing strands in them is
:mod:`hack_render.hair.groom`'s job.

The regions are found on the mean mesh from its 68 landmarks and head-frame angles, with
the thresholds written below; they are procedural, not segmented from data. Coordinates
are metres in the model frame (y up, z forward, x the subject's left).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry.nearest import PointTree
from hack_render.geometry.normals import vertex_normals
from hack_render.hair.style import HairStyle

SKIN_MATERIALS = ("M_Face", "M_BackHead")
#: Scalp hairline height (y, metres) by azimuth about the head's vertical axis (degrees, 0
#: = front), on the mean mesh; recession and a widow's peak move it (:func:`scalp_mask`).
HAIRLINE_KNOTS = ((0, 0.118), (25, 0.115), (45, 0.097), (60, 0.074), (75, 0.056),
                  (100, 0.046), (115, 0.02), (135, -0.02), (180, -0.045))


@dataclass
class HeadSurface:
    """The rest mesh strands are grown on and rooted in: vertices (N, 3) metres, faces
    (F, 3), the skin triangles (``skin``: face indices of :data:`SKIN_MATERIALS`), the 68
    landmark vertex indices.

    What every groom grown on it reads is made once per surface, on first use (the
    arrays are not to be changed after): :attr:`normals`, :attr:`skin_centroids` and
    their k-d tree, :attr:`skin_vertices`, their normals and k-d tree (the collision
    proxy's, ``strands.BodyProxy.of``)."""

    vertices: np.ndarray
    faces: np.ndarray
    skin: np.ndarray
    landmarks: np.ndarray

    @cached_property
    def digest(self) -> str:
        """A hash of the vertices and faces: the surface's part of a groom's cache key
        (``groom.GroomCache``)."""
        return hashlib.blake2b(np.ascontiguousarray(self.vertices).tobytes() +
                               np.ascontiguousarray(self.faces).tobytes(),
                               digest_size=16).hexdigest()

    @cached_property
    def normals(self) -> np.ndarray:
        """(N, 3) unit vertex normals of the whole mesh."""
        return vertex_normals(self.vertices, self.faces)

    @cached_property
    def skin_centroids(self) -> np.ndarray:
        """(len(skin), 3) the skin triangles' centroids."""
        return self.vertices[self.faces[self.skin]].mean(1)

    @cached_property
    def centroid_tree(self) -> PointTree:
        """A k-d tree over :attr:`skin_centroids`."""
        return PointTree(self.skin_centroids)

    @cached_property
    def skin_vertices(self) -> np.ndarray:
        """Sorted indices of the skin triangles' vertices."""
        return np.unique(self.faces[self.skin])

    @cached_property
    def skin_normals(self) -> np.ndarray:
        """(N, 3) unit vertex normals of the skin triangles alone (zero elsewhere)."""
        return vertex_normals(self.vertices, self.faces[self.skin])

    @cached_property
    def skin_tree(self) -> PointTree:
        """A k-d tree over the :attr:`skin_vertices`' positions."""
        return PointTree(self.vertices[self.skin_vertices])

    @staticmethod
    def from_model(model) -> HeadSurface:
        """From a ``HackModel``, a ``PosingModel`` or a dict of the model file's arrays."""
        def arr(x):
            return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)

        if isinstance(model, dict):
            a = model
            v, f, fm = a["template_vertices"], a["faces"], a["face_material"]
            names, lm = [str(s) for s in a["material_names"]], a["landmark_indices"]
        else:
            v, f, fm = model.template, model.faces, model.face_material
            names = list(model.material_names)
            lm = getattr(model, "landmark_indices", None)
            if lm is None:
                lm = model.arrays["landmark_indices"]
        fm = arr(fm)
        ids = [names.index(m) for m in SKIN_MATERIALS if m in names]
        if not ids:
            raise HackError(f"hair: the model has none of the skin materials "
                            f"{', '.join(SKIN_MATERIALS)}; strands need a skin to root on.")
        return HeadSurface(arr(v).astype(np.float64), arr(f).astype(np.int64),
                           np.flatnonzero(np.isin(fm, ids)), arr(lm).astype(np.int64))


def hairline_height(azimuth_deg: np.ndarray, style: HairStyle) -> np.ndarray:
    """The scalp's lower edge (y, metres) at each azimuth (degrees, 0 front, either side)."""
    a = np.abs(azimuth_deg)
    knots = np.asarray(HAIRLINE_KNOTS, np.float64)
    y = np.interp(a, knots[:, 0], knots[:, 1])
    # recession: the front and (more) the temples move up towards the crown (an M shape)
    front = np.clip((100.0 - a) / 40.0, 0.0, 1.0)
    temples = np.exp(-((a - 48.0) / 14.0) ** 2)
    y = y + style.hairline * (0.035 * front + 0.02 * temples)
    return y - style.widows_peak * 0.014 * np.exp(-(a / 9.0) ** 2)


def _azimuth(p: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(p[..., 0], p[..., 2] - 0.005))


def scalp_mask(surface: HeadSurface, style: HairStyle) -> tuple[np.ndarray, np.ndarray]:
    """(skin face indices on the scalp, a soft 0..1 density weight each): above the hairline
    (:func:`hairline_height`, a 6 mm soft edge), not on the ears."""
    cent = surface.skin_centroids
    edge = cent[:, 1] - hairline_height(_azimuth(cent), style)
    ear = (np.abs(cent[:, 0]) > 0.066) & (cent[:, 1] > -0.045) & (cent[:, 1] < 0.05) & \
        (cent[:, 2] > -0.04) & (cent[:, 2] < 0.03)
    weight = np.clip(edge / 0.006 + 0.5, 0.0, 1.0) * ~ear
    keep = weight > 0
    return surface.skin[keep], weight[keep]


def beard_mask(surface: HeadSurface, beard: str) -> np.ndarray:
    """Skin face indices of a ``stubble``/``full`` beard (cheeks below the line from the
    jaw's top to the mouth's corners, moustache, chin, under the jaw) or a ``goatee``."""
    lm = surface.vertices[surface.landmarks]
    c = surface.skin_centroids
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    ax = np.abs(x)
    mouth_half = abs(lm[54, 0] - lm[48, 0]) / 2 + 0.003
    nose_y, lip_top, lip_bottom = lm[33, 1] - 0.002, lm[51, 1] + 0.0015, lm[57, 1] - 0.004
    lips = (ax < mouth_half) & (y < lip_top) & (y > lip_bottom)
    jaw = lm[0:17]
    order = np.argsort(jaw[:, 0])
    jaw_y = np.interp(x, jaw[order, 0], jaw[order, 1])
    chin = lm[8, 1]
    moustache = (ax < mouth_half + 0.004) & (y < nose_y) & (y >= lip_top - 0.001) & (z > 0.07)
    if beard == "goatee":
        region = ((ax < mouth_half + 0.005) & (y < lip_bottom + 0.001) & (y > chin - 0.012)
                  & (z > 0.06)) | moustache
        return surface.skin[region & ~lips]
    jaw_top = abs(lm[1, 0])
    cheek_line = np.interp(ax, [mouth_half, jaw_top], [lm[48, 1] + 0.012, lm[1, 1] - 0.01])
    cheeks = (y < cheek_line) & (ax < jaw_top + 0.004) & (z > 0.025) & (y > jaw_y - 0.004)
    under = (y <= jaw_y + 0.002) & (y > np.maximum(jaw_y - 0.035, chin - 0.035)) & \
        (z > -0.005) & (ax < jaw_top)
    return surface.skin[(cheeks | under | moustache) & ~lips]
