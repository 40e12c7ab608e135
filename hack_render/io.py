"""Files, on the ground floor: atomic writes (bytes, text, JSON, ``.npz`` arrays, anything
a writer puts at a path), linear float32 EXR with named channels, sRGB PNG with an explicit
tone map.

Every package writes its files through :func:`atomic_path`: the data goes to a temporary
name in the target folder, which is renamed over the target only when it is complete, so
an interrupted run (Ctrl-C, a kill, a full disk) never leaves a half-written file, and a
failed write leaves no temporary. A temporary is named ``.tmp-<tag>-<random><suffix>``
(the tag: 6 hex digits of the target's name, :func:`temp_glob`; the target's suffix, so
writers that choose a format by suffix still do): short, so any legal file name (255
bytes) can be written, and recognisable, so what a killed run left can be removed
(:data:`TEMP_GLOB`, :func:`hack_render.boundary.clean_temporaries`).

No Mitsuba here: OpenEXR writes and reads EXR, colour-science encodes sRGB, imageio
writes PNG. Imports nothing of the project but :mod:`hack_render.errors`.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

import imageio.v3 as iio  # 0.03 s after NumPy
import numpy as np
import OpenEXR  # 0.005 s

from hack_render.errors import HackError

TONE_MAPS = ("clip", "reinhard", "aces")

#: How every temporary of :func:`atomic_path` begins, and the pattern of them all.
TEMP_PREFIX = ".tmp-"
TEMP_GLOB = TEMP_PREFIX + "*"

# a target suffix longer than this is left off the temporary (no real format has one)
_MAX_SUFFIX = 32


# ------------------------------------------------------------------------ atomic writes


def _writable_folder(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise HackError(f"{folder}: expected a folder the output can be written to, found "
                        f"it cannot be created ({err.strerror}). Choose another output "
                        "path with -o.") from err
    if not os.access(folder, os.W_OK | os.X_OK):
        raise HackError(f"{folder}: expected a writable output folder, found it is not "
                        "writable. Choose another output path with -o or fix its "
                        "permissions.")


def check_writable(path: str | Path) -> Path:
    """Create ``path``'s folder if needed and check that files can be written there
    (``path`` itself is taken for the folder when it has no suffix).

    Raises:
        HackError: naming the folder and the fix, before any rendering is done.
    """
    path = Path(path)
    _writable_folder(path.parent if path.suffix else path)
    return path


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# read once, at import: os.umask can only be read by setting it, which would race with
# files created meanwhile by other threads (the dataset's writer thread)
_UMASK = _read_umask()


def _tag(name: str) -> str:
    return hashlib.sha256(name.encode("utf-8", "surrogateescape")).hexdigest()[:6]


def temp_glob(path: str | Path) -> str:
    """The glob pattern, in ``path``'s folder, of the temporaries :func:`atomic_path`
    makes for ``path`` (and for no other name, short of a 24-bit hash collision): what a
    killed writer of ``path`` may have left, safe to remove in a folder that other
    writers share (before the next write of ``path``, under its lock)."""
    return f"{TEMP_PREFIX}{_tag(Path(path).name)}-*"


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); rename it over ``path`` when
    the block completes. The folder is created if needed (:func:`check_writable`'s
    checks); the file gets the permissions the umask gives any new file; on an error or
    an interruption the temporary is removed and ``path`` is left as it was.

    Raises:
        HackError: the folder cannot be created or is not writable.
    """
    path = Path(path)
    _writable_folder(path.parent)
    suffix = path.suffix if len(path.suffix.encode("utf-8", "surrogateescape")) <= _MAX_SUFFIX \
        else ""
    fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{_tag(path.name)}-", suffix=suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates 0600; an output is an ordinary file, readable as the umask allows
        os.chmod(tmp_path, 0o666 & ~_UMASK)
        tmp_path.replace(path)
    finally:
        try:
            tmp_path.unlink(missing_ok=True)
        except OSError:
            pass  # the error that stopped the write is the one to report


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


def write_json(path: str | Path, obj: Any, indent: int | None = 1, sort_keys: bool = False,
               default: Any = None) -> Path:
    """Write ``obj`` as JSON (``json.dumps`` with these arguments, no final newline)
    atomically (:func:`atomic_path`); returns ``path``."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, sort_keys=sort_keys,
                                              default=default))


def write_npz(path: str | Path, arrays: dict[str, Any], compressed: bool = False) -> Path:
    """Write named arrays as ``.npz`` (``np.savez``, or ``np.savez_compressed``) atomically
    (:func:`atomic_path`); returns ``path``. Written through a file object, so NumPy adds
    no ``.npz`` to a path that lacks it."""
    save = np.savez_compressed if compressed else np.savez
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        save(f, **arrays)
    return Path(path)


# ------------------------------------------------------------------------------- images


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
        OpenEXR.File(header, data).write(str(tmp))
    return Path(path)


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
