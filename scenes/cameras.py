"""Camera presets as pinhole cameras with OpenCV intrinsics and extrinsics.

Conventions: world metres, Y up, the face looks along +Z. A :class:`Camera` stores
OpenCV's ``K`` (pixels) and ``R, t`` (world -> camera: ``x_cam = R @ X + t``; camera
x right, y down, z forward). Mitsuba's ``to_world`` is derived from them in
``hack_render.render.camera``; nothing here imports Mitsuba.

Presets (all look at ``target`` and keep an object of height ``extent`` in frame):
``portrait`` (front, focal length in mm), ``three_quarter`` (35 degrees), ``profile``
(90 degrees, the subject's left), and ``ring`` (N cameras evenly spaced around the
vertical axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hack_render.errors import HackError
from hack_render.io import write_json

#: Sensor width that focal lengths refer to (full-frame 35 mm).
SENSOR_WIDTH_MM = 36.0
#: Default framing: the default head's centre and height (chin-to-crown plus neck), metres.
DEFAULT_TARGET = (0.0, -0.01, 0.02)
DEFAULT_EXTENT = 0.36


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) intrinsics in pixels.
        R: (3, 3) world-to-camera rotation (OpenCV). t: (3,) translation, metres.
        width, height: image size in pixels.
        name: label used in file names and metadata.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    name: str = "camera"

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,) metres: -R^T t."""
        return -self.R.T @ self.t

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.width / self.K[0, 0]))

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> pixel coordinates (..., 2) (OpenCV: pixel centres at +0.5)."""
        cam = points @ self.R.T + self.t
        uvw = cam @ self.K.T
        return uvw[..., :2] / uvw[..., 2:3]

    def to_dict(self) -> dict:
        """JSON-ready dict with K, R, t, size and name (OpenCV convention)."""
        return {"name": self.name, "width": self.width, "height": self.height,
                "K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
                "convention": "OpenCV: x_cam = R @ X_world + t; x right, y down, z forward"}


def intrinsics(width: int, height: int, focal_mm: float,
               sensor_width_mm: float = SENSOR_WIDTH_MM) -> np.ndarray:
    """K for square pixels and a centred principal point; focal length in mm on a sensor."""
    if not focal_mm > 0:
        raise HackError(f"focal length: expected > 0 mm, found {focal_mm}.")
    f = focal_mm / sensor_width_mm * width
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV (R, t) of a camera at ``eye`` looking at ``target`` with world ``up`` up."""
    eye, target, up = (np.asarray(x, dtype=np.float64) for x in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # camera x (right) = forward x up, in a right-handed world
    if np.linalg.norm(x) < 1e-9:
        raise HackError("camera: expected a view direction not parallel to 'up', found "
                        "them parallel. Move the camera off the vertical axis.")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # camera y points down
    R = np.stack([x, y, z])
    return R, -R @ eye


def framing_distance(K: np.ndarray, width: int, height: int, extent: float,
                     margin: float = 1.15) -> float:
    """Distance at which an object ``extent`` metres tall and wide fills the frame with a margin."""
    half = 0.5 * extent * margin
    return max(half * K[0, 0] / (0.5 * width), half * K[1, 1] / (0.5 * height))


def orbit(width: int, height: int, focal_mm: float, yaw_deg: float, pitch_deg: float = 0.0,
          target=DEFAULT_TARGET, extent: float = DEFAULT_EXTENT, name: str = "orbit",
          distance: float | None = None) -> Camera:
    """A camera on a sphere around ``target``: yaw about +Y from the +Z (front) axis,
    pitch up from the horizontal plane, at the framing distance unless ``distance``."""
    K = intrinsics(width, height, focal_mm)
    d = distance if distance is not None else framing_distance(K, width, height, extent)
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    offset = d * np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch),
                           math.cos(yaw) * math.cos(pitch)])
    eye = np.asarray(target, dtype=np.float64) + offset
    R, t = look_at(eye, target)
    return Camera(K, R, t, width, height, name)


def portrait(width: int, height: int, focal_mm: float = 85.0, **kw) -> list[Camera]:
    """Front view, slightly above eye level."""
    return [orbit(width, height, focal_mm, 0.0, 5.0, name="portrait", **kw)]


def three_quarter(width: int, height: int, focal_mm: float = 85.0, **kw) -> list[Camera]:
    """Three-quarter view, turned 35 degrees towards the subject's left."""
    return [orbit(width, height, focal_mm, 35.0, 5.0, name="three_quarter", **kw)]


def profile(width: int, height: int, focal_mm: float = 85.0, **kw) -> list[Camera]:
    """Side view of the subject's left side (camera on +X)."""
    return [orbit(width, height, focal_mm, 90.0, 0.0, name="profile", **kw)]


def ring(width: int, height: int, focal_mm: float = 50.0, n: int = 8, pitch_deg: float = 0.0,
         **kw) -> list[Camera]:
    """``n`` cameras evenly spaced on a horizontal circle, the first in front."""
    if not 1 <= n <= 1024:
        raise HackError(f"ring cameras: expected 1..1024 views, found {n}.")
    return [orbit(width, height, focal_mm, 360.0 * i / n, pitch_deg, name=f"ring_{i:03d}", **kw)
            for i in range(n)]


PRESETS: dict[str, Callable[..., list[Camera]]] = {
    "portrait": portrait, "three_quarter": three_quarter, "profile": profile, "ring": ring,
}


def preset(name: str, width: int, height: int, focal_mm: float | None = None,
           n: int = 8, **kw) -> list[Camera]:
    """Cameras of a named preset (see :data:`PRESETS`)."""
    if name not in PRESETS:
        raise HackError(f"camera preset: expected one of {', '.join(PRESETS)}, found "
                        f"{name!r}.")
    if focal_mm is not None:
        kw["focal_mm"] = focal_mm
    if name == "ring":
        kw["n"] = n
    return PRESETS[name](width, height, **kw)


def save_cameras(path, cameras: list[Camera], render: dict | None = None) -> None:
    """Write cameras as JSON (OpenCV K, R, t) through a temporary file; ``render``: what
    the images were rendered with (``render.cli.rendered``: sampler, spp), as ``render``."""
    data = {"cameras": [c.to_dict() for c in cameras]}
    if render is not None:
        data["render"] = render
    write_json(path, data, indent=1)
