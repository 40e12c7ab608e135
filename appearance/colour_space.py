"""Colour conversions used by the appearance model, all through colour-science.

- Spectra (reflectance, 0-1) to CIE XYZ: CIE 1931 2 degree observer, illuminant D65,
  ``colour.msds_to_XYZ`` (integration), result on the 0-100 scale.
- XYZ to linear Rec.709 / sRGB primaries: ``colour.XYZ_to_sRGB(..., apply_cctf_encoding=False)``
  (input scaled to 0-1).
- sRGB transfer function (encoding for 8/16-bit PNG): ``colour.cctf_encoding`` /
  ``colour.cctf_decoding`` with ``function="sRGB"``.
- CIELAB (D65 white), CIEDE2000 and the individual typology angle (ITA) of skin.

colour-science is imported by the functions that convert (it costs 1.3-2.8 s to import,
matplotlib included): importing this module, and the generator through it, is cheap.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


def d65_xy() -> np.ndarray:
    """The D65 white point's CIE 1931 xy chromaticity (colour-science's)."""
    import colour

    return np.asarray(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


@lru_cache(maxsize=8)
def _cmfs_illuminant(start: float, end: float, interval: float):
    import colour

    shape = colour.SpectralShape(start, end, interval)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    return shape, cmfs, ill


def spectra_to_xyz(reflectance: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """Reflectance spectra to CIE XYZ (0-100 scale), CIE 1931 2 degree, D65.

    Args:
        reflectance: (..., L) reflectance in [0, 1] sampled at ``wavelengths``.
        wavelengths: (L,) evenly spaced, nanometres.
    Returns:
        (..., 3) XYZ, Y = 100 for a perfect white.
    """
    import colour

    wl = np.asarray(wavelengths, np.float64)
    step = float(wl[1] - wl[0])
    shape, cmfs, ill = _cmfs_illuminant(float(wl[0]), float(wl[-1]), step)
    r = np.asarray(reflectance, np.float64)
    flat = r.reshape(-1, r.shape[-1])
    xyz = colour.msds_to_XYZ(flat, cmfs=cmfs, illuminant=ill, method="Integration",
                             shape=shape)
    return np.asarray(xyz).reshape(r.shape[:-1] + (3,))


def xyz_to_linear_srgb(xyz: np.ndarray) -> np.ndarray:
    """(..., 3) XYZ on the 0-100 scale to linear sRGB (Rec.709 primaries, D65)."""
    import colour

    return np.asarray(colour.XYZ_to_sRGB(np.asarray(xyz) / 100.0, apply_cctf_encoding=False))


def linear_srgb_to_xyz(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear sRGB to XYZ on the 0-100 scale."""
    import colour

    return 100.0 * np.asarray(colour.sRGB_to_XYZ(np.asarray(rgb), apply_cctf_decoding=False))


def spectra_to_linear_srgb(reflectance: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """(..., L) reflectance spectra to (..., 3) linear sRGB."""
    return xyz_to_linear_srgb(spectra_to_xyz(reflectance, wavelengths))


def linear_srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear sRGB to CIELAB (D65 reference white)."""
    import colour

    return np.asarray(colour.XYZ_to_Lab(linear_srgb_to_xyz(rgb) / 100.0, d65_xy()))


def delta_e2000(rgb_a: np.ndarray, rgb_b: np.ndarray) -> np.ndarray:
    """CIEDE2000 between two (..., 3) linear sRGB arrays."""
    import colour

    return np.asarray(colour.delta_E(linear_srgb_to_lab(rgb_a), linear_srgb_to_lab(rgb_b),
                                     method="CIE 2000"))


def ita_degrees(rgb: np.ndarray) -> np.ndarray:
    """Individual typology angle, arctan((L* - 50) / b*) in degrees, of (..., 3) linear sRGB."""
    lab = linear_srgb_to_lab(rgb)
    return np.degrees(np.arctan2(lab[..., 0] - 50.0, lab[..., 2]))


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear sRGB in [0, 1] to the sRGB-encoded signal (IEC 61966-2-1)."""
    import colour

    return np.asarray(colour.cctf_encoding(np.clip(linear, 0.0, 1.0), function="sRGB"))


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded signal in [0, 1] to linear sRGB."""
    import colour

    return np.asarray(colour.cctf_decoding(np.asarray(encoded, np.float64), function="sRGB"))
