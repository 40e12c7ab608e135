"""The fitter's 68 facial landmarks (iBUG / Multi-PIE order): its detection, landmark
files, jaw contours.

- :func:`detect`: the detectors of the vision package
  (:mod:`hack_render.vision.landmarks68`: dlib's, the vision package's in its place, or
  both averaged) as the fit config's ``landmarks`` section chooses, dlib's points moved
  by the landmark refiner (:func:`refine_detection`). The detection itself
  (:class:`~hack_render.vision.detection.Detection`, dlib's models) is the vision
  package's.
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
from pathlib import Path

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.fit.config import LandmarkConfig
from hack_render.fit.landmark_refiner import load_refiner
from hack_render.vision.detection import Detection
from hack_render.vision.landmarks68 import detect_landmarks, fuse_detection, mesh_detection

#: ICT jawline substitutes (DATA.md): landmarks 0-7 (right) and 9-16 (left).
JAW_SUBSTITUTES = {0: 1278, 1: 1272, 2: 12, 3: 1834, 4: 243, 5: 781, 6: 2199, 7: 1447,
                   9: 3661, 10: 4390, 11: 3022, 12: 2484, 13: 4036, 14: 2253, 15: 3490,
                   16: 3496}
JAW = tuple(range(17))
#: Landmark groups for weights and overlays.
GROUPS = {"jaw": range(17), "brows": range(17, 27), "nose": range(27, 36),
          "eyes": range(36, 48), "mouth": range(48, 68)}


def refine_detection(rgb8: np.ndarray, det: Detection, refiner: str = "dlib") -> Detection:
    """dlib's detection with its inner points moved by the landmark refiner named by
    ``landmarks.refiner`` ("dlib": the shipped one, "off", or a file;
    :mod:`hack_render.fit.landmark_refiner`). Other sources are returned as they are."""
    ref = load_refiner(refiner) if det.source == "dlib" and not det.refined else None
    if ref is None:
        return det
    return Detection(ref.refine(rgb8, det.points), det.box, det.n_faces, det.source,
                     raw=np.array(det.points, copy=True), weights=ref.weights)


def detect(rgb8: np.ndarray, config=None, name: str = "photo") -> Detection:
    """:func:`~hack_render.vision.landmarks68.detect_landmarks` and
    :func:`refine_detection` with a fit config's ``landmarks`` section (defaults when
    None): ``detector`` "auto" the vision package's face alone
    (:func:`~hack_render.vision.landmarks68.mesh_detection`), "both" dlib's averaged
    with it (:func:`~hack_render.vision.landmarks68.fuse_detection`); ``fallback`` the
    vision package's face where dlib finds none."""
    if config is None:
        config = LandmarkConfig()
    if config.detector == "auto":
        return mesh_detection(rgb8, config.min_face_px, name, None, "auto")
    try:
        det = detect_landmarks(rgb8, min_face_px=config.min_face_px, name=name)
    except HackError as err:
        if config.fallback == "off" or "no face found" not in str(err):
            raise
        return mesh_detection(rgb8, config.min_face_px, name, err, config.fallback)
    det = refine_detection(rgb8, det, config.refiner)
    return fuse_detection(rgb8, det, name) if config.detector == "both" else det


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
