"""Glasses' frames where they cross the brows: occluders the skin test cannot take there.

:func:`hack_render.vision.segment.segment` tests for occluders (pixels that are not skin)
only outside the eyes, brows and lips, whose own colours are not the skin's. A frame's
top bar runs along the brows, so where it crosses the brows' polygons it stayed in the
photometric loss and in the bake: Grace Hopper's dark top bar baked into the texture as
blue-grey strokes at her brows' outer ends (docs/fit.md).

Inside the brows, a pixel that is not skin is taken as an occluder where it is joined
(8-connected, through pixels that are not skin) to an occluder that reaches below the
upper lid **between the eye's corners**: the rim of a frame around the eye, a strand
or a hand across it. A fringe that touches the brows from above, or hair at the temples
that reaches down beside the eye, does not reach there, and leaves the brows as they
are (the astronaut's dark brows, joined to her hair at the temple, are kept; the
cameraman's fringe does not reach his lids).
"""

from __future__ import annotations

import math

import numpy as np


def upright_xy(face, x, y) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` turned into the face's upright frame (its roll undone about the nose
    tip, landmark 30), as :func:`hack_render.vision.segment._upright` (rows)."""
    a = math.radians(face.roll_deg)
    c = face.points[30]
    dx, dy = np.asarray(x) - c[0], np.asarray(y) - c[1]
    return (c[0] + dx * math.cos(a) - dy * math.sin(a),
            c[1] + dx * math.sin(a) + dy * math.cos(a))


def under_lids(face, shape) -> np.ndarray:
    """(H, W) bool: below each eye's upper lid (landmarks 37-38, 43-44) and between its
    corners (36-39, 42-45), in the face's upright frame."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    ux, uy = upright_xy(face, xx, yy)
    px, py = upright_xy(face, face.points[:, 0], face.points[:, 1])
    out = np.zeros((h, w), bool)
    for a, b, lid in ((36, 39, [37, 38]), (42, 45, [43, 44])):
        x0, x1 = sorted((px[a], px[b]))
        out |= (ux > x0) & (ux < x1) & (uy > py[lid].mean())
    return out


def frames_in_brows(face, skin: np.ndarray, occluder: np.ndarray,
                    brows: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``brows`` (the brows' widened polygons) to add to
    ``occluder`` (the module docstring): not ``skin``, joined through pixels that are
    not skin to an occluder part that reaches under a lid between the eye's corners."""
    from scipy import ndimage

    eight = np.ones((3, 3), bool)
    lab, _ = ndimage.label(occluder, structure=eight)
    ids = np.unique(lab[occluder & under_lids(face, occluder.shape) & ~brows])
    beside = np.isin(lab, ids[ids > 0])
    if not beside.any():
        return np.zeros_like(occluder)
    cand = ~skin & brows & ~occluder
    lab, _ = ndimage.label(cand | beside, structure=eight)
    ids = np.unique(lab[beside])
    return np.isin(lab, ids[ids > 0]) & cand
