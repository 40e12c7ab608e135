"""Faces in photos, at any angle and on any background: detection with 68 (and 468 dense)
landmarks and visibility (:mod:`~hack_render.vision.detect`), person, face, skin and
occluder masks (:mod:`~hack_render.vision.segment`), and known-truth composites of the
model's renders over photographs for measuring them (:mod:`~hack_render.vision.synthetic`).
Used by the fitter (``hack_render.fit``) and the benchmark ``bench/bench_real_photos.py``;
docs/vision.md has the measured figures."""

from hack_render.vision.detect import FaceLandmarks, FaceWarning, detect_face, detect_faces

__all__ = ["FaceLandmarks", "FaceWarning", "detect_face", "detect_faces"]
