"""Face boxes checked against the person: ``auto``'s detector on hard views.

BlazeFace (:func:`hack_render.vision.boxes.find_boxes`) loses faces seen from 45
degrees above or below at 30-90 degrees of yaw: it boxes a patch of background, or the
head and neck together (up to twice the face's size, some found only in the image turned
by a quarter turn, at a low score), or nothing. MediaPipe's selfie segmentation still
outlines the person there, and a face lies on the person, in the head at the top of the
silhouette. So:

1. **Person**: the selfie segmentation's probability (:func:`person_probability`,
   :mod:`hack_render.vision.person`); its
   largest connected part above 0.5 is the person. No person (under ``MIN_PERSON`` of
   the image): BlazeFace's boxes are returned unchecked.
2. **Verification**: a BlazeFace box of the whole image mostly off the person (its mean
   person probability under ``ON_PERSON``) is dropped, unless BlazeFace is sure of it
   (``SURE``: a face the segmentation missed, someone small in a crowd).
3. **Head region**: the top of the person's silhouette: a square of side the
   silhouette's width over its top 30 % (:func:`head_region`), where the person stands
   upright (:func:`upright`: the frame cuts the silhouette at the bottom at least as
   much as at the top or a side; a photo turned sideways or upside down has its head
   elsewhere, and there is no head search).
4. **Head search**, where no box is left, or every box left is weak (scores under
   ``WEAK``): BlazeFace again on square crops of the head region (``HEAD_CROPS`` times
   its side) resampled to ``CROP_PX`` pixels, so the face fills more of BlazeFace's
   input; its most confident box on the person replaces the weak boxes of its face (on
   the head region, or overlapping it) where it scores higher. (Replacing strong boxes
   too, wherever the head search scores higher, changed the points of faces found
   either way for the worse: a box of the same place from another view gives other
   keypoints, docs/vision.md.)
"""

from __future__ import annotations

import numpy as np

from hack_render.vision import boxes as face_boxes
from hack_render.vision import person

#: the least share of the image the person must cover for the boxes to be checked
MIN_PERSON = 0.01
#: a box is on the person where the mean person probability inside it is at least this
#: (a face's box holds background too: a profile's reaches in front of the face; on the
#: benchmark's composites the boxes on faces were at 0.48 or more, the one on the
#: background at 0.09)
ON_PERSON = 0.25
#: BlazeFace's score from which a box off the person is kept all the same
SURE = 0.8
#: BlazeFace's score under which a box is weak: where every box left is, the head search
#: runs and its candidate replaces the weak boxes of its face where it scores higher (set
#: on the benchmark's composites: docs/vision.md)
WEAK = 0.6
#: the head search's crops: sides in head-region sides (the silhouette's width near its
#: top misses the head's size both ways: a shoulder, hair or a background the
#: segmentation spreads into)
HEAD_CROPS = (1.0, 1.5, 2.0)
CROP_PX = 192               # the head search's crop side, pixels


def person_probability(rgb8: np.ndarray) -> np.ndarray:
    """(H, W) float32: the selfie segmentation's person probability."""
    return person.person_probability(rgb8)


def on_person(prob: np.ndarray, box) -> float:
    """Mean person probability inside ``box`` (left, top, right, bottom; pixels); 0 for
    a box wholly outside the image."""
    h, w = prob.shape
    x0, y0 = max(int(np.floor(box[0])), 0), max(int(np.floor(box[1])), 0)
    x1, y1 = min(int(np.ceil(box[2])), w), min(int(np.ceil(box[3])), h)
    if x1 <= x0 or y1 <= y0:
        return 0.0
    inside = float(prob[y0:y1, x0:x1].sum())
    area = max((box[2] - box[0]) * (box[3] - box[1]), 1.0)
    return inside / area          # the part outside the image counts as off the person


def person_part(prob: np.ndarray) -> np.ndarray | None:
    """The person's largest connected part above 0.5 (bool), or None where it covers
    under ``MIN_PERSON`` of the image."""
    from scipy import ndimage

    mask = prob > 0.5
    lab, n = ndimage.label(mask)
    if n == 0:
        return None
    sizes = ndimage.sum(mask, lab, range(1, n + 1))
    if sizes.max() < MIN_PERSON * mask.size:
        return None
    return lab == 1 + int(np.argmax(sizes))


def upright(mask: np.ndarray) -> bool:
    """Whether a silhouette stands upright: the frame cuts it at the bottom at least as
    much as at the top or a side (a portrait's shoulders), or nowhere (a whole bust)."""
    edges = [mask[-1].mean(), mask[0].mean(), mask[:, 0].mean(), mask[:, -1].mean()]
    return bool(edges[0] >= max(edges[1:]))


def head_region(prob: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(centre (x, y), side) of the square at the top of the person's silhouette
    (:func:`person_part`), side its width over the top 30 % of its height; None where
    there is no person or it is not :func:`upright`."""
    mask = person_part(prob)
    if mask is None or not upright(mask):
        return None
    ys = np.nonzero(mask.any(1))[0]
    y0, y1 = int(ys[0]), int(ys[-1])
    top = mask[y0:y0 + max(int(0.3 * (y1 - y0)), 1)]
    cols = np.nonzero(top.any(0))[0]
    side = float(cols[-1] - cols[0] + 1)
    xs = np.nonzero(mask[y0:y0 + int(side)])[1]
    return np.array([xs.mean() + 0.5, y0 + side / 2]), side


def crop_boxes(rgb8: np.ndarray, centre, side: float) -> list:
    """BlazeFace on the square crop of ``side`` px around ``centre`` resampled to
    ``CROP_PX``: boxes as :func:`~hack_render.vision.boxes.blazeface_boxes`, in the
    image's pixels."""
    import cv2

    k = CROP_PX / side
    to_crop = np.array([[k, 0.0, CROP_PX / 2 - k * centre[0]],
                        [0.0, k, CROP_PX / 2 - k * centre[1]]])
    crop = cv2.warpAffine(rgb8, to_crop, (CROP_PX, CROP_PX), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
    return [((x0 - to_crop[0, 2]) / k, (y0 - to_crop[1, 2]) / k, (x1 - to_crop[0, 2]) / k,
             (y1 - to_crop[1, 2]) / k, s, (kp - to_crop[:, 2]) / k)
            for x0, y0, x1, y1, s, kp in face_boxes.blazeface_boxes(crop)]


def head_box(rgb8: np.ndarray, prob: np.ndarray, region) -> tuple | None:
    """The head search's candidate: BlazeFace's most confident box on the person over
    the crops of the head region (``HEAD_CROPS``), or None."""
    centre, side = region
    found = [b for f in HEAD_CROPS for b in crop_boxes(rgb8, centre, f * side)
             if on_person(prob, b[:4]) >= ON_PERSON]
    return max(found, key=lambda b: b[4], default=None)


def _on_head(box, centre, side: float) -> bool:
    """Whether ``box`` overlaps the head region's square."""
    h = side / 2
    return (box[0] < centre[0] + h and box[2] > centre[0] - h
            and box[1] < centre[1] + h and box[3] > centre[1] - h)


def verified_boxes(rgb8: np.ndarray, boxes: list) -> list:
    """``boxes`` (BlazeFace's, of the whole image) checked against the person, a weak or
    missing face searched for in the head region (the module docstring)."""
    prob = person_probability(rgb8)
    if person_part(prob) is None:
        return boxes
    kept = [b for b in boxes if b[4] >= SURE or on_person(prob, b[:4]) >= ON_PERSON]
    if any(b[4] >= WEAK for b in kept):    # a confident face: no search
        return kept
    region = head_region(prob)
    if region is None:
        return kept
    cand = head_box(rgb8, prob, region)
    if cand is None:
        return kept
    # the boxes of the candidate's face: on the head region, or overlapping the candidate
    same = [b for b in kept if _on_head(b, *region) or face_boxes.iou(b[:4], cand[:4]) >= 0.3]
    if any(b[4] >= cand[4] for b in same):
        return kept
    return [cand] + [b for b in kept if not any(b is o for o in same)]
