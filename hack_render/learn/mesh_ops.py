"""Small mesh operators used by the learners: normals, Laplacians, neck landmarks."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from hack_render.learn.ict_default import averaging_operator
from hack_render.learn.skeleton_fit import midline_profiles


def vertex_normals(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals. v: (N, 3), faces: (F, 3) -> (N, 3) (zero if isolated)."""
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    n = np.zeros_like(v, dtype=np.float64)
    for c in range(3):
        np.add.at(n, faces[:, c], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.maximum(norm, 1e-20)


def uniform_laplacian(faces: np.ndarray, n: int, v: np.ndarray | None = None) -> sparse.csr_matrix:
    """L = I - A with A the row-normalised adjacency (inverse-edge-length weighted if ``v``)."""
    return (sparse.eye(n) - averaging_operator(faces, n, v)).tocsr()


def ring(faces: np.ndarray, mask: np.ndarray, k: int = 1) -> np.ndarray:
    """Dilate a boolean vertex mask by k rings of the triangle mesh."""
    mask = mask.copy()
    for _ in range(k):
        touched = mask[faces].any(1)
        mask[faces[touched].ravel()] = True
    return mask


def neck_front_landmarks(v: np.ndarray, skin_idx: np.ndarray, chin_idx: int) -> dict[str, float]:
    """Chin-neck angle (hyoid, C3), suprasternal notch (T2) and the C4-C5 level on the front
    midline of one mesh (metres).

    The notch is the most posterior point of the front midline profile below the chin (as in
    :mod:`hack_render.learn.skeleton_fit`); the angle is the lowest height above which the
    profile leaves the lower-neck line (fitted over the 3 cm above the notch) by more than
    6 mm forward. Surface anatomy (ANATOMY.md) puts the hyoid at C3, the laryngeal prominence
    at C4-C5 and the notch at T2; taking vertebral levels as evenly spaced along the front
    skin between C3 and T2 (six levels), C4-C5 lies 1.5 / 6 = 25 % of the way from the
    angle to the notch.

    Returns:
        {"y_angle", "y_notch", "y_c45", "z_c45"}: heights (and the front depth at C4-C5).
    """
    skin = v[skin_idx]
    ys, front, _ = midline_profiles(skin)
    y_chin = v[chin_idx, 1]
    ok = np.isfinite(front)
    neck = (ys < y_chin - 0.01) & (ys > skin[:, 1].min() + 0.02) & ok
    y_notch = float(ys[neck][np.argmin(front[neck])])
    low = ok & (ys >= y_notch) & (ys <= y_notch + 0.03)
    slope, icpt = np.polyfit(ys[low], front[low], 1)
    above = ok & (ys > y_notch + 0.03) & (ys < y_chin)
    off = front[above] - (slope * ys[above] + icpt)
    leave = np.flatnonzero(off > 0.006)
    y_angle = float(ys[above][leave[0]]) if len(leave) else float(y_chin - 0.012)
    y_c45 = y_angle + 0.25 * (y_notch - y_angle)
    z_c45 = float(np.interp(y_c45, ys[ok], front[ok]))
    return {"y_angle": y_angle, "y_notch": y_notch, "y_c45": float(y_c45), "z_c45": z_c45}
