"""Light rigs (``scenes.lights.LightRig``) and cameras (``scenes.cameras.Camera``) as
Mitsuba plugin dictionaries and transforms."""

from __future__ import annotations

import math

import numpy as np

from hack_render.errors import HackError
from scenes.cameras import Camera
from scenes.lights import LightRig

#: OpenCV camera axes (x right, y down) -> Mitsuba camera axes (x left, y up).
_CV_TO_MI = np.diag([-1.0, -1.0, 1.0])


def camera_to_world(cam: Camera) -> np.ndarray:
    """Mitsuba ``to_world`` (4, 4) of an OpenCV camera: [R^T diag(-1,-1,1) | centre]."""
    m = np.eye(4)
    m[:3, :3] = cam.R.T @ _CV_TO_MI
    m[:3, 3] = cam.center
    return m


def check_intrinsics(cam: Camera) -> None:
    """Mitsuba's ``perspective`` models square pixels; we also keep the principal point
    centred, so that K round-trips exactly."""
    K = cam.K
    ok = (abs(K[0, 0] - K[1, 1]) < 1e-6 * K[0, 0] and abs(K[0, 2] - cam.width / 2) < 1e-6
          and abs(K[1, 2] - cam.height / 2) < 1e-6 and K[0, 1] == 0)
    if not ok:
        raise HackError(f"camera {cam.name!r}: expected K with fx == fy, no skew and the "
                        f"principal point at the image centre, found K = {K.tolist()}. Use "
                        "scenes.cameras.intrinsics().")


def sensor_dict(cam: Camera, spp: int, pixel_format: str = "rgba",
                pixel_filter: str = "gaussian", sampler: str = "independent") -> dict:
    """A ``perspective`` sensor with an ``hdrfilm`` of the camera's size.

    ``pixel_filter="box"`` splats each sample into one pixel only: with a fixed seed the
    image is then bit-identical from run to run (the wider ``gaussian`` filter adds
    samples into neighbouring pixels from several threads, in no fixed order).
    ``sampler``: a Mitsuba sampler plugin; ``spp`` must be a count it takes unrounded
    (``settings.sampler_spp``)."""
    import mitsuba as mi

    check_intrinsics(cam)
    return {
        "type": "perspective", "fov_axis": "x", "fov": cam.fov_x_deg,
        "near_clip": 0.01, "far_clip": 100.0,
        "to_world": mi.ScalarTransform4f(camera_to_world(cam).tolist()),
        "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                 "pixel_format": pixel_format, "component_format": "float32",
                 "rfilter": {"type": pixel_filter}},
        "sampler": {"type": sampler, "sample_count": spp},
    }


def rotation_y(deg: float) -> np.ndarray:
    """(4, 4) rotation about +Y by ``deg`` degrees."""
    a = math.radians(deg)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    return m


def _look_at(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Mitsuba's look_at as a (4, 4) array (local +Z towards target)."""
    p, t = np.asarray(position, float), np.asarray(target, float)
    d = (t - p) / np.linalg.norm(t - p)
    left = np.cross(up, d)
    if np.linalg.norm(left) < 1e-9:
        left = np.cross((0.0, 0.0, 1.0), d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, p
    return m


def area_light_transform(light, rotation_deg: float = 0.0) -> np.ndarray:
    """``to_world`` of a ``rectangle`` emitter ([-1, 1]^2 in XY, facing +Z), rotated about Y."""
    scale = np.diag([light.size[0] / 2.0, light.size[1] / 2.0, 1.0, 1.0])
    return rotation_y(rotation_deg) @ _look_at(light.position, light.target) @ scale


def sampling_weights(rig: LightRig, env_image: np.ndarray | None) -> list[float]:
    """How often next-event estimation picks each emitter of ``emitter_dicts`` (area
    lights in order, then the environment): in proportion to the irradiance each gives
    the subject, as a surface at the light's target facing it would receive it. An area
    light: its mean radiance times its solid angle there (area / distance^2, small-light
    approximation); the environment: pi times its mean radiance over the sphere (a
    lat-long map's rows weighted by sin theta), as a uniform sky gives a facing surface.

    Mitsuba's default picks every emitter equally often. The studio rig's dim
    environment (3 % of the irradiance) then took a quarter of the shadow rays, and the
    image's noise depended on whether the sample count divided among the four emitters:
    25 orthogonal samples were noisier than 16 multijitter ones. With these weights the
    README still's 25 and 49 samples are 2.7 and 3.4 dB less noisy (docs/render.md,
    "Light sampling")."""
    out = []
    for light in rig.area:
        d = np.subtract(light.position, light.target, dtype=np.float64)
        solid = light.size[0] * light.size[1] / max(float(d @ d), 1e-12)
        out.append(float(np.mean(light.radiance)) * rig.scale * solid)
    if env_image is not None:
        img = np.asarray(env_image, np.float64)
        theta = (np.arange(img.shape[0]) + 0.5) / img.shape[0] * np.pi
        row_w = np.sin(theta)[:, None]
        mean = float((img.mean(-1) * row_w).sum() / (row_w.sum() * img.shape[1]))
        out.append(np.pi * mean * rig.scale)
    elif rig.env_constant is not None:
        out.append(np.pi * float(np.mean(rig.env_constant)) * rig.scale)
    # a dark emitter keeps a little: Mitsuba takes positive weights only
    top = max(out, default=1.0)
    return [max(w, 1e-6 * top, 1e-12) for w in out]


def emitter_dicts(rig: LightRig, env_image: np.ndarray | None) -> dict[str, dict]:
    """Mitsuba emitters of a rig, keyed ``light_<i>`` and ``environment``, each picked by
    next-event estimation in proportion to :func:`sampling_weights`.

    Args:
        env_image: the rig's lat-long map (H, 2H, 3), already read (from ``env_map`` or
            ``env_file``), or None.
    """
    import mitsuba as mi

    out: dict[str, dict] = {}
    s = rig.scale
    weights = sampling_weights(rig, env_image)
    for i, light in enumerate(rig.area):
        out[f"light_{i}"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f(area_light_transform(light, rig.rotation_deg).tolist()),
            "emitter": {"type": "area", "sampling_weight": weights[i],
                        "radiance": {"type": "rgb",
                                     "value": [float(c) * s for c in light.radiance]}},
        }
    if env_image is not None:
        out["environment"] = {"type": "envmap", "bitmap": mi.Bitmap(env_image), "scale": s,
                              "sampling_weight": weights[-1],
                              "to_world": mi.ScalarTransform4f(rotation_y(rig.rotation_deg).tolist())}
    elif rig.env_constant is not None:
        out["environment"] = {"type": "constant", "sampling_weight": weights[-1], "radiance": {
            "type": "rgb", "value": [float(c) * s for c in rig.env_constant]}}
    return out
