"""Image files: linear float32 EXR with named channels, sRGB PNG with an explicit tone map.

No Mitsuba here: OpenEXR writes and reads EXR, colour-science encodes sRGB, imageio
writes PNG. Every writer goes through :func:`hack_render.io.atomic_path` (a temporary name
in the target folder, renamed when complete), so an interrupted run never leaves a
half-written file.
"""

from __future__ import annotations

import errno
import os
import shutil
from functools import lru_cache
from pathlib import Path

import imageio.v3 as iio  # 0.03 s after NumPy
import numpy as np
import OpenEXR  # 0.005 s

from hack_render.errors import HackError
from hack_render.io import atomic_path

TONE_MAPS = ("clip", "reinhard", "aces")


def write_exr(path: str | Path, channels: dict[str, np.ndarray],
              metadata: dict[str, str] | None = None) -> Path:
    """Write named float32 channels to an EXR (ZIP compressed, scanline).

    Args:
        channels: name -> (H, W) array, e.g. ``{"R": r, "G": g, "B": b, "depth.Z": z}``.
            All the same (H, W); converted to float32.
        metadata: extra string attributes for the header (e.g. camera matrices as text).
    """
    shapes = {k: np.shape(v) for k, v in channels.items()}
    if not channels or len(set(shapes.values())) != 1 or len(next(iter(shapes.values()))) != 2:
        raise HackError(f"EXR channels: expected equal (H, W) arrays, found shapes {shapes}.")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        header[k] = str(v)
    with atomic_path(path) as tmp:
        write_openexr(OpenEXR.File(header, data), tmp, path)
    return Path(path)


#: what OpenEXR's RuntimeError says of an OS error while writing, and that error's number
_OS_ERRORS_IN_OPENEXR = (("No space left on device", errno.ENOSPC),
                         ("Disk quota exceeded", errno.EDQUOT),
                         ("Read-only file system", errno.EROFS),
                         ("Permission denied", errno.EACCES))


def write_openexr(exr_file, tmp: str | Path, path: str | Path) -> None:
    """``exr_file.write(tmp)``, with OpenEXR's RuntimeError for a full disk (or a quota, a
    read-only or unwritable folder) raised as the OSError it is, naming ``path``, so that
    the command line ends in one line and exit 2 rather than a traceback."""
    try:
        exr_file.write(str(tmp))
    except RuntimeError as err:
        for text, number in _OS_ERRORS_IN_OPENEXR:
            if text in str(err):
                raise OSError(number, os.strerror(number), str(path)) from err
        raise
    # OpenEXR says nothing when the disk fills while it flushes its last buffer: it leaves
    # an empty or cut file. On an all but full disk, read the file back before keeping it.
    if os.path.getsize(tmp) == 0 or shutil.disk_usage(Path(tmp).parent).free < FULL_DISK_BYTES:
        try:
            with OpenEXR.File(str(tmp), separate_channels=True) as back:
                whole = os.path.getsize(tmp) > 0 and all(
                    c.pixels is not None for c in back.channels().values())
        except Exception:  # noqa: BLE001 - unreadable: cut short
            whole = False
        if not whole:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


#: free bytes under which a file a library wrote without an error is read back
FULL_DISK_BYTES = 1 << 20


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Read every channel of an EXR as name -> (H, W) float32."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"{path}: EXR file not found. Check the path.")
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
    except Exception as err:  # OpenEXR raises plain RuntimeError/IOError
        raise HackError(f"{path}: expected a readable OpenEXR file, found an error "
                        f"({err}). Re-export it as .exr.") from err
    return {k: np.asarray(c.pixels, dtype=np.float32) for k, c in f.channels().items()}


def rgb_channels(image: np.ndarray, prefix: str = "") -> dict[str, np.ndarray]:
    """(H, W, 3) -> {"R", "G", "B"} (with an optional layer prefix such as ``"albedo."``)."""
    return {f"{prefix}{c}": image[..., i] for i, c in enumerate("RGB")}


def tone_map(linear: np.ndarray, exposure: float = 0.0, operator: str = "aces") -> np.ndarray:
    """Linear Rec.709 radiance -> display-referred linear values in [0, 1].

    Args:
        linear: (..., 3) scene-referred linear RGB.
        exposure: stops; the image is multiplied by 2**exposure first.
        operator: ``clip`` (plain clamp), ``reinhard`` (x / (1 + x) on each channel) or
            ``aces`` (Narkowicz's fit of the ACES filmic curve), the default.
    """
    if operator not in TONE_MAPS:
        raise HackError(f"tone map: expected one of {', '.join(TONE_MAPS)}, found "
                        f"{operator!r}.")
    x = np.maximum(np.asarray(linear, dtype=np.float64), 0.0) * 2.0 ** exposure
    if operator == "reinhard":
        x = x / (1.0 + x)
    elif operator == "aces":
        x = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)
    return np.clip(x, 0.0, 1.0)


#: Cache file of the sRGB 8-bit decision thresholds (computed once by colour-science).
SRGB8_CACHE = "srgb8_thresholds_v1.npy"


def _cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "hack-render"


@lru_cache(maxsize=1)
def srgb8_thresholds() -> np.ndarray:
    """(255,) display-linear values where the 8-bit sRGB code steps from k - 1 to k:
    colour-science's sRGB decoding of (k - 0.5) / 255. Computed once and cached on disk
    (importing colour-science costs about 1.3 CPU s, more than the rest of a PNG write);
    recomputed when the cache is missing, unreadable or not what it should be."""
    path = _cache_dir() / SRGB8_CACHE
    try:
        t = np.load(path, allow_pickle=False)
        if t.shape == (255,) and t.dtype == np.float64 and np.all(np.diff(t) > 0):
            return t
    except (OSError, ValueError):
        pass
    import colour

    t = np.asarray(colour.cctf_decoding((np.arange(1, 256) - 0.5) / 255.0, function="sRGB"),
                   np.float64)
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.save(f, t)
    except (OSError, HackError):
        pass  # a read-only cache: compute again next time
    return t


def to_srgb8(linear: np.ndarray, exposure: float = 0.0, operator: str = "aces") -> np.ndarray:
    """Tone map, then encode with the sRGB transfer function to uint8: the code k whose
    interval [decode((k - 0.5) / 255), decode((k + 0.5) / 255)) holds the value, i.e.
    round(255 encode(x)) with colour-science's encoding (:func:`srgb8_thresholds`)."""
    display = tone_map(linear, exposure, operator)
    return np.searchsorted(srgb8_thresholds(), display, side="right").astype(np.uint8)


def write_png(path: str | Path, linear: np.ndarray, exposure: float = 0.0,
              operator: str = "aces") -> Path:
    """Write a linear (H, W, 3) image as an sRGB PNG through :func:`to_srgb8`."""
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, to_srgb8(linear, exposure, operator), extension=".png")
    return Path(path)


def read_hdr_image(path: str | Path) -> np.ndarray:
    """Read a lat-long environment map (.exr or Radiance .hdr) as (H, W, 3) float32 linear.

    Raises:
        HackError: missing or unreadable file, wrong format or shape, non-finite values.
    """
    path = Path(path)
    if not path.is_file():
        raise HackError(f"{path}: environment map not found. Pass an existing lat-long "
                        ".exr or .hdr file.")
    suffix = path.suffix.lower()
    if suffix == ".exr":
        ch = read_exr(path)
        if not all(c in ch for c in "RGB"):
            raise HackError(f"{path}: expected R, G, B channels, found {sorted(ch)}.")
        img = np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    elif suffix == ".hdr":
        try:
            img = np.asarray(iio.imread(path), dtype=np.float32)[..., :3]
        except Exception as err:
            raise HackError(f"{path}: expected a readable Radiance .hdr file, found an "
                            f"error ({err}).") from err
    else:
        raise HackError(f"{path}: expected an environment map in .exr or .hdr format, "
                        f"found {suffix or 'no suffix'}. Convert it to EXR.")
    if img.ndim != 3 or img.shape[0] < 2 or img.shape[1] != 2 * img.shape[0]:
        raise HackError(f"{path}: expected a lat-long map twice as wide as high, found "
                        f"shape {img.shape}.")
    if not np.all(np.isfinite(img)):
        raise HackError(f"{path}: expected finite radiance values, found NaN or Inf.")
    return img.astype(np.float32)


def straight_colour(premultiplied: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W, 3) straight (not premultiplied) colour of a render over a transparent
    background: colour / alpha where the pixel is mostly covered (alpha >= 0.5); at the
    silhouette's thin edge, where that division amplifies the samples' noise into
    saturated specks (a pixel at alpha 0.001 became pure red), the nearest mostly
    covered pixel's colour (edge padding, as texture tools do); 0 where alpha is 0."""
    from scipy.ndimage import distance_transform_edt

    solid = alpha >= 0.5
    rgb = premultiplied / np.maximum(alpha, 1e-6)[..., None]
    if solid.any() and not solid.all():
        iy, ix = distance_transform_edt(~solid, return_distances=False, return_indices=True)
        rgb = np.where(solid[..., None], rgb, rgb[iy, ix])
    return np.where((alpha > 0)[..., None], rgb, 0.0)


def sample_bilinear(img: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """An image (H, W) or (H, W, C) at fractional pixel coordinates (Q,) each, pixel
    centres at integers, clamped at the borders: (Q,) or (Q, C)."""
    h, w = img.shape[:2]
    c0 = np.clip(np.floor(col).astype(np.int64), 0, w - 1)
    r0 = np.clip(np.floor(row).astype(np.int64), 0, h - 1)
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    fc, fr = np.clip(col - c0, 0, 1), np.clip(row - r0, 0, 1)
    if img.ndim == 3:
        fc, fr = fc[:, None], fr[:, None]
    top = img[r0, c0] * (1 - fc) + img[r0, c1] * fc
    bot = img[r1, c0] * (1 - fc) + img[r1, c1] * fc
    return top * (1 - fr) + bot * fr
