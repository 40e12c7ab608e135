"""Dataset backgrounds: real photographs shipped with scikit-image, composited behind.

The renderer's film holds the subject alone (camera rays never see an emitter, see
``render/scene_images.py``), premultiplied by its coverage; a sample's background photo is
cropped, flipped and scaled here and composited behind it (RGB + (1 - alpha) photo), so
labels, depth and the matte are those of the subject exactly as without a background.

Photos (:data:`PHOTOS`): the colour and texture images that scikit-image installs with
its package (``skimage/data``, no download), each public domain or CC0 according to
scikit-image's own documentation (``skimage.data.<name>.__doc__``); faces are left out
(``astronaut``) so that no person is labelled background, and so is the stereo
``motorcycle`` pair (Middlebury licence). Photos are sRGB-decoded (colour-science) to
linear and scaled to a sampled mean luminance: the lighting of the head is not matched
to them. The photos are 8-bit, so decoding is a 256-entry table (:func:`srgb_decode8`,
kept on disk: importing colour-science costs 1.1-2.8 s of a dataset's first sample).
"""

from __future__ import annotations

import contextlib
import os
from functools import lru_cache
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from hack_render.errors import HackError
from hack_render.io import atomic_path

#: name -> (file in skimage/data, credit and licence as scikit-image documents them)
PHOTOS: dict[str, tuple[str, str]] = {
    "chelsea": ("chelsea.png", "Stefan van der Walt; CC0"),
    "coffee": ("coffee.png", "Rachel Michetti, courtesy of Pikolo Espresso Bar; CC0"),
    "rocket": ("rocket.jpg", "SpaceX, launch of DSCOVR on Falcon 9; public domain"),
    "hubble_deep_field": ("hubble_deep_field.jpg", "NASA, Hubble Telescope; public domain"),
    "brick": ("brick.png", "CC0Textures Bricks25; CC0 (greyscale)"),
    "grass": ("grass.png", "CC0Textures Grass; CC0 (greyscale)"),
    "gravel": ("gravel.png", "CC0Textures Gravel04; CC0 (greyscale)"),
}
SOURCES = ("photos", "environment")


def _data_dir():
    try:
        import skimage
    except ImportError as err:
        raise HackError(f"dataset background photos: expected scikit-image (its sample "
                        f"photos), found it unavailable ({err}). `pip install scikit-image` "
                        "or set background.source: environment.") from err
    return Path(skimage.__file__).parent / "data"


#: File name of :func:`srgb_decode8`'s disk cache (version in the name).
SRGB_DECODE_CACHE = "srgb_decode8-v1.npy"


@lru_cache(maxsize=1)
def srgb_decode8() -> np.ndarray:
    """(256,) float64: colour-science's sRGB decoding of k / 255 for the 8-bit codes k.

    Computed once and kept in ``$XDG_CACHE_HOME/hack-render`` (or ``~/.cache``); a missing,
    unreadable or malformed file is recomputed (a read-only cache: every time)."""
    path = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "hack-render" \
        / SRGB_DECODE_CACHE
    try:
        t = np.load(path, allow_pickle=False)
        if (t.shape == (256,) and t.dtype == np.float64 and t[0] == 0.0 and t[-1] == 1.0
                and np.all(np.diff(t) > 0)):
            return t
    except (OSError, ValueError):
        pass
    import colour

    t = np.asarray(colour.cctf_decoding(np.arange(256) / 255.0, function="sRGB"), np.float64)
    # a cache that cannot be written: no cache
    with contextlib.suppress(OSError, HackError), atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, t)
    return t


@lru_cache(maxsize=len(PHOTOS))
def photo(name: str) -> np.ndarray:
    """(h, w, 3) float32 linear Rec.709 of a shipped photo, mean luminance 1."""

    if name not in PHOTOS:
        raise HackError(f"background photo: expected one of {', '.join(PHOTOS)}, found "
                        f"{name!r}.")
    path = _data_dir() / PHOTOS[name][0]
    if not path.is_file():
        raise HackError(f"background photo {name!r}: expected {path} (shipped with "
                        "scikit-image), found no file. Reinstall scikit-image or set "
                        "background.source: environment.")
    img = np.asarray(iio.imread(path))
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.dtype == np.uint8:
        lin = srgb_decode8()[img[..., :3]]
    else:  # not a shipped photo's format: decode it directly
        import colour

        lin = colour.cctf_decoding(img[..., :3] / float(np.iinfo(img.dtype).max),
                                   function="sRGB")
    lum = lin @ np.array([0.2126, 0.7152, 0.0722])
    return (lin / max(float(lum.mean()), 1e-6)).astype(np.float32)


def sample_background(cfg: dict, rng: np.random.Generator) -> dict:
    """The background of one sample (JSON-ready): a photo with its crop (centre u, v in
    [0, 1] of the free range, side as a fraction of the photo's short side), a mirror
    flag and the mean luminance; or the rig's environment."""
    c = cfg["background"]
    if c["source"] == "environment":
        return {"source": "environment"}
    names = list(PHOTOS) if c["photos"] == "all" else list(c["photos"])
    return {"source": "photo", "name": names[int(rng.integers(0, len(names)))],
            "crop": [float(rng.random()), float(rng.random()), float(rng.uniform(*c["crop"]))],
            "mirror": bool(rng.random() < 0.5),
            "luminance": float(np.exp(rng.uniform(*np.log(c["luminance"]))))}


def background_image(spec: dict, width: int, height: int) -> np.ndarray | None:
    """(H, W, 3) float32 linear background of a sample spec's ``background``; None for
    the environment. The crop keeps the image's aspect; resampled with area averaging."""
    if spec["source"] == "environment":
        return None
    img = photo(spec["name"])
    h, w = img.shape[:2]
    u, v, side = spec["crop"]
    ch = max(2, round(min(h, w) * side))
    cw = max(2, min(w, round(ch * width / height)))
    ch = max(2, min(h, round(cw * height / width)))
    y0, x0 = round(v * (h - ch)), round(u * (w - cw))
    crop = img[y0:y0 + ch, x0:x0 + cw]
    if spec["mirror"]:
        crop = crop[:, ::-1]
    out = resize_linear(crop, height, width)
    return (out * spec["luminance"]).astype(np.float32)


def resize_linear(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W, C) float image resampled to (height, width, C): scikit-image's
    ``transform.resize(img, (height, width), order=1, anti_aliasing=True,
    preserve_range=True)`` (0.26), the same SciPy calls with the same arguments, so the
    same bits, without importing ``skimage.transform`` (~0.3 s at a dataset's first
    sample: it loads scipy.spatial and scipy.linalg)."""
    from scipy import ndimage

    if img.dtype.char not in "df":
        img = img.astype(float)
    out_shape = (int(height), int(width), *img.shape[2:])
    factors = np.divide(img.shape, out_shape)
    # anti-aliasing: a Gaussian of sigma (factor - 1) / 2 per axis; skimage's 'reflect'
    # is ndimage's 'mirror'
    filtered = ndimage.gaussian_filter(img, np.maximum(0, (factors - 1) / 2), cval=0,
                                       mode="mirror")
    out = ndimage.zoom(filtered, [1 / f for f in factors], order=1, mode="mirror", cval=0,
                       grid_mode=True)
    # clipped to the input's range (higher orders overshoot; kept for the same bits)
    np.clip(out, np.asarray(np.min(img)), np.asarray(np.max(img)), out=out)
    return out


def check_background_config(cfg: dict, fail) -> None:
    """Validate ``cfg['background']``; ``fail(key, expected, found)`` raises."""
    c = cfg["background"]
    if not isinstance(c["source"], str) or c["source"] not in SOURCES:
        fail("background.source", f"one of {', '.join(SOURCES)}", c["source"])
    photos = c["photos"]
    if photos != "all" and (not isinstance(photos, list) or not photos
                            or any(not isinstance(p, str) or p not in PHOTOS for p in photos)):
        fail("background.photos", f"'all' or a non-empty list of {', '.join(PHOTOS)}", photos)
    for key, lo, hi in (("crop", 0.05, 1.0), ("luminance", 1e-4, 100.0)):
        v = c[key]
        if (not isinstance(v, (list, tuple)) or len(v) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                or not lo <= v[0] <= v[1] <= hi):
            fail(f"background.{key}", f"[min, max] with {lo} <= min <= max <= {hi}", v)
