"""Colour path and skin optics: colour-science references and physical plausibility."""

import colour
import numpy as np
import pytest

from appearance.colour_space import (
    delta_e2000,
    ita_degrees,
    spectra_to_linear_srgb,
    srgb_decode,
    srgb_encode,
)
from appearance.skin_optics import (
    WAVELENGTHS,
    haemoglobin_absorption,
    skin_albedo,
    skin_reflectance,
)

# X-Rite ColorChecker published sRGB (8-bit, D65) of the two skin patches.
PUBLISHED_SRGB = {"dark skin": (115, 82, 68), "light skin": (194, 150, 130)}


@pytest.mark.parametrize("patch", sorted(PUBLISHED_SRGB))
def test_colorchecker_skin_patches_match_published_srgb(patch):
    sd = colour.SDS_COLOURCHECKERS["BabelColor Average"][patch].copy()
    sd = sd.align(colour.SpectralShape(380, 780, 5))
    rgb = spectra_to_linear_srgb(sd.values, sd.wavelengths)
    ref = srgb_decode(np.asarray(PUBLISHED_SRGB[patch]) / 255.0)
    assert float(delta_e2000(rgb, ref)) < 2.0


def test_srgb_round_trip_and_reference_point():
    x = np.linspace(0, 1, 257)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    # IEC 61966-2-1: linear 0.5 encodes to 0.7354 (188 / 255)
    assert abs(float(srgb_encode(0.5)) - 0.735357) < 1e-5


def test_ita_signs():
    # a light, yellowish skin has a large positive ITA, a very dark one a negative ITA
    assert ita_degrees(np.array([0.55, 0.4, 0.3])) > 40
    assert ita_degrees(np.array([0.08, 0.05, 0.04])) < -30


def test_haemoglobin_soret_peak():
    oxy, deoxy = haemoglobin_absorption(tuple(np.arange(380.0, 781.0, 2.0)))
    wl = np.arange(380.0, 781.0, 2.0)
    assert 410 <= wl[oxy.argmax()] <= 420 and 425 <= wl[deoxy.argmax()] <= 436
    # whole blood at 150 g/L, 414 nm: ln(10) * 524280 * 150 / 64500 / 10 ~ 281 / mm
    assert abs(oxy.max() - 280.7) < 1.0


def test_skin_albedo_physical_and_monotone():
    cm = np.linspace(0.01, 0.5, 20)
    rgb = skin_albedo(cm, 0.02, 0.7)
    assert np.all((rgb > 0) & (rgb < 1))
    assert np.all(np.diff(rgb, axis=0) < 0)  # more melanin, darker in every channel
    from appearance.population import load_calibration

    refl = skin_reflectance(0.05, np.array([0.005, 0.2]), 0.7, load_calibration().optics)
    i560 = np.argmin(np.abs(WAVELENGTHS - 560))
    i660 = np.argmin(np.abs(WAVELENGTHS - 660))
    # blood absorbs green far more than red: relative loss larger at 560 nm
    ratio = refl[1] / refl[0]
    assert ratio[i560] < ratio[i660] < 1.0
