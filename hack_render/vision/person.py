"""The person in a photo: MediaPipe's selfie segmentation (the landscape model, shipped in
the ``mediapipe`` wheel; it measured better than the general one on the composites,
docs/vision.md), offline. Its probability is what :mod:`hack_render.vision.verify`
checks face boxes against and what :mod:`hack_render.vision.segment` builds the person
mask from."""

from __future__ import annotations

import os
import warnings

import numpy as np

_CACHE: dict = {}


def _selfie():
    if "selfie" not in _CACHE:
        os.environ.setdefault("GLOG_minloglevel", "2")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mediapipe as mp

            _CACHE["selfie"] = mp.solutions.selfie_segmentation.SelfieSegmentation(
                model_selection=1)
    return _CACHE["selfie"]


def person_probability(rgb8: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    """(H, W) float32: MediaPipe selfie segmentation's person probability, run on the
    image turned by the quarter turn nearest ``roll_deg`` (the face's in-plane angle)
    so the person stands upright (on Grace Hopper turned by a quarter, half and
    three-quarter turn the model's mask had IoU 0.80 / 0.44 / 0.38 with the upright
    photo's), turned back."""
    k = -round(roll_deg / 90.0) % 4
    res = _selfie().process(np.ascontiguousarray(np.rot90(rgb8, k)))
    return np.ascontiguousarray(np.rot90(np.asarray(res.segmentation_mask, np.float32), -k))
