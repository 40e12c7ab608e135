"""The procedural skin population: per-subject chromophore draws and calibrated constants.

A subject's base skin is (C_m, C_h, b_m): melanin volume fraction, dermal blood volume
fraction and eumelanin share. Following DATA.md the fractions are sampled skewed to low
values, C = lo + (hi - lo) u^3 with u ~ U(0, 1); b_m ~ U(b_lo, b_hi). The bounds and the
optics constants (:class:`appearance.skin_optics.OpticsConstants`) are the calibrated
free constants, stored in ``data/calibration.json`` by :mod:`appearance.calibrate`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from appearance.skin_optics import DATA_DIR, AlbedoLUT, OpticsConstants
from hack_render.errors import HackError
from hack_render.io.npz import write_npz

CALIBRATION_FILE = DATA_DIR / "calibration.json"


@dataclass(frozen=True)
class PopulationConstants:
    """Bounds of the per-subject chromophore draws (literature ranges in DATA.md)."""

    cm_lo: float = 0.01
    cm_hi: float = 0.45
    ch_lo: float = 0.01
    ch_hi: float = 0.3
    bm_lo: float = 0.6
    bm_hi: float = 0.75
    skew: float = 3.0


@dataclass(frozen=True)
class Calibration:
    """Optics and population constants, with the fit that produced them."""

    optics: OpticsConstants = OpticsConstants()
    population: PopulationConstants = PopulationConstants()
    fit: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"format": "hack-appearance-calibration", "version": 1,
                "kind": "procedural population constants fitted to measured skin albedo",
                "optics": asdict(self.optics), "population": asdict(self.population),
                "fit": self.fit}

    @staticmethod
    def from_json(d: dict) -> Calibration:
        try:
            return Calibration(OpticsConstants(**d["optics"]),
                               PopulationConstants(**d["population"]), d.get("fit", {}))
        except (KeyError, TypeError) as exc:
            raise HackError(f"calibration file: expected keys optics/population with the "
                            f"dataclass fields, found {sorted(d)} ({exc}). Re-run "
                            f"`python -m appearance.calibrate`.") from exc


@lru_cache(maxsize=2)
def load_calibration(path: str | None = None) -> Calibration:
    """The shipped calibration (``data/calibration.json``) or the one at ``path``."""
    p = Path(path) if path else CALIBRATION_FILE
    if not p.is_file():
        raise HackError(f"calibration: expected {p}, found no file. Run "
                        f"`python -m appearance.calibrate` to create it.")
    return Calibration.from_json(json.loads(p.read_text()))


#: Version of the albedo table's disk cache (bump when AlbedoLUT.build changes).
LUT_CACHE_VERSION = 1


def lut_cache_path(optics: OpticsConstants) -> Path:
    """Where :func:`albedo_lut` keeps the table of these constants (``$XDG_CACHE_HOME`` or
    ``~/.cache``, then ``hack-render/``; one file per set of constants)."""
    key = hashlib.sha256(json.dumps([LUT_CACHE_VERSION, asdict(optics)], sort_keys=True)
                         .encode()).hexdigest()[:16]
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return root / "hack-render" / f"albedo_lut-{key}.npz"


@lru_cache(maxsize=4)
def albedo_lut(optics: OpticsConstants) -> AlbedoLUT:
    """The albedo look-up table for these optics constants.

    Kept in memory and on disk (:func:`lut_cache_path`): building it integrates 11,520
    spectra with colour-science, whose import alone costs 1.3-2.8 s, and every process that
    generates a subject (a dataset's first sample, each Ray worker) needs it. A missing,
    unreadable or malformed file is rebuilt (a read-only cache: built every time)."""
    path = lut_cache_path(optics)
    try:
        with np.load(path, allow_pickle=False) as z:
            lut = AlbedoLUT(z["sqrt_cm"], z["sqrt_ch"], z["bm"], z["rgb"])
        if (lut.rgb.dtype == np.float32 and lut.rgb.shape == (len(lut.sqrt_cm), len(lut.sqrt_ch),
                                                              len(lut.bm), 3)
                and np.all(np.isfinite(lut.rgb))):
            return lut
    except (OSError, ValueError, KeyError):
        pass
    lut = AlbedoLUT.build(optics)
    with contextlib.suppress(OSError, HackError):  # a cache that cannot be written: no cache
        write_npz(path, {"sqrt_cm": lut.sqrt_cm, "sqrt_ch": lut.sqrt_ch, "bm": lut.bm,
                         "rgb": lut.rgb})
    return lut


def draw_chromophores(u: np.ndarray, pop: PopulationConstants) -> dict[str, np.ndarray]:
    """Map uniforms (N, 3) to base chromophores {"c_m", "c_h", "b_m"}, each (N,)."""
    u = np.asarray(u, np.float64)
    return {"c_m": pop.cm_lo + (pop.cm_hi - pop.cm_lo) * u[:, 0] ** pop.skew,
            "c_h": pop.ch_lo + (pop.ch_hi - pop.ch_lo) * u[:, 1] ** pop.skew,
            "b_m": pop.bm_lo + (pop.bm_hi - pop.bm_lo) * u[:, 2]}


def subject_uniforms(seed: int) -> np.ndarray:
    """(3,) the uniforms that fix subject ``seed``'s base chromophores."""
    return np.random.default_rng([int(seed), 0]).random(3)
