"""Reading photos for fitting: every odd input is converted, resized or refused clearly.

Handled: unreadable or truncated files (refused), grayscale and palette (to RGB), CMYK
(to RGB), 16-bit and float images (scaled to [0, 1]), RGBA / LA (alpha composited over
mid grey), EXIF orientation (applied), huge images (> ``MAX_SIDE_PX``: downscaled, with
a warning). Faces that are too small are refused later, by the detector stage. The EXIF
35 mm-equivalent focal length (tag 0xA405), when a camera wrote one, is kept
(``Photo.focal_mm``): the fitter then centres its focal prior on it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from hack_render.errors import HackError


class PhotoWarning(UserWarning):
    """A photo was converted or resized on the way in."""


#: photos with a side above this (pixels) are downscaled to WORKING_SIDE_PX on reading
MAX_SIDE_PX = 8000
#: the long side a photo over MAX_SIDE_PX is downscaled to (pixels)
WORKING_SIDE_PX = 2048


@dataclass
class Photo:
    """An RGB photo.

    Attributes:
        rgb: (H, W, 3) float32 sRGB-encoded values in [0, 1].
        name: label (file stem). scale: working size / original size (1 unless resized).
        notes: what was converted on the way in.
        focal_mm: the 35 mm-equivalent focal length (36 mm across the long side) when
            known: from EXIF (tag 0xA405, FocalLengthIn35mmFilm) or given by the user;
            ``focal_source`` says which ("exif", "--focal-mm", ...); None: unknown.
    """

    rgb: np.ndarray
    name: str = "photo"
    scale: float = 1.0
    notes: list = field(default_factory=list)
    focal_mm: float | None = None
    focal_source: str = ""

    @property
    def height(self) -> int:
        return self.rgb.shape[0]

    @property
    def width(self) -> int:
        return self.rgb.shape[1]

    @property
    def is_grey(self) -> bool:
        """True for a photo without colour (its three channels equal to 1/255: a grey
        photo, or one converted from grey): the fit then compares luminance only and
        ``render.png`` is grey (the photo says nothing of the skin's colour)."""
        if "_grey" not in self.__dict__:
            self.__dict__["_grey"] = bool(np.ptp(self.rgb, axis=2).max() <= 1.0 / 255)
        return self.__dict__["_grey"]

    def linear(self) -> np.ndarray:
        """(H, W, 3) float32 linear Rec.709 (the inverse sRGB transfer function); a copy of
        the one decoded per ``rgb`` array (the final stage asks for it a dozen times, and
        colour-science's transfer function takes ~0.1 s at 512 px)."""
        import colour

        rgb, lin = self.__dict__.get("_linear", (None, None))
        if rgb is not self.rgb:
            lin = np.asarray(colour.cctf_decoding(self.rgb, function="sRGB"), np.float32)
            self.__dict__["_linear"] = (self.rgb, lin)
        return lin.copy()

    def uint8(self) -> np.ndarray:
        return np.clip(np.round(self.rgb * 255.0), 0, 255).astype(np.uint8)


def _to_float_rgb(arr: np.ndarray, mode: str, notes: list) -> np.ndarray:
    """Any PIL-decoded array to (H, W, 3) float in [0, 1]."""
    a = np.asarray(arr)
    if a.dtype == np.uint8:
        x = a.astype(np.float32) / 255.0
    elif a.dtype in (np.uint16, np.int32, np.int64) or mode.startswith("I"):
        notes.append(f"{mode} {a.dtype} scaled from 16 bits to [0, 1]")
        x = a.astype(np.float32) / 65535.0
    elif a.dtype == bool:
        x = a.astype(np.float32)
    else:
        x = a.astype(np.float32)
        hi = float(np.nanmax(x)) if x.size else 1.0
        if hi > 1.0:
            x = x / hi
    x = np.nan_to_num(np.clip(x, 0.0, 1.0))
    if x.ndim == 2:
        x = np.repeat(x[..., None], 3, axis=2)
    elif x.shape[2] == 2:  # LA
        x = x[..., :1] * x[..., 1:2] + 0.5 * (1 - x[..., 1:2])
        x = np.repeat(x, 3, axis=2)
    elif x.shape[2] == 4:
        notes.append("alpha channel composited over mid grey")
        x = x[..., :3] * x[..., 3:4] + 0.5 * (1.0 - x[..., 3:4])
    return np.ascontiguousarray(x[..., :3], dtype=np.float32)


def load_photo(path: str | Path, max_side: int = MAX_SIDE_PX,
               working_side: int = WORKING_SIDE_PX) -> Photo:
    """Read a photo file into an sRGB float :class:`Photo`, handling odd formats.

    Raises:
        HackError: the file is missing, unreadable, truncated or has no pixels.
    """
    path = Path(path)
    if not path.is_file():
        raise HackError(f"photo {path}: file not found.")
    notes: list[str] = []
    focal_mm = None
    # Pillow's decompression-bomb guard would refuse huge photos before we could resize
    # them; we guard by pixel count ourselves (after reading the header only).
    old = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None
    try:
        with Image.open(path) as im:
            w, h = im.size
            if w * h > 400e6:
                raise HackError(f"photo {path}: expected at most 400 megapixels, found {w}x{h}. "
                                "Downscale it first.")
            if w < 1 or h < 1:
                raise HackError(f"photo {path}: the image has no pixels ({w}x{h}).")
            im.load()
            exif = im.getexif()
            orient = exif.get(0x0112, 1)
            focal_mm = exif_focal_35mm(exif)
            im = ImageOps.exif_transpose(im)
            if orient not in (1, None):
                notes.append(f"EXIF orientation {orient} applied")
            mode = im.mode
            if mode == "CMYK":
                notes.append("CMYK converted to RGB")
                im = im.convert("RGB")
            elif mode in ("P", "PA"):
                notes.append("palette image converted to RGB(A)")
                im = im.convert("RGBA" if "transparency" in im.info or mode == "PA" else "RGB")
            elif mode in ("L", "1"):
                notes.append("grayscale converted to RGB")
            elif mode not in ("RGB", "RGBA", "LA", "I", "I;16", "I;16B", "I;16L", "F"):
                notes.append(f"{mode} converted to RGB")
                im = im.convert("RGB")
            arr = np.asarray(im)
            mode = im.mode
    except HackError:
        raise
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
        what = "truncated or corrupt" if "truncated" in str(err).lower() or isinstance(
            err, (OSError, SyntaxError)) else "not a readable image"
        raise HackError(f"photo {path}: {what} ({err}). Re-export it as PNG or JPEG.") from err
    finally:
        Image.MAX_IMAGE_PIXELS = old
    if arr.dtype != np.uint8 and path.suffix.lower() == ".png" and arr.ndim == 3:
        pass  # Pillow already gave a wide array for 16-bit RGB
    rgb = _to_float_rgb(arr, mode, notes)
    if rgb.ndim == 3 and rgb.shape[2] == 3 and path.suffix.lower() in (".png", ".tif", ".tiff"):
        rgb16 = _maybe_16bit_rgb(path)
        if rgb16 is not None:
            rgb = rgb16
            notes.append("16-bit RGB scaled to [0, 1]")
    photo = Photo(rgb, path.stem, 1.0, notes)
    photo = limit_size(photo, max_side, working_side)
    if focal_mm is not None:  # relative to the frame, so resizing keeps it
        photo.focal_mm, photo.focal_source = focal_mm, "exif"
    for n in photo.notes:
        warnings.warn(f"photo {path.name}: {n}", PhotoWarning, stacklevel=2)
    return photo


def exif_focal_35mm(exif) -> float | None:
    """FocalLengthIn35mmFilm (0xA405, in the Exif sub-IFD 0x8769) of a PIL ``Image.Exif``,
    in mm, or None when absent, zero ("unknown" in the standard) or implausible."""
    try:
        value = exif.get_ifd(0x8769).get(0xA405)
        if value is None:
            value = exif.get(0xA405)
        f = float(value) if value is not None else 0.0
    except (TypeError, ValueError, KeyError, AttributeError):
        return None
    return f if 5.0 <= f <= 2000.0 else None


def _maybe_16bit_rgb(path: Path) -> np.ndarray | None:
    """Pillow reads 16-bit RGB PNGs as 8 bits; imageio keeps the 16 bits (None otherwise)."""
    try:
        a = iio.imread(path)
    except Exception:  # noqa: BLE001 - Pillow already read it; this is a refinement
        return None
    if a.dtype != np.uint16 or a.ndim != 3 or a.shape[2] not in (3, 4):
        return None
    x = a.astype(np.float32) / 65535.0
    if x.shape[2] == 4:
        x = x[..., :3] * x[..., 3:4] + 0.5 * (1.0 - x[..., 3:4])
    return np.ascontiguousarray(x, np.float32)


def limit_size(photo: Photo, max_side: int = MAX_SIDE_PX,
               working_side: int = WORKING_SIDE_PX) -> Photo:
    """Downscale photos with a side above ``max_side`` to ``working_side`` (anti-aliased)."""
    h, w = photo.rgb.shape[:2]
    if max(h, w) <= max_side:
        return photo
    from skimage.transform import resize

    s = working_side / max(h, w)
    rgb = resize(photo.rgb, (max(1, round(h * s)), max(1, round(w * s))), anti_aliasing=True,
                 preserve_range=True).astype(np.float32)
    notes = photo.notes + [(f"{w}x{h} px is above {max_side} px: downscaled to "
                            f"{rgb.shape[1]}x{rgb.shape[0]}")]
    return Photo(rgb, photo.name, photo.scale * s, notes, photo.focal_mm, photo.focal_source)


def from_array(rgb: np.ndarray, name: str = "photo") -> Photo:
    """A :class:`Photo` from an in-memory uint8/float RGB(A)/gray array."""
    a = np.asarray(rgb)
    mode = "L" if a.ndim == 2 else ("RGBA" if a.shape[2] == 4 else "RGB")
    notes: list[str] = []
    return limit_size(Photo(_to_float_rgb(a, mode, notes), name, 1.0, notes))
