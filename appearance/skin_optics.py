"""Two-layer biophysical skin reflectance (Donner & Jensen 2006 chromophores, Kubelka-Munk).

Spectral absorption (lambda in nm, coefficients per mm, DATA.md):

- epidermis: mu_a,e = C_m [b_m s_em + (1 - b_m) s_pm] + (1 - C_m) s_base, with eumelanin
  s_em = 6.6e10 lambda^-3.33, pheomelanin s_pm = 2.9e13 lambda^-4.75 and the baseline
  s_base = 0.0244 + 8.53 exp(-(lambda - 154) / 66.2);
- dermis: mu_a,d = C_h [g s_oxy + (1 - g) s_deoxy] + (1 - C_h) s_base, g = 0.75, with the
  whole-blood haemoglobin absorption ln(10) eps(lambda) * 150 g/L / 64500 g/mol (Prahl's
  molar extinction eps, ``data/prahl_hemoglobin.json``), converted from 1/cm to 1/mm;
- reduced scattering: epidermis 14.74 lambda^-0.22 + 2.2e11 lambda^-4 (1/mm), dermis half.

Each layer is a Kubelka-Munk slab with K = 2 k_path mu_a (k_path the mean path-length
factor; K = 2 mu_a for diffuse light in KM theory) and S = k_scat mu_s'; the baseline is
scaled by k_base. The epidermis (0.25 mm) lies on a semi-infinite dermis:
R = R_e + T_e^2 R_d / (1 - R_e R_d). Plain constants (k_path = k_scat = k_base = 1) do
not reproduce measured skin; :mod:`appearance.calibrate` fits them (and the population's
chromophore ranges) to measured albedo percentiles, and stores them in
``data/calibration.json``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from appearance.colour_space import spectra_to_linear_srgb

DATA_DIR = Path(__file__).resolve().parent / "data"
WAVELENGTHS = np.arange(380.0, 781.0, 10.0)  # nm; colour integration every 10 nm
HB_MOLAR_MASS = 64500.0  # g/mol
HB_CONCENTRATION = 150.0  # g/L whole blood
EPIDERMIS_MM = 0.25


@dataclass(frozen=True)
class OpticsConstants:
    """Free constants of the reflectance model (fitted by :mod:`appearance.calibrate`).

    Attributes:
        k_path: absorption path-length factor (multiplies mu_a).
        k_scat: scattering scale (multiplies mu_s').
        k_base: baseline absorption scale (multiplies s_base).
        oxygenation: oxygen saturation g of dermal blood.
        epidermis_mm: epidermis thickness, mm.
    """

    k_path: float = 1.0
    k_scat: float = 1.0
    k_base: float = 1.0
    oxygenation: float = 0.75
    epidermis_mm: float = EPIDERMIS_MM


@lru_cache(maxsize=4)
def haemoglobin_absorption(wavelengths: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(oxy, deoxy) whole-blood absorption coefficients in 1/mm at ``wavelengths`` (nm)."""
    tab = json.loads((DATA_DIR / "prahl_hemoglobin.json").read_text())
    wl = np.asarray(wavelengths)
    scale = np.log(10.0) * HB_CONCENTRATION / HB_MOLAR_MASS / 10.0  # 1/cm -> 1/mm
    oxy = np.interp(wl, tab["lambda_nm"], tab["HbO2"]) * scale
    deoxy = np.interp(wl, tab["lambda_nm"], tab["Hb"]) * scale
    return oxy, deoxy


def baseline_absorption(wl: np.ndarray) -> np.ndarray:
    """Baseline skin absorption s_base(lambda), 1/mm."""
    return 0.0244 + 8.53 * np.exp(-(wl - 154.0) / 66.2)


def epidermis_absorption(c_m, b_m, wl, k_base=1.0):
    """(..., L) epidermal absorption, 1/mm, for melanin fraction C_m and eumelanin share b_m."""
    c_m = np.asarray(c_m, np.float64)[..., None]
    b_m = np.asarray(b_m, np.float64)[..., None]
    s_em = 6.6e10 * wl ** -3.33
    s_pm = 2.9e13 * wl ** -4.75
    return c_m * (b_m * s_em + (1 - b_m) * s_pm) + (1 - c_m) * k_base * baseline_absorption(wl)


def dermis_absorption(c_h, wl, oxygenation=0.75, k_base=1.0):
    """(..., L) dermal absorption, 1/mm, for blood volume fraction C_h."""
    c_h = np.asarray(c_h, np.float64)[..., None]
    oxy, deoxy = haemoglobin_absorption(tuple(float(w) for w in wl))
    blood = oxygenation * oxy + (1 - oxygenation) * deoxy
    return c_h * blood + (1 - c_h) * k_base * baseline_absorption(wl)


def reduced_scattering(wl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(epidermis, dermis) reduced scattering coefficients mu_s', 1/mm."""
    epi = 14.74 * wl ** -0.22 + 2.2e11 * wl ** -4.0
    return epi, 0.5 * epi


def km_layer(k: np.ndarray, s: np.ndarray, d: float | None):
    """Kubelka-Munk reflectance and transmittance of a slab (thickness d, None = infinite)."""
    a = 1.0 + k / s
    b = np.sqrt(a * a - 1.0)
    if d is None:
        return a - b, np.zeros_like(a)
    bsd = b * s * d
    den = a * np.sinh(bsd) + b * np.cosh(bsd)
    return np.sinh(bsd) / den, b / den


def skin_reflectance(c_m, c_h, b_m, const: OpticsConstants = OpticsConstants(),
                     wl: np.ndarray = WAVELENGTHS) -> np.ndarray:
    """(..., L) diffuse reflectance spectra of two-layer skin.

    Args:
        c_m, c_h, b_m: broadcastable arrays: melanin fraction, blood fraction, eumelanin share.
    """
    mu_e = epidermis_absorption(c_m, b_m, wl, const.k_base)
    mu_d = dermis_absorption(c_h, wl, const.oxygenation, const.k_base)
    sp_e, sp_d = reduced_scattering(wl)
    r_e, t_e = km_layer(2 * const.k_path * mu_e, const.k_scat * sp_e, const.epidermis_mm)
    r_d, _ = km_layer(2 * const.k_path * mu_d, const.k_scat * sp_d, None)
    r_e, t_e, r_d = np.broadcast_arrays(r_e, t_e, r_d)
    return r_e + t_e ** 2 * r_d / (1.0 - r_e * r_d)


def skin_albedo(c_m, c_h, b_m, const: OpticsConstants = OpticsConstants()) -> np.ndarray:
    """(..., 3) linear sRGB diffuse albedo (D65, CIE 1931 2 degree) of two-layer skin."""
    return spectra_to_linear_srgb(skin_reflectance(c_m, c_h, b_m, const), WAVELENGTHS)


@dataclass(frozen=True)
class AlbedoLUT:
    """Albedo on a regular grid in (sqrt C_m, sqrt C_h, b_m), trilinearly interpolated.

    The generator evaluates millions of texels; the spectral model is evaluated once on
    the grid (sqrt spacing: skin colour changes fastest at low concentrations).
    """

    sqrt_cm: np.ndarray
    sqrt_ch: np.ndarray
    bm: np.ndarray
    rgb: np.ndarray  # (Nm, Nh, Nb, 3)

    @staticmethod
    def build(const: OpticsConstants, n_m: int = 48, n_h: int = 40, n_b: int = 6,
              cm_max: float = 0.6, ch_max: float = 0.4) -> AlbedoLUT:
        sm = np.linspace(0.0, np.sqrt(cm_max), n_m)
        sh = np.linspace(0.0, np.sqrt(ch_max), n_h)
        bm = np.linspace(0.4, 0.9, n_b)
        g = np.meshgrid(sm ** 2, sh ** 2, bm, indexing="ij")
        return AlbedoLUT(sm, sh, bm, skin_albedo(*g, const).astype(np.float32))

    def __call__(self, c_m, c_h, b_m) -> np.ndarray:
        """(..., 3) albedo for arrays of C_m, C_h, b_m (clamped to the grid)."""
        from scipy.ndimage import map_coordinates

        def idx(v, grid):
            return np.clip((v - grid[0]) / (grid[1] - grid[0]), 0, len(grid) - 1)

        c = np.stack([idx(np.sqrt(np.clip(c_m, 0, None)), self.sqrt_cm),
                      idx(np.sqrt(np.clip(c_h, 0, None)), self.sqrt_ch),
                      idx(np.asarray(b_m, np.float64), self.bm)])
        flat = c.reshape(3, -1)
        out = np.stack([map_coordinates(self.rgb[..., k], flat, order=1, mode="nearest")
                        for k in range(3)], -1)
        return out.reshape(np.shape(c_m) + (3,)).astype(np.float32)


def constants_dict(const: OpticsConstants) -> dict:
    return asdict(const)
