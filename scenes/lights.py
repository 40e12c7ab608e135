"""Lighting presets, described without Mitsuba: area lights and environment maps.

A :class:`LightRig` is a list of rectangular area lights plus an environment (a
constant radiance, a lat-long map array, or a user's HDR file) with a rotation about +Y
and an exposure in stops. ``hack_render.render.lights`` turns it into Mitsuba emitters.

Presets (:data:`PRESETS`):
- ``studio``: three-point lighting with soft boxes (key 45 degrees up-left of camera,
  fill on the other side, rim behind), plus a dim grey ambient.
- ``light_stage``: uniform white illumination from every direction (a constant
  environment), as in a light-stage flat-lit capture.
- ``overcast_sun``: an overcast sky (CIE overcast luminance gradient, cool tint) with a
  sun disc breaking through, generated here and written as an EXR lat-long map.
- ``window``: an interior lit by one large window to the subject's right, with a warm,
  dim ambient from the room.
Environment lat-long maps use Mitsuba's convention: row 0 is straight up (+Y), the
centre column lies along +Z (in front of the face); see :func:`latlong_directions`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.io.image import rgb_channels, write_exr

DATA_DIR = Path(__file__).resolve().parent / "data"


@dataclass(frozen=True)
class AreaLight:
    """A one-sided rectangular emitter facing ``target``.

    Attributes:
        position: (3,) centre, metres. target: (3,) point it faces.
        size: (width, height) metres. radiance: (3,) linear Rec.709 W/(m^2 sr).
    """

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    size: tuple[float, float]
    radiance: tuple[float, float, float]


@dataclass(frozen=True)
class LightRig:
    """Area lights plus one environment.

    Attributes:
        area: the rectangular lights.
        env_constant: (3,) radiance of a uniform environment, or None.
        env_map: (H, 2H, 3) float32 lat-long radiance, or None.
        env_file: path of a lat-long .exr/.hdr (read by the renderer), or None.
        rotation_deg: environment rotation about +Y. exposure: stops (scale 2**exposure,
            applied to every light of the rig).
    """

    name: str
    area: tuple[AreaLight, ...] = ()
    env_constant: tuple[float, float, float] | None = None
    env_map: np.ndarray | None = field(default=None, repr=False)
    env_file: str | None = None
    rotation_deg: float = 0.0
    exposure: float = 0.0

    @property
    def scale(self) -> float:
        return 2.0 ** self.exposure


def latlong_directions(height: int) -> np.ndarray:
    """World directions (H, 2H, 3) of a lat-long map's pixel centres (Mitsuba ``envmap``).

    Pixel (u, v) in [0, 1]^2 looks along theta = v pi from +Y and phi = 2 pi u:
    d = (sin(phi) sin(theta), cos(theta), -cos(phi) sin(theta)), so the centre column
    (u = 0.5) looks along +Z, towards the face (checked against Mitsuba in the tests).
    """
    w = 2 * height
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(w) + 0.5) / w
    theta = v[:, None] * math.pi
    phi = u[None, :] * 2.0 * math.pi
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st),
                    axis=-1)


def overcast_sky(height: int = 128, sun_dir=(0.45, 0.75, 0.5), sun_strength: float = 300.0,
                 sky_radiance: float = 1.0) -> np.ndarray:
    """An overcast sky with a soft sun, as a lat-long map (H, 2H, 3) float32.

    Sky: CIE standard overcast sky, L(theta) = Lz (1 + 2 cos theta) / 3 for directions
    above the horizon, slightly blue; ground below the horizon: dim grey-brown (albedo
    0.15 lit by the sky). Sun: a disc of 2.5 degrees radius with a Gaussian halo.
    """
    d = latlong_directions(height)
    cos_t = d[..., 1]
    sky = sky_radiance * (1.0 + 2.0 * np.clip(cos_t, 0.0, 1.0)) / 3.0
    img = sky[..., None] * np.array([0.92, 0.97, 1.06])
    ground = cos_t < 0.0
    img[ground] = sky_radiance * 0.15 * np.array([0.85, 0.8, 0.72])
    s = np.asarray(sun_dir, dtype=np.float64)
    s /= np.linalg.norm(s)
    ang = np.arccos(np.clip(d @ s, -1.0, 1.0))
    disc = (ang < math.radians(2.5)).astype(np.float64)
    halo = np.exp(-0.5 * (ang / math.radians(8.0)) ** 2) * 0.04
    img += (sun_strength * disc + sun_strength * halo)[..., None] * np.array([1.0, 0.95, 0.86])
    return img.astype(np.float32)


def overcast_sky_file() -> Path:
    """Path of the generated overcast-sky EXR, writing it (once) if it does not exist.

    Prefers ``scenes/data/overcast_sun.exr``; falls back to ``$XDG_CACHE_HOME/hack-render``
    when the package folder is read-only.
    """
    name = "overcast_sun.exr"
    for folder in (DATA_DIR, Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                   / "hack-render"):
        path = folder / name
        if path.is_file():
            return path
        try:
            write_exr(path, rgb_channels(overcast_sky()),
                      {"comment": "hack-render overcast sky with sun (scenes/lights.py)"})
            return path
        except (HackError, OSError):
            continue
    raise HackError(f"overcast sky: could not write {name} under {DATA_DIR} or the cache "
                    "folder. Make one of them writable.")


def studio() -> LightRig:
    """Three-point studio lighting with large soft boxes."""
    t = (0.0, 0.02, 0.05)
    return LightRig("studio", area=(
        AreaLight((-0.9, 0.7, 1.2), t, (0.6, 0.6), (14.0, 13.5, 12.8)),  # key, camera right-up
        AreaLight((1.1, 0.15, 1.0), t, (0.8, 0.8), (3.0, 3.05, 3.2)),    # fill, other side
        AreaLight((0.5, 0.8, -1.0), t, (0.5, 0.3), (16.0, 16.0, 16.0)),  # rim, behind above
    ), env_constant=(0.04, 0.04, 0.04))


def light_stage() -> LightRig:
    """Uniform illumination from the whole sphere."""
    return LightRig("light_stage", env_constant=(1.0, 1.0, 1.0))


def overcast_sun() -> LightRig:
    """Overcast sky with a sun, from a generated EXR environment map."""
    return LightRig("overcast_sun", env_file=str(overcast_sky_file()))


def window() -> LightRig:
    """A large window to the subject's right (world -X), and a warm dim room."""
    return LightRig("window", area=(
        AreaLight((-1.6, 0.35, 0.6), (0.0, 0.0, 0.05), (1.0, 1.4), (15.0, 16.0, 17.5)),
    ), env_constant=(0.06, 0.05, 0.04))


PRESETS = {"studio": studio, "light_stage": light_stage, "overcast_sun": overcast_sun,
           "window": window}


def preset(name: str, rotation_deg: float = 0.0, exposure: float = 0.0) -> LightRig:
    """A named preset, or ``env:PATH`` for a user's lat-long .exr/.hdr environment map."""
    if name.startswith("env:"):
        path = Path(name[4:]).expanduser()
        if not path.is_file():
            raise HackError(f"lighting {name!r}: expected an existing lat-long .exr or .hdr "
                            f"file, found no file at {path}.")
        if path.suffix.lower() not in (".exr", ".hdr"):
            raise HackError(f"lighting {name!r}: expected a .exr or .hdr file, found "
                            f"{path.suffix or 'no suffix'}.")
        rig = LightRig(f"env:{path.name}", env_file=str(path))
    elif name in PRESETS:
        rig = PRESETS[name]()
    else:
        raise HackError(f"lighting preset: expected one of {', '.join(PRESETS)} or "
                        f"env:PATH.exr, found {name!r}.")
    return replace(rig, rotation_deg=rotation_deg, exposure=exposure)
