"""The virtual view of a photo that the photometric stage renders and compares in: a
camera looking straight at the face (the fitted camera turned by Rv about its centre,
the face's box filling the frame), the photo resampled into it through the homography
K Rv^T Kv^-1 after an anti-aliasing blur, and the landmark skin polygon there.
"""

from __future__ import annotations

import numpy as np

from hack_render.fit.camera import R0
from hack_render.fit.state import View
from scenes.cameras import Camera

FACE_OUTLINE = list(range(17)) + list(range(26, 16, -1))
HOLES = (list(range(36, 42)), list(range(42, 48)), list(range(60, 68)))


def rotation_to_axis(d: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking the unit vector ``d`` onto +Z (Rodrigues)."""
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(d, z)
    s, c = np.linalg.norm(v), float(d @ z)
    if s < 1e-12:
        return np.eye(3)
    k = v / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def virtual_camera(view: View, res: int):
    """(Camera, H) for a view at ``res`` px: H maps virtual pixels to photo pixels."""
    ph, det = view.photo, view.detection
    f = float(view.focal.detach())
    K = np.array([[f, 0, ph.width / 2], [0, f, ph.height / 2], [0, 0, 1.0]])
    pts = det.points
    centre = 0.5 * (pts.min(0) + pts.max(0))
    centre[1] -= 0.12 * det.size  # include the forehead
    side = 2.0 * det.size
    Rv = rotation_to_axis(np.linalg.inv(K) @ np.r_[centre, 1.0])
    fv = f * res / side
    Kv = np.array([[fv, 0, res / 2], [0, fv, res / 2], [0, 0, 1.0]])
    R = Rv @ R0.numpy().astype(np.float64)
    t = Rv @ view.transl.detach().numpy().astype(np.float64)
    H = K @ Rv.T @ np.linalg.inv(Kv)
    return Camera(Kv, R, t, res, res, f"{ph.name}_{res}"), H, side / res


def warp_photo(img: np.ndarray, H: np.ndarray, res: int, scale: float,
               mode: str = "edge") -> np.ndarray:
    """Resample the photo (h, w, C) into the virtual view (res, res, C), pre-blurred;
    beyond its border the edge pixels repeat (``mode="constant"``: zeros)."""
    from scipy.ndimage import gaussian_filter
    from skimage.transform import ProjectiveTransform, warp

    sigma = max(0.0, 0.5 * scale - 0.3)
    src = gaussian_filter(img, sigma=(sigma, sigma, 0)) if sigma > 0 else img
    # skimage coordinates have pixel centres at integers; ours at +0.5
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    Ti = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
    return warp(src, ProjectiveTransform(Ti @ H @ T), output_shape=(res, res), order=1,
                mode=mode, cval=0.0).astype(np.float32)


def on_photo(h: int, w: int, H: np.ndarray, res: int) -> np.ndarray:
    """(res, res) bool: the virtual view's pixels that lie on an (h, w) photo (``H``: view
    pixel -> photo pixel, as :func:`warp_photo` takes it); beyond it ``warp_photo``'s
    default repeats the photo's edge pixels."""
    return warp_photo(np.ones((h, w, 1), np.float32), H, res, 1.0, mode="constant")[..., 0] > 0.5


def face_mask(points_v: np.ndarray, res: int) -> np.ndarray:
    """Skin polygon from 68 landmarks in virtual pixels: face outline minus eyes, mouth."""
    from skimage.draw import polygon

    m = np.zeros((res, res), bool)
    out = points_v[FACE_OUTLINE]
    rr, cc = polygon(out[:, 1] - 0.5, out[:, 0] - 0.5, (res, res))
    m[rr, cc] = True
    for hole in HOLES:
        p = points_v[hole]
        c = p.mean(0)
        p = c + 1.3 * (p - c)
        rr, cc = polygon(p[:, 1] - 0.5, p[:, 0] - 0.5, (res, res))
        m[rr, cc] = False
    return m
