"""The any-angle 68-point shape predictor: dlib's regression trees, one per range of yaw.

A single ensemble of regression trees starts every face from one mean shape; over yaw
+-90 degrees the shapes differ too much for its cascade (a profile's points are half on
the far side), and one predictor trained on all angles returned a scramble of frontal
and profile points (19-27 % of the box at every yaw, docs/vision.md). So the face is
first normalised, then handed to a predictor trained on its own range of yaw:

1. **Upright crop**: BlazeFace's six keypoints (eyes, nose tip, mouth, ear tragions) give
   the face's up direction (the mouth to the eyes' midpoint); the square of side
   ``CROP_SCALE`` x the box's around the box's centre is turned upright and resampled to
   ``CROP_PX`` pixels, the box becoming the crop's central square.
2. **Yaw from the keypoints**: a ridge regression (linear and quadratic terms of the
   keypoints in the crop's frame) fitted on the training composites; 7.9 degrees median
   error, the sign right in 99 % of the faces turned more than 20 degrees (the 330 faces
   BlazeFace boxes in the held-out benchmark sets 9015-9019, docs/vision.md).
3. **Mirror**: a face turned to the other side (negative yaw) is mirrored, so the
   predictors only learn one side; the points come back mirrored and relabelled.
4. **Range**: the predictor of the yaw range holding the estimate (``YAW_BINS``; each
   trained on its range widened by ``BIN_MARGIN`` degrees).

Without keypoints (a box from dlib's CNN detector) the crop is not turned, and the yaw
is the head pose fitted to the frontal predictor's points (:mod:`hack_render.vision.pose`).

Derived data: the predictors and the regression (``hack_render/data/face_ert_68_*.dat``,
``face_ert_yaw.npz``) are trained on the model's renders composited over photographs by
:mod:`hack_render.learn.face_ert`; not on annotated photos.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.vision import boxes, pose
from hack_render.vision.boxes import KP_MIRROR
from hack_render.vision.detection import MIRROR_68

DATA = Path(__file__).resolve().parents[1] / "data"
#: |yaw| ranges (degrees) of the predictors, chosen by the estimated yaw
YAW_BINS = ((0.0, 30.0), (30.0, 60.0), (60.0, 90.0))
#: each predictor is trained on its range widened by this many degrees each side
BIN_MARGIN = 12.0
CROP_PX = 160               # the upright crop's side, pixels
CROP_SCALE = 2.0            # the crop's side in box sides
YAW_FILE = DATA / "face_ert_yaw.npz"
#: BlazeFace keypoint ids
KP_EYES, KP_MOUTH = (0, 1), 3

_CACHE: dict = {}


def bin_file(i: int) -> Path:
    lo, hi = YAW_BINS[i]
    return DATA / f"face_ert_68_yaw{int(lo)}-{int(hi)}.dat"


def mirror_ids() -> np.ndarray:
    return MIRROR_68


def upright_map(box, kps) -> np.ndarray:
    """2x3 map from image pixels to the upright crop's pixels (the box's centre at the
    crop's centre, the face's up direction up, the box's side CROP_PX / CROP_SCALE)."""
    x0, y0, x1, y1 = box
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    side = math.sqrt(max(x1 - x0, 1.0) * max(y1 - y0, 1.0))
    angle = 0.0
    if kps is not None:
        up = np.mean(kps[list(KP_EYES)], axis=0) - kps[KP_MOUTH]
        if np.linalg.norm(up) > 1e-6:
            # rotate so that ``up`` points to -y (the crop's up)
            angle = math.atan2(up[0], -up[1])
    k = CROP_PX / (CROP_SCALE * side)
    c, s = math.cos(-angle), math.sin(-angle)
    m = np.array([[k * c, -k * s, 0.0], [k * s, k * c, 0.0]])
    m[:, 2] = CROP_PX / 2 - m[:, :2] @ centre
    return m


def apply(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.asarray(p, float) @ m[:, :2].T + m[:, 2]


def crop(rgb8: np.ndarray, m: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.warpAffine(rgb8, m, (CROP_PX, CROP_PX), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def crop_box() -> tuple[int, int, int, int]:
    """The box's place in the crop (left, top, right, bottom)."""
    h = CROP_PX / CROP_SCALE / 2
    c = CROP_PX / 2
    return (round(c - h), round(c - h), round(c + h), round(c + h))


def yaw_features(kps_crop: np.ndarray) -> np.ndarray:
    """(N, 6, 2) keypoints in crop pixels -> (N, 25) features (linear, quadratic, 1)."""
    f = (np.asarray(kps_crop, float).reshape(len(kps_crop), -1) - CROP_PX / 2) / CROP_PX
    return np.hstack([f, f ** 2, np.ones((len(f), 1))])


def mirror_kps(kps_crop: np.ndarray) -> np.ndarray:
    """(N, 6, 2) keypoints of the mirrored crops."""
    m = np.array(kps_crop, float)[:, KP_MIRROR]
    m[..., 0] = CROP_PX - m[..., 0]
    return m


def fit_yaw_regression(kps_crop: np.ndarray, yaw: np.ndarray, ridge: float = 1e-3):
    """Ridge regression of yaw on :func:`yaw_features`, fitted on the faces and their
    mirror images (yaw negated), so a face and its mirror get opposite yaws."""
    kps = np.concatenate([kps_crop, mirror_kps(kps_crop)])
    y = np.concatenate([np.asarray(yaw, float), -np.asarray(yaw, float)])
    F = yaw_features(kps)
    return np.linalg.solve(F.T @ F + ridge * np.eye(F.shape[1]), F.T @ y)


def estimate_yaw(kps_crop: np.ndarray) -> float:
    """Yaw (degrees, the composites' convention: > 0 the camera on the subject's left)
    from BlazeFace's keypoints in the upright crop."""
    if "yaw" not in _CACHE:
        if not YAW_FILE.is_file():
            raise HackError(f"face landmarks: expected {YAW_FILE} (shipped with hack-render; "
                            "rebuild: python -m hack_render.learn.face_ert train)")
        with np.load(YAW_FILE) as z:
            _CACHE["yaw"] = z["weights"]
    return float(yaw_features(kps_crop[None])[0] @ _CACHE["yaw"])


def choose_bin(abs_yaw: float) -> int:
    for i, (_, hi) in enumerate(YAW_BINS):
        if abs_yaw < hi:
            return i
    return len(YAW_BINS) - 1


def training_bins(abs_yaw: float) -> list[int]:
    """The predictors a training face at this |yaw| (estimated) goes to."""
    return [i for i, (lo, hi) in enumerate(YAW_BINS)
            if lo - BIN_MARGIN <= abs_yaw <= hi + BIN_MARGIN
            or (i == len(YAW_BINS) - 1 and abs_yaw > hi)]


def predictor(i: int):
    if i not in _CACHE:
        import dlib

        f = bin_file(i)
        if not f.is_file():
            raise HackError(f"face landmarks: expected {f} (shipped with hack-render; "
                            "rebuild: python -m hack_render.learn.face_ert), found it missing.")
        _CACHE[i] = dlib.shape_predictor(str(f))
    return _CACHE[i]


def _predict(img: np.ndarray, i: int, flip: bool) -> np.ndarray:
    """The bin's predictor on an upright crop (mirrored first where ``flip``): (68, 2)
    points in the crop's pixels (pixel centres at +0.5)."""
    import dlib

    im = np.ascontiguousarray(img[:, ::-1]) if flip else img
    shape = predictor(i)(im, dlib.rectangle(*crop_box()))
    p = np.array([[q.x + 0.5, q.y + 0.5] for q in shape.parts()], float)
    if flip:
        p[:, 0] = CROP_PX - p[:, 0]
        p = p[mirror_ids()]
    return p


def _upside_down_keypoints(img: np.ndarray, m: np.ndarray, margin: float = 0.05,
                           sure: float = 0.85):
    """BlazeFace finds an upside-down face in an upright image, its keypoints upside down
    with it (the eyes where the mouth is). BlazeFace on the crop and on the crop turned
    by 180 degrees: where the turned one scores at least ``sure`` and higher by
    ``margin``, its keypoints (image pixels), else None. (Faces seen from 45 degrees
    above or below also score higher turned, at 0.54-0.81 on the benchmark's composites,
    the upside-down ones at 0.77-0.92: the two thresholds were set on those composites.)"""
    def best(im):
        found = boxes.blazeface_boxes(np.ascontiguousarray(im))
        return max(found, key=lambda b: b[4], default=None)

    up, down = best(img), best(img[::-1, ::-1])
    if down is None or down[4] < sure or (up is not None and down[4] <= up[4] + margin):
        return None
    kps_crop = (CROP_PX - down[5])              # back from the turned crop
    return apply(_invert(m), kps_crop)


def _invert(m: np.ndarray) -> np.ndarray:
    a = np.linalg.inv(m[:, :2])
    return np.c_[a, -a @ m[:, 2]]


def upright_keypoints(rgb8: np.ndarray, box, kps) -> np.ndarray:
    """BlazeFace's keypoints of the face in ``box``, turned the right way up where they
    came upside down (:func:`_upside_down_keypoints`)."""
    m = upright_map(box, kps)
    turned = _upside_down_keypoints(crop(rgb8, m), m)
    return kps if turned is None else turned


def landmarks(rgb8: np.ndarray, box, kps=None,
              check_upside_down: bool = True) -> tuple[np.ndarray, float]:
    """68 points (image pixels) of the face in ``box`` and the yaw that chose the
    predictor (degrees). ``check_upside_down``: first :func:`upright_keypoints` (off
    where the caller did it)."""
    if kps is not None and check_upside_down:
        kps = upright_keypoints(rgb8, box, kps)
    m = upright_map(box, kps)
    img = crop(rgb8, m)
    if kps is not None:
        yaw = estimate_yaw(apply(m, kps))
    else:
        yaw = pose.fit_pose(_predict(img, 0, False)).angles()[0]
    p = _predict(img, choose_bin(abs(yaw)), yaw < 0)
    return apply(_invert(m), p), yaw
