"""Glasses' frames where they cross the brows: occluders the skin test cannot take there.

:func:`hack_render.vision.segment.segment` tests for occluders (pixels that are not skin)
only outside the eyes, brows and lips, whose own colours are not the skin's. A frame's
top bar runs along the brows, so where it crosses the brows' polygons it stayed in the
photometric loss and in the bake: Grace Hopper's dark top bar baked into the texture as
blue-grey strokes at her brows' outer ends (docs/fit.md).

Inside the brows, a pixel that is not skin is taken as an occluder where it is joined
(8-connected, through pixels that are not skin) to a **thin** occluder (one an opening
by a disk of ``THIN`` outer-eye distances removes: a frame's bar or rim, not a blob)
that reaches below the upper lid **between the eye's corners**, and only where that
holds on **both** sides of the face (a pair of glasses sits on both eyes). A fringe
that touches the brows from above, or hair at the temples that reaches down beside the
eye, does not reach there, and leaves the brows as they are (the astronaut's dark
brows, joined to her hair at the temple, are kept; the cameraman's fringe does not
reach his lids). On the benchmark's composites (sets 9000-9003, 156 faces the mesh
finds, none wearing glasses) it takes nothing; without the thinness and both-sides
tests it took up to 81 pixels of a face, joined to the segmentation's false occluders
along the far side of a turned face (docs/vision.md).
"""

from __future__ import annotations

import math

import numpy as np

#: the thinness test's disk radius, in outer-eye distances: an opening by it removes
#: what is narrower than its diameter (a frame's bar or rim) and keeps a blob (Grace
#: Hopper's frames: 143 pixels taken at 0.08 to 0.12, none at 0.06, where one side's
#: bar is not thin enough; on the composites, none up to 0.08, a face's brows at 0.1
#: and 0.12: a narrow band, set on one photo with glasses, docs/vision.md)
THIN = 0.08


def upright_xy(face, x, y) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` turned into the face's upright frame (its roll undone about the nose
    tip, landmark 30); its rows are those of
    :func:`hack_render.vision.segment._upright_rows`."""
    a = math.radians(face.roll_deg)
    c = face.points[30]
    dx, dy = np.asarray(x) - c[0], np.asarray(y) - c[1]
    return (c[0] + dx * math.cos(a) - dy * math.sin(a),
            c[1] + dx * math.sin(a) + dy * math.cos(a))


def under_lids(face, shape, origin=(0, 0)) -> np.ndarray:
    """(H, W) bool: below each eye's upper lid (landmarks 37-38, 43-44) and between its
    corners (36-39, 42-45), in the face's upright frame; for the image's window of
    ``shape`` whose top-left pixel is ``origin`` (x, y)."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    xx, yy = xx + origin[0], yy + origin[1]
    ux, uy = upright_xy(face, xx, yy)
    px, py = upright_xy(face, face.points[:, 0], face.points[:, 1])
    out = np.zeros((h, w), bool)
    for a, b, lid in ((36, 39, [37, 38]), (42, 45, [43, 44])):
        x0, x1 = sorted((px[a], px[b]))
        out |= (ux > x0) & (ux < x1) & (uy > py[lid].mean())
    return out


def _disk(r: int) -> np.ndarray:
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return x * x + y * y <= r * r


def frames_in_brows(face, skin: np.ndarray, occluder: np.ndarray,
                    brows: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``brows`` (the brows' widened polygons) to add to
    ``occluder`` (the module docstring): not ``skin``, joined through pixels that are
    not skin to a thin occluder part that reaches under a lid between the eye's corners,
    on both sides of the face (left and right of the nose's line); else none."""
    from scipy import ndimage

    out = np.zeros_like(occluder)
    iod = float(np.linalg.norm(face.points[36] - face.points[45]))
    # the work is done in a box about the brows and eyes, 0.6 outer-eye distances wide
    # of them (the opening's cost grows with the image; the frames are there)
    h, w = occluder.shape
    lo = np.floor(face.points[17:48].min(0) - 0.6 * iod).astype(int).clip(0, [w, h])
    hi = np.ceil(face.points[17:48].max(0) + 0.6 * iod).astype(int).clip(0, [w, h])
    box = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
    occ, skin, brows = occluder[box], skin[box], brows[box]
    if not occ.any():
        return out
    r = max(round(THIN * iod), 1)
    opened = ndimage.binary_opening(np.pad(occ, r, mode="edge"), structure=_disk(r))
    thin = occ & ~opened[r:-r, r:-r]
    eight = np.ones((3, 3), bool)
    lab, _ = ndimage.label(thin, structure=eight)
    ids = np.unique(lab[thin & under_lids(face, occ.shape, lo) & ~brows])
    beside = np.isin(lab, ids[ids > 0])
    if not beside.any():
        return out
    cand = ~skin & brows & ~occ
    lab, _ = ndimage.label(cand | beside, structure=eight)
    ids = np.unique(lab[beside])
    ys, xs = np.nonzero(np.isin(lab, ids[ids > 0]) & cand)
    ux, _ = upright_xy(face, xs + lo[0] + 0.5, ys + lo[1] + 0.5)
    mid, _ = upright_xy(face, face.points[27:31, 0], face.points[27:31, 1])
    if not ((ux < mid.mean()).any() and (ux > mid.mean()).any()):
        return out
    out[ys + lo[1], xs + lo[0]] = True
    return out
