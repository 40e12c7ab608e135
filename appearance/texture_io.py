"""Texture IO: EXR through OpenEXR, PNG (8/16-bit) with explicit sRGB coding, texture sets.

- EXR: float32 or half, any number of channels, channel names kept. ``write_exr`` then
  ``read_exr`` round-trips float32 data bit for bit (and half data after its rounding).
- PNG: 8 or 16-bit through imageio; colour data (diffuse albedo, previews) is
  sRGB-encoded with colour-science's IEC 61966-2-1 transfer function; data maps
  (specular, roughness) are stored linearly; normal maps as (n + 1) / 2.
- Texture set folder layout (one folder per subject), atlas images (H, 2H), row 0 = v 1::

      SUBJECT/diffuse.exr|png     3 channels, linear Rec.709 (PNG: sRGB-encoded)
      SUBJECT/specular.exr|png    1 channel, intensity in [0, 1] (scale of F0 = 0.028)
      SUBJECT/normal.exr|png      3 channels, tangent space, OpenGL +Y (PNG: (n+1)/2)
      SUBJECT/roughness.exr|png   optional, 1 channel, perceptual roughness

Every write goes to a temporary name in the destination folder and is renamed into
place, so an interrupted run never leaves a half-written file.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import OpenEXR
import png as pypng

from appearance.colour_space import srgb_decode, srgb_encode
from hack_render.errors import HackError
from hack_render.io import atomic_path
from hack_render.io.image import write_openexr

MAP_CHANNELS = {"diffuse": 3, "specular": 1, "roughness": 1, "normal": 3}
REQUIRED_MAPS = ("diffuse", "specular", "normal")
EXTENSIONS = (".exr", ".png")
_DEFAULT_NAMES = {1: ["Y"], 2: ["X", "Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}


def write_exr(path, image: np.ndarray, channels: list[str] | None = None,
              half: bool = False) -> None:
    """Write an (H, W) or (H, W, C) array to EXR (float32, or half if ``half``).

    Args:
        channels: names, one per channel (default Y / R,G,B / R,G,B,A).
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3:
        raise HackError(f"{path}: expected an (H, W) or (H, W, C) image, found shape "
                        f"{img.shape}.")
    names = channels or _DEFAULT_NAMES.get(img.shape[2]) or [f"C{i}" for i in range(img.shape[2])]
    if len(names) != img.shape[2]:
        raise HackError(f"{path}: expected {img.shape[2]} channel names, found {names}.")
    dt = np.float16 if half else np.float32
    chans = {n: np.ascontiguousarray(img[..., i].astype(dt)) for i, n in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, chans) as f:
        write_openexr(f, tmp, path)


def read_exr(path) -> tuple[np.ndarray, list[str]]:
    """Read an EXR: (H, W, C) array (float32 or float16 as stored) and channel names.

    Channels come in file order for RGBA-like names (R, G, B, A first), else sorted.
    """
    path = Path(path)
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            ch = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
    except Exception as exc:  # OpenEXR raises plain Exceptions for non-EXR files
        raise HackError(f"{path}: expected a readable OpenEXR image, found an unreadable "
                        f"file ({exc}). Re-export it as EXR.") from exc
    order = {"R": 0, "G": 1, "B": 2, "A": 3, "X": 0, "Y": 1, "Z": 2}
    names = sorted(ch, key=lambda n: (order.get(n.split(".")[-1], 9), n))
    arrays = [ch[n] for n in names]
    if any(a.ndim != 2 for a in arrays):
        raise HackError(f"{path}: expected scalar channels, found {[a.shape for a in arrays]}.")
    dt = np.result_type(*[a.dtype for a in arrays])
    return np.stack([a.astype(dt) for a in arrays], -1), names


def write_png(path, image: np.ndarray, bits: int = 8, srgb: bool = True) -> None:
    """Write a [0, 1] float image as 8 or 16-bit PNG, sRGB-encoded if ``srgb``."""
    if bits not in (8, 16):
        raise HackError(f"{path}: PNG bit depth expected 8 or 16, found {bits}.")
    img = np.clip(np.asarray(image, np.float64), 0.0, 1.0)
    if srgb:
        img = srgb_encode(img)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    top = 255 if bits == 8 else 65535
    q = np.round(img * top).astype(np.uint8 if bits == 8 else np.uint16)
    if bits == 16 and q.ndim == 3:
        # Pillow (imageio's PNG plugin here) has no 16-bit RGB mode; pypng does.
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            pypng.Writer(q.shape[1], q.shape[0], greyscale=False, alpha=q.shape[2] == 4,
                         bitdepth=16).write(fh, q.reshape(q.shape[0], -1).tolist())
        return
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, q, extension=".png")


def read_png(path, srgb: bool = True) -> np.ndarray:
    """Read a PNG (1 to 16 bits per channel) as (H, W, C) float32 in [0, 1], sRGB-decoded if ``srgb``.

    pypng reads every PNG flavour (palette, grey, alpha, interlaced) at its true bit depth;
    Pillow would silently reduce 16-bit RGB to 8 bits.
    """
    path = Path(path)
    try:
        width, height, rows, info = pypng.Reader(filename=str(path)).asDirect()
        q = np.vstack([np.asarray(r, np.uint32) for r in rows]).reshape(height, width, info["planes"])
    except Exception as exc:
        raise HackError(f"{path}: expected a readable PNG image, found an unreadable file "
                        f"({exc}). Re-export it as PNG.") from exc
    img = q.astype(np.float64) / (2.0 ** info["bitdepth"] - 1)  # 1..16-bit
    if srgb:
        img = srgb_decode(img)
    return img.astype(np.float32)


def find_map(folder: Path, name: str) -> Path | None:
    """The file for map ``name`` in ``folder`` (``name.exr`` or ``name.png``), or None."""
    hits = [folder / f"{name}{e}" for e in EXTENSIONS if (folder / f"{name}{e}").is_file()]
    if len(hits) > 1:
        raise HackError(f"{folder}: expected one file for map {name!r}, found "
                        f"{[h.name for h in hits]}. Keep only one of them.")
    return hits[0] if hits else None


def read_map(path: Path, name: str) -> np.ndarray:
    """Read one map as (H, W, C) float32 in its physical units, validated.

    Raises:
        HackError naming the file: wrong channel count, non-finite texels, bad shape.
    """
    want = MAP_CHANNELS[name]
    if path.suffix.lower() == ".exr":
        img, _ = read_exr(path)
        img = img.astype(np.float32)
    else:
        img = read_png(path, srgb=(name == "diffuse"))
        if name == "normal":
            img = img * 2.0 - 1.0
    if img.ndim != 3 or img.shape[2] != want:
        raise HackError(f"{path}: map {name!r} expected {want} channel(s), found "
                        f"{img.shape[2] if img.ndim == 3 else img.shape}. Export {name} with "
                        f"{want} channel(s).")
    h, w = img.shape[:2]
    if w != 2 * h:
        raise HackError(f"{path}: map {name!r} expected an atlas of shape (H, 2H) covering "
                        f"u in [0, 2], found {h} x {w}. See docs/model.md (the appearance model) for the layout.")
    return img


def write_map(path: Path, name: str, img: np.ndarray, half: bool = False) -> None:
    """Write one map by extension (EXR float32/half, PNG 16-bit with the coding of ``read_map``)."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        write_exr(path, img, half=half)
    elif name == "normal":
        write_png(path, (np.asarray(img) + 1.0) * 0.5, bits=16, srgb=False)
    else:
        write_png(path, img, bits=16, srgb=(name == "diffuse"))


def read_texture_set(folder) -> dict[str, np.ndarray]:
    """Read a subject folder: {"diffuse", "specular", "normal"[, "roughness"]} arrays.

    Raises:
        HackError naming the folder and file for missing maps, mismatched resolutions,
        wrong channel counts, NaN/Inf texels or unreadable files.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise HackError(f"{folder}: expected a subject folder with diffuse/specular/normal "
                        f"maps, found no folder.")
    out, shape = {}, None
    for name in MAP_CHANNELS:
        p = find_map(folder, name)
        if p is None:
            if name in REQUIRED_MAPS:
                raise HackError(f"{folder}: expected map {name}.exr or {name}.png, found "
                                f"none (files: {sorted(x.name for x in folder.iterdir())}).")
            continue
        img = read_map(p, name)
        if shape is not None and img.shape[:2] != shape[1]:
            raise HackError(f"{p}: expected the resolution of {shape[0]} "
                            f"({shape[1][0]} x {shape[1][1]}), found {img.shape[0]} x "
                            f"{img.shape[1]}. Resample all maps of a subject to one size.")
        shape = shape or (p.name, img.shape[:2])
        if not np.all(np.isfinite(img)):
            bad = np.argwhere(~np.isfinite(img))[0]
            raise HackError(f"{p}: expected finite texels, found NaN/Inf (first at row "
                            f"{bad[0]}, column {bad[1]}). Fill or inpaint them.")
        out[name] = img
    return out


def write_texture_set(folder, maps: dict[str, np.ndarray], fmt: str = "exr") -> list[Path]:
    """Write maps to ``folder`` as ``name.exr`` (float32) or ``name.png`` (16/8-bit).

    All maps are validated before the first file is written; each file is written
    atomically. Returns the written paths.
    """
    if fmt not in ("exr", "png"):
        raise HackError(f"texture format: expected 'exr' or 'png', found {fmt!r}.")
    h = None
    for name, img in maps.items():
        if name not in MAP_CHANNELS:
            raise HackError(f"texture set: expected maps {list(MAP_CHANNELS)}, found {name!r}.")
        if img.ndim != 3 or img.shape[2] != MAP_CHANNELS[name] or img.shape[1] != 2 * img.shape[0]:
            raise HackError(f"texture set map {name!r}: expected shape (H, 2H, "
                            f"{MAP_CHANNELS[name]}), found {img.shape}.")
        if h is not None and img.shape[0] != h:
            raise HackError(f"texture set map {name!r}: expected height {h}, found {img.shape[0]}.")
        h = img.shape[0]
        if not np.all(np.isfinite(img)):
            raise HackError(f"texture set map {name!r}: expected finite values, found NaN/Inf.")
    folder = Path(folder)
    paths = []
    for name, img in maps.items():
        p = folder / f"{name}.{fmt}"
        write_map(p, name, img)
        paths.append(p)
    return paths
