"""A face's 68 landmarks (iBUG / Multi-PIE order) as the detectors return them.

- :class:`Detection`: the fitter's and the tracker's currency: 68 points, the face box,
  the number of faces found, the detector's name, and what a refiner, a fallback or a
  second detector added (dlib's own points, per-point weights, visibility, the fused
  detector's points).
- :class:`FaceLandmarks`: a :class:`Detection` from the vision package's detectors
  (:func:`hack_render.vision.detect.detect_face`), with their score, visibility, dense
  points, roll and head pose.
- :class:`FaceWarning`: several faces were found (the largest is used).
- :data:`MIRROR_68`: each landmark's mirror image (left <-> right).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _mirror_68() -> np.ndarray:
    pairs = [(i, 16 - i) for i in range(17)] + [(17 + i, 26 - i) for i in range(5)] + \
        [(27, 27), (28, 28), (29, 29), (30, 30), (31, 35), (32, 34), (33, 33)] + \
        [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)] + \
        [(48, 54), (49, 53), (50, 52), (51, 51), (55, 59), (56, 58), (57, 57)] + \
        [(60, 64), (61, 63), (62, 62), (65, 67), (66, 66)]
    m = np.arange(68)
    for a, b in pairs:
        m[a], m[b] = b, a
    return m


#: the Multi-PIE index of each landmark's mirror image (left <-> right)
MIRROR_68 = _mirror_68()


class FaceWarning(UserWarning):
    """Several faces were found (the largest is used)."""


@dataclass
class Detection:
    """Landmarks (68, 2) in pixels (continuous, pixel centres at +0.5), the face box
    (left, top, right, bottom) and the number of faces found. A refined detection
    (:func:`hack_render.fit.landmarks.refine_detection`) keeps the detector's own points
    in ``raw`` and carries the refiner's per-point loss weights in ``weights``."""

    points: np.ndarray
    box: tuple[float, float, float, float]
    n_faces: int
    source: str = "dlib"
    raw: np.ndarray | None = None
    weights: np.ndarray | None = None
    # (68,) bool: False where the detector says the point is hidden (the far side of a
    # profile; the face mesh's fallback detections); None: all seen
    visible: np.ndarray | None = None
    # (68, 2) the vision package's points whose inner ones were averaged into ``points``
    # (landmarks.detector "both", :func:`hack_render.vision.landmarks68.fuse_detection`);
    # None: not fused
    fused: np.ndarray | None = None

    @property
    def refined(self) -> bool:
        return self.raw is not None

    @property
    def size(self) -> float:
        """Face size in pixels: the landmarks' bounding-box diagonal / sqrt(2)."""
        span = self.points.max(0) - self.points.min(0)
        return float(np.linalg.norm(span) / np.sqrt(2.0))

    @property
    def side(self) -> float:
        """The face's size for the minimum face: its box's side (the geometric mean of
        width and height), or :attr:`size` where the landmarks span more (a turned face's
        points span less than its face: a profile has half of them on the far side)."""
        x0, y0, x1, y1 = self.box
        return max(self.size, float(np.sqrt(max(x1 - x0, 0.0) * max(y1 - y0, 0.0))))

    @property
    def interocular(self) -> float:
        """Distance between the outer eye corners (landmarks 36 and 45), pixels."""
        return float(np.linalg.norm(self.points[36] - self.points[45]))


@dataclass
class FaceLandmarks(Detection):
    """One detected face.

    points: (68, 2) Multi-PIE landmarks in pixels (continuous, pixel centres at +0.5).
    box: (left, top, right, bottom) pixels. n_faces: faces found in the image. source:
    the detector ("mesh", "dlib_hog", "dlib_cnn"). score: the detector's confidence in
    [0, 1] (mesh: face presence x box score; dlib HOG: the SVM margin squashed by a
    logistic). visible: (68,) bool, False where the point is hidden (self-occluded; the
    far side of a profile); all True for dlib, which does not say. dense: (468, 3) the
    mesh model's points (x, y pixels; z in pixels, smaller nearer the camera) or None.
    roll_deg: the in-plane angle of the face (eyes' line, degrees counter-clockwise).
    convention: "3d" (every point a fixed surface point, hidden ones where they
    project) or "2d" (dlib: the jawline on the visible outline). pose: (yaw, pitch,
    roll) degrees of the camera about the head, from the points
    (:func:`hack_render.vision.pose.fit_pose`; 3-D convention only). ``raw`` and
    ``weights`` as :class:`Detection`'s (None here), whose fields, ``size`` and
    ``interocular`` it extends, so it goes wherever a ``Detection`` does.
    """

    score: float = 1.0
    dense: np.ndarray | None = None
    roll_deg: float = 0.0
    convention: str = "2d"
    pose: tuple[float, float, float] | None = None

    def __post_init__(self):
        if self.visible is None:
            self.visible = np.ones(len(self.points), bool)
