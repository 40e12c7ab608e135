"""MediaPipe's face mesh on a photo: its 478 points with the irises (``refine_landmarks``),
its contours as closed loops of point ids, and the person's eye and mouth openings they
enclose. The eyes' colours (``iris.py``), the eyes' and the mouth's stages (``eyes.py``,
``mouth.py``), the parts' bake (``final.py``) and the real-photo benchmark's scored regions
read the photo's face through it; the models are in the mediapipe wheel.
"""

from __future__ import annotations

import warnings
from collections import defaultdict

import numpy as np

#: The face mesh with iris landmarks is run on the detection's box grown by this much of
#: its size on each side (a small face in a large photo is found there).
EYE_CROP_GROW = 0.6
_MESH: dict = {}


def _face_mesh():
    """MediaPipe's face mesh with its iris landmarks (``refine_landmarks``: 478 points,
    468-472 and 473-477 the irises' centres and four rim points each; the models are in
    the mediapipe wheel)."""
    if "mesh" not in _MESH:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mediapipe as mp

            _MESH["mesh"] = mp.solutions.face_mesh.FaceMesh(
                static_image_mode=True, refine_landmarks=True, max_num_faces=4,
                min_detection_confidence=0.3)
    return _MESH["mesh"]


def iris_landmarks(rgb8: np.ndarray, points: np.ndarray | None = None) -> np.ndarray | None:
    """(478, 2) the face mesh's points with the irises' (pixels, centres at +0.5), of the
    face nearest ``points`` (e.g. the fit's 68 detected points; the mesh runs on their box
    grown by :data:`EYE_CROP_GROW`), or None where it finds no face or mediapipe is
    missing."""
    h, w = rgb8.shape[:2]
    x0, y0, crop = 0, 0, rgb8
    if points is not None:
        lo, hi = np.asarray(points).min(0), np.asarray(points).max(0)
        g = EYE_CROP_GROW * float((hi - lo).max())
        x0, y0 = int(max(0, lo[0] - g)), int(max(0, lo[1] - g))
        x1, y1 = int(min(w, hi[0] + g + 1)), int(min(h, hi[1] + g + 1))
        crop = np.ascontiguousarray(rgb8[y0:y1, x0:x1])
    try:
        res = _face_mesh().process(crop)
    except (ImportError, OSError, RuntimeError):
        return None
    if not res.multi_face_landmarks:
        return None
    ch, cw = crop.shape[:2]
    faces = [np.array([(lm.x * cw + x0, lm.y * ch + y0) for lm in f.landmark])
             for f in res.multi_face_landmarks]
    faces = [f for f in faces if len(f) >= 478]
    if not faces:
        return None
    ref = np.asarray(points).mean(0) if points is not None else np.array([w / 2, h / 2])
    return min(faces, key=lambda f: float(np.linalg.norm(f[:468].mean(0) - ref)))


def mesh_loops(name: str) -> list:
    """A face-mesh connection set (MediaPipe's ``FACEMESH_*``) as its closed loops of
    point ids, longest first: the sets are undirected edges (an eye's is two lids' polylines
    from corner to corner; the lips' two such loops, outer and inner)."""
    from mediapipe.python.solutions import face_mesh_connections as fmc

    adj = defaultdict(set)
    for a, b in getattr(fmc, name):
        adj[a].add(b)
        adj[b].add(a)
    loops, seen = [], set()
    for start in sorted(adj):
        if start in seen:
            continue
        loop, prev, p = [start], None, start
        seen.add(start)
        while True:
            nxt = [q for q in sorted(adj[p]) if q != prev and (q not in seen or q == start)]
            if not nxt or nxt[0] == start:
                break
            prev, p = p, nxt[0]
            seen.add(p)
            loop.append(p)
        loops.append(loop)
    return sorted(loops, key=len, reverse=True)


def mesh_at(rgb8: np.ndarray, points, shape) -> tuple[np.ndarray, int, int] | None:
    """The face mesh's points with irises (:func:`iris_landmarks`) scaled to ``shape`` (H, W;
    default the photo's), and that size: (points, H, W), or None where no face is found."""
    pts = iris_landmarks(rgb8, points)
    if pts is None:
        return None
    h, w = shape or rgb8.shape[:2]
    return pts * [w / rgb8.shape[1], h / rgb8.shape[0]], h, w


def opening_masks(pts: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(eyes, mouth), (h, w) bool each, of the face mesh's points ``pts`` (pixels of an
    h x w image): inside its two lid contours (FACEMESH_LEFT_EYE / RIGHT_EYE), and inside
    its inner lip contour (the smaller of FACEMESH_LIPS' two loops)."""
    from skimage.draw import polygon

    eyes, mouth = np.zeros((h, w), bool), np.zeros((h, w), bool)
    loops = [(eyes, pts[mesh_loops(n)[0]]) for n in ("FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE")]
    loops.append((mouth, min((pts[q] for q in mesh_loops("FACEMESH_LIPS")), key=loop_area)))
    for out, loop in loops:
        rr, cc = polygon(loop[:, 1] - 0.5, loop[:, 0] - 0.5, (h, w))
        out[rr, cc] = True
    return eyes, mouth


def loop_area(loop: np.ndarray) -> float:
    """The area a closed polygon (n, 2) encloses (the shoelace formula)."""
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def views_mesh(state, read=None) -> list:
    """Per view ``read(photo rgb8, the face mesh's 478 points, the photo is grey)``
    (default: the points themselves), or None where the face mesh finds no face near the
    view's detected points (:func:`iris_landmarks`)."""
    out = []
    for v in state.views:
        pts = view_mesh(v)
        out.append(None if pts is None else pts if read is None
                   else read(v.photo.uint8(), pts, v.photo.is_grey))
    return out


def view_mesh(v) -> np.ndarray | None:
    """A view's :func:`iris_landmarks` near its detected points, found once per view
    (kept in ``v.mesh478`` with those points: the mouth's and the final stages both read
    them; ~0.2 s a run on 2 cores) and again only if the points change. A copy."""
    key = np.asarray(v.detection.points, np.float64).tobytes()
    cached = getattr(v, "mesh478", None)
    if cached is None or cached[0] != key:
        cached = (key, iris_landmarks(v.photo.uint8(), v.detection.points))
        v.mesh478 = cached
    return None if cached[1] is None else cached[1].copy()


def views_openings(state) -> list:
    """Per view the person's (eyes, mouth) openings in its photo (:func:`opening_masks`, at
    the photo's size; one face mesh for both), or None where the face mesh finds no face."""
    return views_mesh(state, lambda img, pts, _grey: opening_masks(pts, *img.shape[:2]))
