"""3-D landmarks of a mesh scan in any orientation, found without the user's help.

1. Search: render the scan (its colours if it has any, else shaded) from 26 directions
   around it (the faces, edges and corners of a cube, at most 27 degrees from any
   direction), each image also turned in steps of 45 degrees (dlib's frontal detector
   takes faces to about 25 degrees from upright), and run dlib's face detector on all of
   them; the view with the best detection score is the face's.
2. Refine: from the 68 points of that view, read the surface point under each (Mitsuba
   ray casts, :class:`hack_render.render.mesh_views.MeshViews`), fit the face's frame
   (the similarity onto a reference face's landmarks), and render five close views
   around its front (straight on, 25 degrees left, right, 20 up and down), upright;
   then once more from the frame those views give.
3. Agree: lift each view's landmarks onto the surface; a landmark is kept when at least
   two views put it within ``agree_mm`` of the median of all views, and is the mean of
   those. The jaw line (landmarks 0-16) is a contour that moves with the view, so only
   the 51 inner landmarks are returned.

A point cloud is first meshed (:func:`surface_of_points`) to be rendered; its landmarks
are lifted onto that mesh, within a voxel of the points.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.geometry import load_default_model
from hack_render.io.image import to_srgb8
from hack_render.register.align import INNER, umeyama
from hack_render.register.scan import Scan, smoothed, vertex_colors
from hack_render.render.mesh_views import MeshViews
from hack_render.vision import dlib_models
from scenes.cameras import Camera, framing_distance, intrinsics, look_at

ROTATION_STEP_DEG = 45
#: (yaw, pitch) of the close views around the face's front, degrees
CLOSE_VIEWS = ((0, 0), (25, 0), (-25, 0), (0, 20), (0, -20))


def _directions() -> np.ndarray:
    d = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                  if (x, y, z) != (0, 0, 0)], np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _camera(eye, target, up, size: int, extent: float | None = None) -> Camera:
    K = intrinsics(size, size, 50.0)
    R, t = look_at(eye, target, up)
    return Camera(K, R, t, size, size, "search")


def _any_up(d: np.ndarray) -> np.ndarray:
    up = np.array([0.0, 1.0, 0.0])
    return up if abs(d @ up) < 0.9 else np.array([0.0, 0.0, 1.0])


def _to_rgb8(img: np.ndarray) -> np.ndarray:
    return to_srgb8(img[..., :3], operator="clip")


def _detect(rgb8: np.ndarray, upsample: int = 1) -> tuple[float, np.ndarray | None]:
    """(best detector score, (68, 2) points in this image's pixels) or (-inf, None)."""
    import dlib

    detector, predictor = dlib_models.frontal_detector(), dlib_models.shape_predictor()
    rects, scores, _ = detector.run(np.ascontiguousarray(rgb8), upsample, -0.3)
    if not len(rects):
        return -math.inf, None
    k = int(np.argmax(scores))
    r = rects[k]
    shape = predictor(rgb8, dlib.rectangle(r.left(), r.top(), r.right(), r.bottom()))
    pts = np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], np.float64)
    return float(scores[k]), pts


def _rotate(img: np.ndarray, deg: float) -> np.ndarray:
    """``img`` (S, S, 3) uint8 turned by ``deg`` about its centre (same size)."""
    from scipy import ndimage

    return ndimage.rotate(img, deg, axes=(1, 0), reshape=False, order=1, mode="constant")


def _unrotate(pts: np.ndarray, deg: float, size: int) -> np.ndarray:
    """Points detected in ``_rotate(img, deg)`` -> the original image's pixels."""
    a = math.radians(deg)
    c = np.array([size / 2.0, size / 2.0])
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return (pts - c) @ R.T + c


def _lift(views, cam: Camera, pts: np.ndarray) -> np.ndarray:
    """(68, 3) surface points under the 2-D points (nan where the ray misses)."""
    pos, hit = views.surface_points(cam)
    ij = np.clip(np.floor(pts).astype(int), 0, [cam.width - 1, cam.height - 1])
    out = pos[ij[:, 1], ij[:, 0]].copy()
    out[~hit[ij[:, 1], ij[:, 0]]] = np.nan
    return out


def _face_frame(lmk: np.ndarray, reference: np.ndarray, seen_from: np.ndarray):
    """(centre, forward, up) of a face from its lifted landmarks (68, 3; nan where
    missing): the rotation of the least-squares similarity onto the ``reference``
    landmarks (a head looking along +Z, +Y up) carries the reference's axes over."""
    ok = [i for i in INNER if np.isfinite(lmk[i]).all()]
    _, R, _ = umeyama(lmk[ok], reference[ok])  # scan -> reference
    fwd, up = R.T @ np.array([0.0, 0.0, 1.0]), R.T @ np.array([0.0, 1.0, 0.0])
    if fwd @ (seen_from - lmk[ok].mean(0)) < 0:  # a mirror-image fit: face the camera
        fwd = -fwd
    centre = 0.5 * (np.nanmean(lmk[36:48], 0) + np.nanmean(lmk[48:68], 0))
    return centre, fwd, up


def _close_views(views, frame, size: int) -> list[np.ndarray]:
    """Lifted landmarks of the close views around the face's front that find a face."""
    centre, fwd, up = frame
    K = intrinsics(size, size, 50.0)
    close = framing_distance(K, size, size, 0.24, margin=1.1)
    side = np.cross(up, fwd)
    lifts = []
    for yaw, pitch in CLOSE_VIEWS:
        d = fwd * math.cos(math.radians(yaw)) + side * math.sin(math.radians(yaw))
        d = d * math.cos(math.radians(pitch)) + up * math.sin(math.radians(pitch))
        cam = _camera(centre + d * close, centre, up, size)
        _, pts = _detect(_to_rgb8(views.render(cam)))
        if pts is not None:
            lifts.append(_lift(views, cam, pts))
    return lifts


def surface_of_points(scan: Scan, voxel: float = 0.0025, band: float = 0.006) -> Scan:
    """A mesh through a point cloud, for rendering it: the zero set of the signed distance
    to the nearest point's tangent plane (Hoppe et al. 1992), sampled on a ``voxel`` grid
    within ``band`` of the points and meshed by marching cubes (scikit-image)."""
    from scipy.spatial import cKDTree
    from skimage.measure import marching_cubes

    lo = scan.points.min(0) - 2 * band
    shape = np.ceil((scan.points.max(0) + 2 * band - lo) / voxel).astype(int) + 1
    if np.prod(shape) > 40_000_000:
        raise HackError(f"{scan.name}: the point cloud is too large to mesh for finding its "
                        "face; pass --landmarks FILE.")
    axes = [lo[k] + voxel * np.arange(shape[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    d, i = cKDTree(scan.points).query(grid, distance_upper_bound=band, workers=-1)
    near = np.isfinite(d)
    sdf = np.full(len(grid), band)
    j = i[near]
    sdf[near] = np.einsum("nc,nc->n", grid[near] - scan.points[j], scan.normals[j])
    try:
        v, f, _, _ = marching_cubes(sdf.reshape(shape), level=0.0, spacing=(voxel,) * 3)
    except (ValueError, RuntimeError) as exc:
        raise HackError(f"{scan.name}: no surface could be made through the points ({exc}); "
                        "pass --landmarks FILE.") from exc
    v = v + lo
    colors = None
    if scan.colors is not None:
        colors = scan.colors[cKDTree(scan.points).query(v, workers=-1)[1]]
    # marching cubes orders the triangles for an SDF that grows outwards
    return Scan.from_mesh(scan.name, v, f[:, ::-1].copy(), colors=colors)


def find_landmarks(scan: Scan, size: int = 320, agree_mm: float = 6.0,
                   progress: bool = False, reference: np.ndarray | None = None
                   ) -> tuple[np.ndarray, tuple[int, ...], dict]:
    """(K, 3) landmarks in the scan's frame (metres), their Multi-PIE ids, and a report.

    ``reference``: (68, 3) landmarks of a head looking along +Z with +Y up (default: the
    built-in model's mean face), whose axes give the face's frame."""

    if not scan.is_mesh:
        scan = surface_of_points(scan)

    if reference is None:
        import torch

        with torch.no_grad():
            reference = load_default_model()().landmarks[0].double().numpy()
    # rendered and lifted on the scan smoothed a little (a few tenths of a millimetre):
    # a noisy scan's normals would otherwise turn its shading to salt
    views = MeshViews(smoothed(scan.faces, scan.points), scan.faces, vertex_colors(scan),
                      size, size)
    centre = 0.5 * (scan.points.min(0) + scan.points.max(0))
    extent = scan.extent
    K = intrinsics(size, size, 50.0)
    dist = framing_distance(K, size, size, extent, margin=1.05)
    best = (-math.inf, None, None, None)
    dirs = _directions()
    for d in tqdm(dirs, desc=f"{scan.name}: looking for the face", unit="view",
                  disable=not progress, leave=False):
        cam = _camera(centre + d * dist, centre, _any_up(d), size)
        rgb8 = _to_rgb8(views.render(cam))
        for deg in range(0, 360, ROTATION_STEP_DEG):
            score, pts = _detect(_rotate(rgb8, deg), upsample=0)
            if pts is not None and score > best[0]:
                best = (score, _unrotate(pts, deg, size), cam, deg)
    score, pts, cam, _ = best
    if pts is None:
        raise HackError(f"{scan.name}: no face found in 26 views x {360 // ROTATION_STEP_DEG} "
                        "rotations of the scan. "
                        "Is it a head? Pass --landmarks FILE with 68 or 51 3-D points.")
    first = _lift(views, cam, pts)
    ok = np.isfinite(first).all(1)
    if ok[list(INNER)].sum() < 20:
        raise HackError(f"{scan.name}: the face found does not lie on the scan's surface. "
                        "Pass --landmarks FILE.")
    lifts: list[np.ndarray] = []
    for _ in range(2):  # the frame from the search view, then from the close views
        L = np.stack(lifts) if lifts else first[None]
        with warnings.catch_warnings():  # landmarks no view hit stay nan
            warnings.simplefilter("ignore", RuntimeWarning)
            lifts = _close_views(views, _face_frame(np.nanmedian(L, 0), reference, cam.center),
                                 size)
    if len(lifts) < 2:
        raise HackError(f"{scan.name}: the face was found in only {len(lifts)} close view(s); "
                        "expected 2 or more. Pass --landmarks FILE.")
    L = np.stack(lifts)  # (V, 68, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(L, 0)
    near = np.linalg.norm(L - med, axis=2) * 1000.0 < agree_mm  # (V, 68)
    ids = [i for i in INNER if near[:, i].sum() >= 2]
    if len(ids) < 20:
        raise HackError(f"{scan.name}: the views agree on only {len(ids)} landmarks (< 20). "
                        "Pass --landmarks FILE.")
    pts3 = np.stack([np.nanmean(np.where(near[:, i, None], L[:, i], np.nan), 0) for i in ids])
    spread = [float(np.nanmax(np.linalg.norm(L[near[:, i], i] - pts3[k], axis=1)) * 1000)
              for k, i in enumerate(ids)]
    info = {"search_score": score, "close_views": len(lifts), "kept": len(ids),
            "spread_mm_median": float(np.median(spread))}
    return pts3, tuple(ids), info
