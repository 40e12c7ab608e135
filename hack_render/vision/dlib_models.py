"""dlib's face detectors and 68-point shape predictor, each loaded once.

The ``fit`` extra (``dlib-bin`` + ``face-recognition-models``, fully offline): dlib's
frontal HOG detector (:func:`frontal_detector`), its MMOD CNN detector
(:func:`cnn_detector`) and its 68-point shape predictor (:func:`shape_predictor`, iBUG /
Multi-PIE order). Every dlib user of the package (the fitter's detection,
:mod:`hack_render.vision.landmarks68`; the vision package's ``dlib_hog`` / ``dlib_cnn``
methods; the tracker; the scan registration) takes them from here, so each model is
read from disk once per process.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from hack_render.errors import HackError

#: the model files in face-recognition-models' ``models`` folder
FILES = {"shape": "shape_predictor_68_face_landmarks.dat",
         "cnn": "mmod_human_face_detector.dat"}
_NEEDS = ("pip install 'hack-render[fit]', i.e. dlib-bin and face-recognition-models")

_CACHE: dict = {}


def models_dir() -> Path:
    """face-recognition-models' ``models`` folder, found without importing the package
    (its __init__ needs pkg_resources, which current setuptools no longer has)."""
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise HackError(f"face detection: expected face-recognition-models ({_NEEDS}), "
                        "found it missing.")
    return Path(next(iter(spec.submodule_search_locations))) / "models"


def model_file(name: str) -> Path:
    """The file of dlib model ``name`` ("shape" or "cnn", :data:`FILES`)."""
    path = models_dir() / FILES[name]
    if not path.is_file():
        raise HackError(f"face detection: expected dlib's model {path} (face-recognition-"
                        f"models ships it), found it missing. {_NEEDS}.")
    return path


def _load(name: str):
    if name not in _CACHE:
        try:
            import dlib
        except ImportError as err:
            raise HackError(f"face detection: expected dlib ({_NEEDS}), found it missing "
                            f"({err}).") from err
        if name == "hog":
            _CACHE[name] = dlib.get_frontal_face_detector()
        elif name == "cnn":
            _CACHE[name] = dlib.cnn_face_detection_model_v1(str(model_file("cnn")))
        else:
            _CACHE[name] = dlib.shape_predictor(str(model_file("shape")))
    return _CACHE[name]


def frontal_detector():
    """dlib's frontal face detector (HOG + linear SVM)."""
    return _load("hog")


def cnn_detector():
    """dlib's MMOD CNN face detector (any pose up to profiles, slower)."""
    return _load("cnn")


def shape_predictor():
    """dlib's 68-point shape predictor (iBUG 300-W)."""
    return _load("shape")
