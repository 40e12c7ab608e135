"""Per-frame 68-point landmarks for the tracker: dlib's detector searched around the last
face (the whole frame when the face was lost), its 68-point predictor, the fit's landmark
refiner, and a plausibility check against the last good frame. Frames without a usable
face are marked lost (their points NaN), never dropped."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.fit.landmark_refiner import load_refiner
from hack_render.io import atomic_path
from hack_render.vision import detect as vision_detect
from hack_render.vision import dlib_models


@dataclass
class FrameLandmarks:
    """A clip's landmarks: ``points`` (T, 68, 2) pixels (NaN where lost), ``found`` (T,)
    bool, ``boxes`` (T, 4) left, top, right, bottom (NaN where lost), ``why`` (T,) the
    reason a frame was lost ('' where found), ``weights`` (68,) the refiner's per-point
    weights (ones without a refiner), and ``raw`` (T, 68, 2) dlib's own points."""

    points: np.ndarray
    found: np.ndarray
    boxes: np.ndarray
    why: list[str]
    weights: np.ndarray
    raw: np.ndarray
    mask: np.ndarray | None = None     # (T, 68) per-frame point weights (None: all 1)
    source: list[str] | None = None    # (T,) "dlib", "mesh" (the fallback) or "" (lost)

    def __post_init__(self):
        if self.mask is None:
            self.mask = np.ones(self.points.shape[:2])
        if self.source is None:
            self.source = ["dlib" if f else "" for f in self.found]

    def save(self, path) -> None:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, points=self.points, found=self.found, boxes=self.boxes,
                     why=np.array(self.why, dtype=str), weights=self.weights, raw=self.raw,
                     mask=self.mask, source=np.array(self.source, dtype=str))

    @classmethod
    def load(cls, path) -> FrameLandmarks:
        with np.load(path, allow_pickle=False) as z:
            return cls(z["points"], z["found"], z["boxes"], [str(s) for s in z["why"]],
                       z["weights"], z["raw"], z.get("mask", None),
                       [str(s) for s in z["source"]] if "source" in z else None)


class FrameDetector:
    """Landmarks frame after frame. ``min_face_px``: smaller faces count as lost;
    ``refiner``: the fit's landmark refiner ("dlib": the shipped one, "off", or a file);
    ``max_jump``: a frame whose landmarks moved more than this fraction of the face's size
    from the last good frame (beyond the motion since) is lost as an outlier."""

    def __init__(self, min_face_px: int = 48, refiner: str = "dlib", max_jump: float = 0.5,
                 fallback: bool = True):
        self.detector = dlib_models.frontal_detector()
        self.predictor = dlib_models.shape_predictor()
        self.min_face_px, self.max_jump = min_face_px, max_jump
        self.refiner = None
        if refiner != "off":
            self.refiner = load_refiner(refiner)
        # where dlib finds no face: the vision package's face mesh (its 68 points are fixed
        # surface points, so its jawline is not dlib's outline: the solve skips it)
        self.fallback = fallback
        self.last_box: np.ndarray | None = None
        self.last_points: np.ndarray | None = None
        self.lost_run = 0

    def _run(self, img: np.ndarray, upsample: int, dx: int = 0, dy: int = 0) -> list:
        rects, scores, _ = self.detector.run(img, upsample, 0.0)
        return [(rc.left() + dx, rc.top() + dy, rc.right() + dx, rc.bottom() + dy, float(sc))
                for rc, sc in zip(rects, scores)]

    def _rects(self, img: np.ndarray) -> list:
        """Face rectangles with the detector's scores (left, top, right, bottom, score),
        near the last face first (a crop of twice its size), the whole frame when that
        finds none or there is no last face."""
        h, w = img.shape[:2]
        if self.last_box is not None and self.lost_run < 5:
            l, t, r, b = self.last_box
            s = max(r - l, b - t)
            cx, cy = (l + r) / 2, (t + b) / 2
            x0, y0 = int(max(0, cx - s)), int(max(0, cy - s))
            x1, y1 = int(min(w, cx + s)), int(min(h, cy + s))
            crop = np.ascontiguousarray(img[y0:y1, x0:x1])
            rects = self._run(crop, 1 if s < 90 else 0, x0, y0)
            if rects:
                return rects
        return self._run(img, 0) or self._run(img, 1)

    def _mesh(self, img: np.ndarray):
        """(points, visible (68,), box) of the face mesh's face nearest the last one, or
        None (no face, or the vision package's models are not installed)."""
        try:
            faces = vision_detect.detect_faces(img, "mesh")
        except (ImportError, HackError, OSError, RuntimeError):
            return None
        faces = [f for f in faces if f.size >= self.min_face_px]
        if not faces:
            return None
        if self.last_box is not None:
            c = np.array([(self.last_box[0] + self.last_box[2]) / 2,
                          (self.last_box[1] + self.last_box[3]) / 2])
            faces.sort(key=lambda f: np.hypot(*(f.points.mean(0) - c)))
        f = faces[0]
        vis = np.ones(68, bool) if f.visible is None else np.asarray(f.visible, bool)
        return np.asarray(f.points, np.float64), vis, np.asarray(f.box, np.float64)

    def detect(self, rgb8: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None,
                                                np.ndarray | None, str, np.ndarray | None]:
        """As calling the detector, with the face mesh where dlib finds no usable face:
        (points, raw, box, why, mask (68,); None for dlib's points)."""
        pts, raw, box, why = self(rgb8)
        if pts is not None or not self.fallback:
            return pts, raw, box, why, None
        got = self._mesh(np.ascontiguousarray(rgb8[..., :3], dtype=np.uint8))
        if got is None:
            return None, None, None, why, None
        pts, vis, box = got
        if self.last_points is not None and self._jumped(pts, self.lost_run):
            return None, None, None, "face mesh's landmarks jumped (outlier)", None
        mask = vis.astype(np.float64)
        mask[:17] = 0.0  # the mesh's jawline is not dlib's outline
        self.last_box, self.last_points, self.lost_run = box, pts, 0
        return pts, pts, box, "", mask

    def _jumped(self, pts: np.ndarray, frames: int) -> bool:
        """Whether landmarks found ``frames`` frames after the last good ones are an
        outlier: their inner points' shape (about their own centre) moved more than
        ``max_jump`` of the face's size, or their centre more than ``max_jump`` of it per
        frame (the face mesh can take an ear, or the back of a turned head, for a face)."""
        last = self.last_points
        size = np.linalg.norm(np.ptp(last, 0)) / np.sqrt(2)
        a, b = pts[17:], last[17:]
        shape = np.median(np.linalg.norm((a - a.mean(0)) - (b - b.mean(0)), axis=1))
        centre = np.linalg.norm(a.mean(0) - b.mean(0))
        return bool(shape > self.max_jump * size
                    or centre > self.max_jump * size * max(1, frames))

    def __call__(self, rgb8: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None,
                                                 np.ndarray | None, str]:
        """(points (68, 2), dlib's raw points, box, '') or (None, None, None, why)."""
        import dlib

        img = np.ascontiguousarray(rgb8[..., :3], dtype=np.uint8)
        rects = self._rects(img)
        if not rects:
            self.lost_run += 1
            return None, None, None, "no face found"
        if self.last_box is not None and self.lost_run < 5:  # the face nearest the last one
            c = np.array([(self.last_box[0] + self.last_box[2]) / 2,
                          (self.last_box[1] + self.last_box[3]) / 2])
            rects.sort(key=lambda r: np.hypot((r[0] + r[2]) / 2 - c[0], (r[1] + r[3]) / 2 - c[1]))
        else:  # the detector's most confident face (the largest can be a false one)
            rects.sort(key=lambda r: r[4], reverse=True)
        l, t, r, b, _ = rects[0]
        if max(r - l, b - t) < self.min_face_px:
            self.lost_run += 1
            return None, None, None, f"face smaller than {self.min_face_px} px"
        shape = self.predictor(img, dlib.rectangle(int(l), int(t), int(r), int(b)))
        raw = np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], dtype=np.float64)
        pts = self.refiner.refine(img, raw) if self.refiner is not None else raw
        box = np.array([l, t, r, b], dtype=np.float64)
        # a jump of the landmarks' shape is a bad fit of the predictor, not motion; a jump
        # of their centre is another thing taken for the face (an ear, on a turned head)
        if self.last_points is not None and self.lost_run < 5 \
                and self._jumped(pts, self.lost_run + 1):
            self.lost_run += 1
            return None, None, None, "landmarks jumped (outlier)"
        self.last_box, self.last_points, self.lost_run = box, pts, 0
        return pts, raw, box, ""


def detect_frames(frames, detector: FrameDetector | None = None, progress: bool = True,
                  total: int | None = None, on_frame=None) -> FrameLandmarks:
    """Landmarks of every frame of an iterable of (H, W, 3) uint8 images. ``on_frame``:
    called as ``on_frame(i, img, points, found)`` as each frame's landmarks are final
    (points (68, 2), NaN where no face was found)."""
    det = detector or FrameDetector()
    pts, raws, boxes, why, masks, source = [], [], [], [], [], []
    for i, img in enumerate(tqdm(frames, total=total, desc="landmarks", unit="frame",
                                 disable=not progress, leave=False)):
        p, raw, box, reason, mask = det.detect(img)
        if on_frame is not None:
            on_frame(i, img, np.full((68, 2), np.nan) if p is None else p, reason == "")
        nan = np.full((68, 2), np.nan)
        pts.append(nan if p is None else p)
        raws.append(nan if raw is None else raw)
        boxes.append(np.full(4, np.nan) if box is None else box)
        why.append(reason)
        masks.append(np.ones(68) if mask is None else mask)
        source.append("" if p is None else ("dlib" if mask is None else "mesh"))
    if not pts:
        raise HackError("track: the video has no frames.")
    found = np.array([w == "" for w in why])
    weights = (np.asarray(det.refiner.weights, dtype=np.float64)
               if det.refiner is not None and det.refiner.weights is not None else np.ones(68))
    return FrameLandmarks(np.stack(pts), found, np.stack(boxes), why, weights, np.stack(raws),
                          np.stack(masks), source)
