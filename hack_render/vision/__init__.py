"""Faces in photos, at any angle and on any background: detection with 68 (and 468 dense)
landmarks and visibility (:mod:`~hack_render.vision.detect`; face boxes
:mod:`~hack_render.vision.boxes`; dlib's models :mod:`~hack_render.vision.dlib_models`),
the fitter's and the tracker's :class:`~hack_render.vision.detection.Detection`
(:mod:`~hack_render.vision.landmarks68`), and person, face, skin and occluder masks
(:mod:`~hack_render.vision.segment`). Used by the fitter (``hack_render.fit``), the
tracker, the scan registration and the benchmark ``bench/bench_real_photos.py``, measured
on known-truth composites of the model's renders over photographs
(:mod:`hack_render.dataset.composites`); docs/vision.md has the measured figures."""

from hack_render.vision.detect import detect_face, detect_faces
from hack_render.vision.detection import Detection, FaceLandmarks, FaceWarning

__all__ = ["Detection", "FaceLandmarks", "FaceWarning", "detect_face", "detect_faces"]
