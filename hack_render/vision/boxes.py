"""Face boxes at any in-plane angle: MediaPipe's BlazeFace, offline.

Both of BlazeFace's models (short and full range, from the ``mediapipe`` wheel) on the
image, merged (:func:`blazeface_boxes`); the image also mirrored where no box is found
upright (:func:`mirrored_boxes`), then both with its contrast equalised
(:func:`equalized`), then turned by 90, 270 and 180 degrees (:func:`find_boxes`; the
order and the variants not taken: docs/vision.md). A box is (left, top, right, bottom,
score, keypoints (6, 2)) in the image's pixels; the keypoints are BlazeFace's: the
subject's right eye, left eye, nose tip, mouth, right and left ear tragion.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

#: BlazeFace's keypoints' mirror images (the eyes and the ears swap)
KP_MIRROR = np.array([1, 0, 2, 3, 5, 4])

_CACHE: dict = {}


def _blazeface(model: int):
    key = ("blazeface", model)
    if key not in _CACHE:
        os.environ.setdefault("GLOG_minloglevel", "2")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mediapipe as mp

            _CACHE[key] = mp.solutions.face_detection.FaceDetection(
                model_selection=model, min_detection_confidence=0.4)
    return _CACHE[key]


def iou(a, b) -> float:
    """Intersection over union of two boxes (left, top, right, bottom)."""
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    area = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / max(area, 1e-9)


def _nms(boxes: list, overlap: float = 0.3) -> list:
    """Boxes (left, top, right, bottom, score, keypoints) by score, overlaps dropped."""
    out = []
    for b in sorted(boxes, key=lambda b: -b[4]):
        if all(iou(b[:4], o[:4]) < overlap for o in out):
            out.append(b)
    return out


def apply_affine(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points (N, 2) through the 2x3 affine map ``m``."""
    return p @ m[:, :2].T + m[:, 2]


def blazeface_boxes(rgb8: np.ndarray) -> list:
    """BlazeFace (short- and full-range models) on the upright image, merged: a list of
    (left, top, right, bottom, score, keypoints (6, 2)) in pixels."""
    h, w = rgb8.shape[:2]
    boxes = []
    for model in (0, 1):
        res = _blazeface(model).process(rgb8)
        for d in res.detections or []:
            b = d.location_data.relative_bounding_box
            kp = np.array([[k.x * w, k.y * h] for k in d.location_data.relative_keypoints])
            boxes.append((b.xmin * w, b.ymin * h, (b.xmin + b.width) * w,
                          (b.ymin + b.height) * h, float(d.score[0]), kp))
    return _nms(boxes)


def _turn(rgb8: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The image turned k quarter turns counter-clockwise, and the 2x3 map from the
    turned image's pixel coordinates back to the original's."""
    h, w = rgb8.shape[:2]
    turned = np.ascontiguousarray(np.rot90(rgb8, k))
    # np.rot90 (counter-clockwise): turned (x', y') <- original (x, y)
    maps = {0: [[1, 0, 0], [0, 1, 0]], 1: [[0, -1, w], [1, 0, 0]],
            2: [[-1, 0, w], [0, -1, h]], 3: [[0, 1, 0], [-1, 0, h]]}
    return turned, np.array(maps[k % 4], float)


def mirrored_boxes(rgb8: np.ndarray) -> list:
    """BlazeFace (not mirror-symmetric) on the image mirrored, mapped back: keypoint 0 is
    still the subject's right eye (the eyes' and ears' keypoints swapped)."""
    w = rgb8.shape[1]
    return [(w - x1, y0, w - x0, y1, s, np.c_[w - kp[:, 0], kp[:, 1]][KP_MIRROR])
            for x0, y0, x1, y1, s, kp in blazeface_boxes(np.ascontiguousarray(rgb8[:, ::-1]))]


def equalized(rgb8: np.ndarray) -> np.ndarray:
    """The image, its luminance histogram equalised: for a low-contrast face."""
    import cv2

    ycc = cv2.cvtColor(rgb8, cv2.COLOR_RGB2YCrCb)
    ycc[..., 0] = cv2.equalizeHist(ycc[..., 0])
    return cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB)


def find_boxes(rgb8: np.ndarray) -> list:
    """Face boxes at any in-plane angle: the first of BlazeFace's passes that finds a face:
    upright, mirrored (:func:`mirrored_boxes`), both on the image :func:`equalized`, then
    turned by quarter turns (the order and the variants not taken: docs/vision.md). Boxes
    and keypoints in the image's pixels (a turned box: the bounds of its corners)."""
    found = blazeface_boxes(rgb8) or mirrored_boxes(rgb8)
    if not found:
        eq = equalized(rgb8)
        found = blazeface_boxes(eq) or mirrored_boxes(eq)
    if found:
        return found
    for k in (1, 3, 2):
        img, back = _turn(rgb8, k)
        found = blazeface_boxes(img)
        if not found:
            continue
        out = []
        for x0, y0, x1, y1, s, kp in found:
            c = apply_affine(back, np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))
            out.append((*c.min(0), *c.max(0), s, apply_affine(back, kp)))
        return out
    return []
