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
    """Mitsuba's ``perspective`` models square pixels and a principal point at the film's
    centre. An off-centre principal point is taken where it sits on the pixel grid's
    half-pixels: the camera is then a window of a larger film centred on it
    (:func:`film_window`), e.g. a crop of a centred camera's image."""
    K = cam.K
    twice = 2.0 * np.array([K[0, 2], K[1, 2]])
    ok = (abs(K[0, 0] - K[1, 1]) < 1e-6 * K[0, 0] and K[0, 1] == 0
          and np.all(np.abs(twice - np.round(twice)) < 1e-6))
    if not ok:
        raise HackError(f"camera {cam.name!r}: expected K with fx == fy, no skew and the "
                        f"principal point on the pixel grid's half-pixels, found K = "
                        f"{K.tolist()}. Use scenes.cameras.intrinsics().")


def film_window(cam: Camera) -> tuple[int, int, int, int] | None:
    """(film width, film height, crop x, crop y) of a camera whose principal point is
    off its image's centre: the smallest film centred on the principal point that holds
    the image, the image its crop window at that offset; None for a centred one."""
    cx2, cy2 = (round(2.0 * float(cam.K[i, 2])) for i in (0, 1))
    if (cx2, cy2) == (cam.width, cam.height):
        return None
    fw, fh = max(cx2, 2 * cam.width - cx2), max(cy2, 2 * cam.height - cy2)
    return fw, fh, (fw - cx2) // 2, (fh - cy2) // 2


def check_centred(cam: Camera) -> None:
    """:func:`check_intrinsics`, and the principal point at the image's centre (a scene's
    camera moved in place keeps its film: a crop's window needs a new scene)."""
    check_intrinsics(cam)
    if film_window(cam) is not None:
        raise HackError(f"camera {cam.name!r}: expected the principal point at the image "
                        f"centre to move a scene's camera, found K = {cam.K.tolist()} (a "
                        "crop's camera: build a new scene for it).")


def cropped(cam: Camera, x0: int, y0: int, width: int, height: int) -> Camera:
    """The camera of the window (x0, y0, width, height) of ``cam``'s image (pixels): the
    same rays through the same pixels, rendered alone (:func:`film_window`)."""
    K = np.array(cam.K, dtype=np.float64)
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, cam.R, cam.t, int(width), int(height), cam.name)


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
    film = {"type": "hdrfilm", "width": cam.width, "height": cam.height,
            "pixel_format": pixel_format, "component_format": "float32",
            "rfilter": {"type": pixel_filter}}
    fov = cam.fov_x_deg
    window = film_window(cam)
    if window is not None:   # a crop: the film centred on the principal point, its window
        fw, fh, x0, y0 = window
        film.update(width=fw, height=fh, crop_offset_x=x0, crop_offset_y=y0,
                    crop_width=cam.width, crop_height=cam.height)
        fov = math.degrees(2.0 * math.atan(0.5 * fw / float(cam.K[0, 0])))
    return {
        "type": "perspective", "fov_axis": "x", "fov": fov,
        "near_clip": 0.01, "far_clip": 100.0,
        "to_world": mi.ScalarTransform4f(camera_to_world(cam).tolist()),
        "film": film,
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
