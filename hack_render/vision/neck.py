"""The neck's skin below the jaw, for the fit's bake (issue 62: "the neck and scalp skin
the photo shows are baked like the face").

The face's skin test (:func:`hack_render.vision.segment.skin_colour_mask`, Mahalanobis 3
of the cheeks' chromaticity) rejects most of a neck: it lies in the jaw's shade and is lit
at another angle, so its chromaticity drifts (on Grace Hopper's portrait nearly all of
it was called clothes). Below the jaw the test is looser (:data:`NECK_K`), and what it
takes is held to the neck's place: under the jaw's contour in the face's upright frame,
between the jaw's angles, down to a face's length below the chin, joined to the face's
own skin. A white collar or a dark tie is far from skin in chromaticity at any looseness
that keeps the neck; a skin-coloured shirt would pass, as it passes the face's test.

A grey photo has no chromaticity to tell a neck from a collar: no neck there.

The tracker has a neck of its own for its outline term
(:func:`hack_render.track.outline.head_neck_mask`: the face's strict test below the mouth,
without a person segmentation, ~60 ms a frame); one mask for both would need the
real-clip tracking bench run again (a follow-up)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from hack_render.vision.detection import FaceLandmarks
from hack_render.vision.glasses import upright_xy

#: the neck's skin test: Mahalanobis distance of the face's skin chromaticity (the face's
#: own test takes 3)
NECK_K = 5.0
#: how far below the chin the neck reaches, in face lengths (nose bridge, landmark 27, to
#: chin, 8)
NECK_DEPTH = 1.0
#: joined to the face's skin across gaps of this many pixels (a crease under the jaw)
JOIN_PX = 2
#: no darker than this share of the face's skin's median brightness: a dark collar's
#: pixels can have a skin's chromaticity (the astronaut's black turtleneck: a speckle
#: of them along its edge)
NECK_DARK = 0.35


def neck_region(face: FaceLandmarks, shape) -> np.ndarray:
    """(H, W) bool: below the jaw's contour (landmarks 2-14, in the face's upright
    frame), between the jaw's angles (3 and 13), down to :data:`NECK_DEPTH` face lengths
    below the chin."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    ux, uy = upright_xy(face, xx, yy)
    px, py = upright_xy(face, face.points[:, 0], face.points[:, 1])
    jx, jy = px[2:15], py[2:15]
    order = np.argsort(jx)
    jaw_y = np.interp(ux, jx[order], jy[order])
    length = float(py[8] - py[27])
    lo, hi = sorted((px[3], px[13]))
    return (uy > jaw_y) & (ux >= lo) & (ux <= hi) & (uy < py[8] + NECK_DEPTH * length)


def _upright(points: np.ndarray, shape):
    """(x, y) of every pixel of an image of ``shape`` and of the 68 ``points`` in the
    face's upright frame (its roll, the eyes' line of landmarks 36 and 45, undone)."""
    h, w = shape
    d = points[45] - points[36]
    face = SimpleNamespace(points=points, roll_deg=math.degrees(math.atan2(-d[1], d[0])))
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    ux, uy = upright_xy(face, xx, yy)
    px, py = upright_xy(face, points[:, 0], points[:, 1])
    return ux, uy, px, py


def below_face(points: np.ndarray, shape) -> np.ndarray:
    """(H, W) bool: what lies below the face in the photo, in the face's upright frame
    (the eyes' line, landmarks 36 and 45, level): below the jaw's contour (landmarks
    0-16) between its two ends, and below the mouth's row (the mean of landmarks 48-67)
    across the whole width (the neck's sides, a collar risen over a turned jaw, the
    shoulders, the chest). ``points``: the 68 landmarks (pixels) of the photo of
    ``shape``. What of it is not the person's skin has no counterpart in the model (it
    has no clothes): a collar, a hand over the neck, a microphone, the background."""
    ux, uy, px, py = _upright(points, shape)
    jx, jy = px[:17], py[:17]
    order = np.argsort(jx)
    jaw_y = np.interp(ux, jx[order], jy[order])
    below = (uy > jaw_y) & (ux >= jx.min()) & (ux <= jx.max())
    return below | (uy > py[48:68].mean())


def above_brows(points: np.ndarray, shape) -> np.ndarray:
    """(H, W) bool: above the brows' row (the mean of landmarks 17-26) in the face's
    upright frame (as :func:`below_face`'s): the scalp and the hair over it, and what
    lies above the head. What of it outside the face's oval is not skin the bake took has
    no counterpart in the model (it has no hair): hair the segmentation did not call hair
    (a crew cut's close-cropped top), the background above a head the model's skull
    overtops."""
    _, uy, _, py = _upright(points, shape)
    return uy < py[17:27].mean()


def neck_skin(face: FaceLandmarks, rgb8: np.ndarray, loose_skin: np.ndarray,
              face_skin: np.ndarray, person: np.ndarray, grey: bool) -> np.ndarray:
    """(H, W) bool: the pixels of ``loose_skin`` (the skin test at :data:`NECK_K`) in the
    person (``person``) and :func:`neck_region`, not darker than :data:`NECK_DARK` of the
    face's skin (``face_skin``) and opened by a pixel (no speckle), in the parts that
    join the face's skin within :data:`JOIN_PX`, their holes filled; none in a grey
    photo."""
    from scipy import ndimage

    if grey or not face_skin.any():
        return np.zeros(face_skin.shape, bool)
    lum = rgb8.astype(np.float32).mean(-1)
    cand = loose_skin & person & neck_region(face, face_skin.shape)
    cand &= lum > NECK_DARK * float(np.median(lum[face_skin]))
    cand = ndimage.binary_opening(cand, iterations=1)
    lab, n = ndimage.label(ndimage.binary_dilation(cand | face_skin, iterations=JOIN_PX))
    if n == 0:
        return cand
    ids = np.unique(lab[face_skin])
    neck = cand & np.isin(lab, ids[ids > 0])
    # a mole's or a crease's few dark pixels inside it are the neck's too
    return ndimage.binary_fill_holes(neck) & person & ~face_skin | neck
