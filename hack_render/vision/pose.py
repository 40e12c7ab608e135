"""Head pose from 68 landmarks, and which landmarks it hides.

A weak-perspective fit of the model's mean 68 landmarks (3-D convention: fixed surface
points; ``hack_render/data/landmarks68_mean.npz``, the calibrated embedding's points on
the model's template with their surface normals, written by
``python -m hack_render.learn.face_ert mean-shape``) to detected points: rotation, scale
and image offset by robust least squares from five starting yaws (a profile's mirror
image fits nearly as well the other way round; the best start wins). A landmark is
hidden when its rotated normal turns away from the camera.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hack_render.errors import HackError

MEAN_FILE = Path(__file__).resolve().parents[1] / "data" / "landmarks68_mean.npz"
_CACHE: list = []


@dataclass
class HeadPose:
    """R (3, 3) model -> camera-aligned frame (x right, y up, z toward the camera),
    scale (pixels per metre), offset (2,) pixels; yaw, pitch, roll in degrees (yaw > 0:
    the face turned toward the image's left, i.e. the subject's own left visible...
    see :meth:`angles`); rms: the fit's residual, pixels."""

    R: np.ndarray
    scale: float
    offset: np.ndarray
    rms: float

    def project(self, X: np.ndarray) -> np.ndarray:
        """(N, 3) model-frame metres -> (N, 2) pixels (image y down)."""
        Y = X @ self.R.T
        return np.c_[Y[:, 0], -Y[:, 1]] * self.scale + self.offset

    def angles(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll) degrees, Y-X-Z order: yaw about the vertical (the camera's
        yaw about the head as in hack_render.dataset.composites: > 0 sees the subject's
        left side), pitch > 0 the camera above, roll in the image plane."""
        from scipy.spatial.transform import Rotation

        # R maps model to view; the camera's own orbit is its inverse
        yaw, pitch, roll = Rotation.from_matrix(self.R.T).as_euler("YXZ", degrees=True)
        return float(yaw), float(-pitch), float(roll)


def mean_shape() -> tuple[np.ndarray, np.ndarray]:
    """(68, 3) mean landmark positions (metres, model frame) and (68, 3) unit normals."""
    if not _CACHE:
        if not MEAN_FILE.is_file():
            raise HackError(f"head pose: expected {MEAN_FILE} (shipped with hack-render; "
                            "rebuild: python -m hack_render.learn.face_ert mean-shape), found "
                            "it missing.")
        with np.load(MEAN_FILE) as z:
            _CACHE.append((z["points"].astype(np.float64), z["normals"].astype(np.float64)))
    return _CACHE[0]


def fit_pose(points: np.ndarray, weights: np.ndarray | None = None) -> HeadPose:
    """Weak-perspective pose of the mean landmarks fitted to (68, 2) pixel points."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    X, _ = mean_shape()
    X = X - X.mean(0)
    x = np.asarray(points, np.float64)
    w = np.ones(68) if weights is None else np.asarray(weights, np.float64)
    size = float(np.sqrt(np.prod(np.ptp(x, 0)) + 1e-9))
    s0 = size / float(np.sqrt(np.prod(np.ptp(X[:, :2], 0))))

    def resid(q):
        R = Rotation.from_rotvec(q[:3]).as_matrix()
        Y = X @ R.T
        p = np.c_[Y[:, 0], -Y[:, 1]] * q[3] + q[4:6]
        return ((p - x) * np.sqrt(w)[:, None]).ravel() / size

    best = None
    for yaw in (-80.0, -40.0, 0.0, 40.0, 80.0):
        # model -> view for a camera orbiting to ``yaw``: rotate the head by -yaw
        q0 = np.r_[Rotation.from_euler("Y", -yaw, degrees=True).as_rotvec(), s0, x.mean(0)]
        r = least_squares(resid, q0, loss="soft_l1", f_scale=0.02)
        if best is None or r.cost < best.cost:
            best = r
    q = best.x
    R = Rotation.from_rotvec(q[:3]).as_matrix()
    rms = float(np.sqrt(np.mean(best.fun ** 2)) * size * np.sqrt(2))
    return HeadPose(R, float(q[3]), q[4:6].copy(), rms)


def visible_from_pose(pose: HeadPose, min_cos: float = 0.1) -> np.ndarray:
    """(68,) bool: the mean landmark's normal, rotated, faces the camera
    (z component over ``min_cos``)."""
    _, N = mean_shape()
    return (N @ pose.R.T)[:, 2] > min_cos
