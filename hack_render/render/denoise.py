"""Denoising renders with Intel Open Image Denoise (PyPI ``pyoidn``, the ``denoise`` extra).

OIDN's ``RT`` filter takes the noisy linear colour with two auxiliary images of the same
pixel footprint, albedo and normal (:func:`hack_render.render.footprint.denoise_features`:
k x k primary rays per pixel, box-averaged, looking through the lights like the camera
and through the lash cards' gaps like the film; on the hair strands the hair's calibrated
colour and the direction to the camera, smooth from strand to strand), which keep edges
and texture sharp. OIDN expects noise that is independent from pixel to pixel: a render
to denoise uses the box pixel filter (``render.cli.denoise_settings``); from Mitsuba's
Gaussian filter, which spreads each sample over neighbouring pixels, OIDN keeps the
correlated noise as detail (on the hair most of all: docs/hair.md, "Against Blender
Cycles"). It runs on the premultiplied subject (the film
without a backdrop), so a backdrop or photo composited afterwards is not blurred.

``pyoidn`` installs about 170 MB of shared libraries (OIDN's CPU, CUDA, HIP and SYCL
devices), so it is an extra: ``pip install 'hack-render[denoise]'``. Where it is missing
or fails, :func:`resolve` and :func:`denoise` either refuse with a message naming the
extra (mode ``on``) or fall back to the noisy image with a warning (mode ``auto``).
"""

from __future__ import annotations

import sys
import warnings

import numpy as np

from hack_render.errors import HackError

EXTRA = "denoise"
INSTALL_HINT = "pip install 'hack-render[denoise]'  (Intel Open Image Denoise, PyPI pyoidn)"
MODES = ("auto", "on", "off")
#: OIDN quality: "balanced" took half the time of "high" at the same PSNR to a 2,048-spp
#: reference (37.2 against 37.5 dB, 16 spp, 128 px studio portrait; docs/render.md).
QUALITY = "balanced"


class DenoiserUnavailable(HackError):
    """pyoidn is not installed or failed to load."""


class DenoiserWarning(UserWarning):
    """The noisy image is kept because the denoiser is missing or failed."""


def _import_pyoidn():
    """``import pyoidn``, without torch where torch is not loaded yet: pyoidn imports it
    (1.1 CPU s) only to accept torch tensors, and this module passes it NumPy arrays. A
    render of a cached pose so never loads torch (docs/render.md, "Fixed cost")."""
    if "torch" in sys.modules or "pyoidn" in sys.modules:
        import pyoidn
        return pyoidn
    sys.modules["torch"] = None  # pyoidn's `import torch` raises ImportError: no tensors
    try:
        import pyoidn
    finally:
        if sys.modules.get("torch", 0) is None:
            del sys.modules["torch"]
    return pyoidn


def _load():
    """Import pyoidn; DenoiserUnavailable (naming the extra) when it cannot load."""
    try:
        pyoidn = _import_pyoidn()
    except Exception as err:  # ImportError, or a broken shared library (OSError)
        raise DenoiserUnavailable(
            f"denoiser: expected the Intel Open Image Denoise bindings (pyoidn), found them "
            f"unavailable ({type(err).__name__}: {err}). Install them with {INSTALL_HINT}, "
            "or pass --denoise off (or auto for the noisy image with a warning).") from err
    return pyoidn


def available() -> bool:
    """True when pyoidn imports."""
    try:
        _load()
    except DenoiserUnavailable:
        return False
    return True


def resolve(mode: str) -> bool:
    """Whether to denoise for a user's ``--denoise`` mode: ``off`` never; ``on`` always
    (DenoiserUnavailable, naming the extra, when pyoidn is missing); ``auto`` when pyoidn
    is available, else a DenoiserWarning and the noisy image."""
    if mode not in MODES:
        raise HackError(f"--denoise: expected one of {', '.join(MODES)}, found {mode!r}.")
    if mode == "off":
        return False
    if mode == "on":
        _load()
        return True
    try:
        _load()
    except DenoiserUnavailable as err:
        warnings.warn(f"{err} Keeping the noisy image.", DenoiserWarning, stacklevel=2)
        return False
    return True


def denoise(color: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None, *, fallback: bool = False) -> np.ndarray:
    """Denoise a linear HDR image.

    Args:
        color: (H, W, 3) linear RGB (any non-negative range; premultiplied is fine).
        albedo: (H, W, 3) in [0, 1], noise-free, same pixel footprint; or None.
        normal: (H, W, 3) in [-1, 1], noise-free (world or camera space); or None.
        fallback: on a missing or failing denoiser return ``color`` unchanged with a
            DenoiserWarning instead of raising DenoiserUnavailable.

    Returns:
        (H, W, 3) float32 denoised image.
    """
    color = np.ascontiguousarray(np.maximum(np.nan_to_num(color[..., :3]), 0.0), np.float32)
    aux = {}
    for name, a in (("albedo", albedo), ("normal", normal)):
        if a is None:
            continue
        a = np.asarray(a, np.float32)
        if a.shape != color.shape:
            raise HackError(f"denoiser {name}: expected shape {color.shape}, found {a.shape}.")
        lo, hi = (0.0, 1.0) if name == "albedo" else (-1.0, 1.0)
        aux[name] = np.ascontiguousarray(np.clip(np.nan_to_num(a), lo, hi))
    if "normal" in aux and "albedo" not in aux:
        raise HackError("denoiser: a normal image needs an albedo image too (OIDN).")
    try:
        pyoidn = _load()
        out = pyoidn.denoise(color, aux.get("albedo"), aux.get("normal"), hdr=True,
                             clean_aux=bool(aux), quality=QUALITY)
    except DenoiserUnavailable:
        if not fallback:
            raise
        warnings.warn(f"denoiser unavailable; kept the noisy image. Install it with "
                      f"{INSTALL_HINT}.", DenoiserWarning, stacklevel=2)
        return color
    except Exception as err:  # OIDN reports device/filter failures as RuntimeError
        if not fallback:
            raise DenoiserUnavailable(
                f"denoiser: Intel Open Image Denoise failed ({type(err).__name__}: {err}). "
                f"Reinstall it with {INSTALL_HINT}, or pass --denoise off.") from err
        warnings.warn(f"denoiser failed ({err}); kept the noisy image.", DenoiserWarning,
                      stacklevel=2)
        return color
    return np.asarray(out, np.float32)
