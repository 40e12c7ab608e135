"""Calibrate the procedural skin population against measured skin albedo; print the fit.

    python -m appearance.calibrate [--subjects 1000] [--verify 300] [--height 64]

Free constants (7): the optics scales k_path, k_scat, k_base
(:class:`appearance.skin_optics.OpticsConstants`) and the chromophore bounds cm_lo,
cm_hi, ch_lo, ch_hi (:class:`appearance.population.PopulationConstants`, kept inside
the literature ranges of DATA.md). They are fitted by bounded least squares so that the
population of subjects 0..N-1 (common random numbers: each subject's uniforms are fixed
by its seed) matches, per channel, the 1st percentile, median and 99th percentile of
measured diffuse albedo (ISSA / Xiao 2016, DATA.md), and spans the measured ITA range.
Then ``--verify`` subjects are generated as full texture maps and their forehead medians
are compared with the same targets (the maps include regional jitter, mottling, freckles
and hair, so this checks the generator, not only the fit). Writes
``appearance/data/calibration.json`` (atomically) unless ``--dry-run``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.optimize import least_squares
from tqdm import tqdm

from appearance.colour_space import ita_degrees
from appearance.generator import generate_subject, representative_albedo
from appearance.population import (
    CALIBRATION_FILE,
    Calibration,
    PopulationConstants,
    draw_chromophores,
    subject_uniforms,
)
from appearance.skin_optics import OpticsConstants, skin_albedo
from hack_render.io import write_json

#: Measured targets (DATA.md, Textures): linear sRGB diffuse albedo, D65, CIE 1931 2 deg.
TARGETS = {
    "p01": np.array([0.107, 0.063, 0.047]),
    "p50": np.array([0.408, 0.230, 0.157]),
    "p99": np.array([0.541, 0.366, 0.281]),
}
SUBGROUP_TARGETS = {
    "african_median": np.array([0.172, 0.089, 0.058]),
    "caucasian_median": np.array([0.466, 0.267, 0.201]),
}
ITA_SPAN = (-42.0, 56.0)  # measured; the requirement is at least -40 .. 55
TOLERANCE = 0.03

_NAMES = ("k_path", "k_scat", "k_base", "cm_lo", "cm_hi", "ch_lo", "ch_hi")
_LO = np.array([np.log(0.05), np.log(0.02), np.log(0.05), 0.002, 0.1, 0.003, 0.02])
_HI = np.array([np.log(5.0), np.log(5.0), np.log(5.0), 0.1, 0.5, 0.1, 0.32])


def _unpack(x: np.ndarray) -> Calibration:
    return Calibration(OpticsConstants(k_path=float(np.exp(x[0])), k_scat=float(np.exp(x[1])),
                                       k_base=float(np.exp(x[2]))),
                       PopulationConstants(cm_lo=float(x[3]), cm_hi=float(x[4]),
                                           ch_lo=float(x[5]), ch_hi=float(x[6])))


def population_albedo(cal: Calibration, seeds: np.ndarray) -> np.ndarray:
    """(N, 3) base linear sRGB albedo of the subjects ``seeds`` (spectral model, no LUT)."""
    u = np.stack([subject_uniforms(s) for s in seeds])
    c = draw_chromophores(u, cal.population)
    return skin_albedo(c["c_m"], c["c_h"], c["b_m"], cal.optics)


def summary(rgb: np.ndarray) -> dict:
    """Percentiles, ITA range and the worst per-channel deviation from the targets."""
    q = np.percentile(rgb, [1, 50, 99], axis=0)
    ita = ita_degrees(rgb)
    dev = np.abs(np.stack([q[0] - TARGETS["p01"], q[1] - TARGETS["p50"],
                           q[2] - TARGETS["p99"]]))
    return {"p01": q[0].round(4).tolist(), "p50": q[1].round(4).tolist(),
            "p99": q[2].round(4).tolist(), "ita_min": round(float(ita.min()), 2),
            "ita_max": round(float(ita.max()), 2),
            "max_abs_error": round(float(dev.max()), 4), "n": len(rgb)}


def _residuals(x, seeds_u, tg, ita_hi):
    cal = _unpack(x)
    c = draw_chromophores(seeds_u, cal.population)
    rgb = skin_albedo(c["c_m"], c["c_h"], c["b_m"], cal.optics)
    q = np.percentile(rgb, [1, 50, 99], axis=0)
    r = np.concatenate([q[0] - tg["p01"], q[1] - tg["p50"], q[2] - tg["p99"]])
    ita = ita_degrees(rgb)
    # hinge penalties (0.002 per degree) pushing the ITA range past the measured span
    span = [max(0.0, ita.min() - ITA_SPAN[0]), max(0.0, ita_hi + 1.0 - ita.max())]
    return np.append(r, 0.002 * np.asarray(span))


def fit(n_subjects: int = 1000, targets: dict | None = None, ita_hi: float = ITA_SPAN[1],
        x0=None) -> tuple[Calibration, dict]:
    """Fit the 7 free constants on subjects 0..n-1; returns the calibration and a report.

    Args:
        targets: percentile targets for the base albedo (default :data:`TARGETS`);
            :func:`main` shifts them to absorb the generator's systematic offsets.
    """
    seeds_u = np.stack([subject_uniforms(s) for s in range(n_subjects)])
    x0 = np.array([0.0, 0.0, 0.0, 0.01, 0.45, 0.01, 0.3]) if x0 is None else x0
    t0 = time.perf_counter()
    tg = targets or TARGETS
    res = least_squares(_residuals, x0, bounds=(_LO, _HI), diff_step=1e-3,
                        args=(seeds_u, tg, ita_hi))
    cal = _unpack(res.x)
    rgb = population_albedo(cal, np.arange(n_subjects))
    rep = {"constants": dict(zip(_NAMES, [float(v) for v in
                                          (*np.exp(res.x[:3]), *res.x[3:])])),
           "fit_population": summary(rgb), "seconds": round(time.perf_counter() - t0, 2),
           "targets": {k: v.tolist() for k, v in TARGETS.items()},
           "tolerance": TOLERANCE, "ita_required": [-40.0, 55.0]}
    rep["subgroup_reachability"] = _reachability(cal)
    rep["x"] = res.x.tolist()
    return cal, rep


def _reachability(cal: Calibration) -> dict:
    """Closest model albedo to the subgroup medians over a grid of (C_m, C_h, b_m)."""
    p = cal.population
    g = np.meshgrid(np.linspace(p.cm_lo, p.cm_hi, 60), np.linspace(p.ch_lo, p.ch_hi, 30),
                    np.linspace(p.bm_lo, p.bm_hi, 4), indexing="ij")
    rgb = skin_albedo(*g, cal.optics).reshape(-1, 3)
    out = {}
    for k, t in SUBGROUP_TARGETS.items():
        err = np.abs(rgb - t).max(1)
        out[k] = {"target": t.tolist(), "closest": rgb[err.argmin()].round(4).tolist(),
                  "max_abs_error": round(float(err.min()), 4)}
    return out


def verify(cal: Calibration, n: int, height: int) -> dict:
    """Generate ``n`` subjects' maps and compare their forehead medians with the targets."""

    rgb = np.stack([representative_albedo(generate_subject(s, height, cal), height)
                    for s in tqdm(range(n), desc="verify (generated maps)", leave=False)])
    return summary(rgb)


def write_calibration(cal: Calibration, path=CALIBRATION_FILE) -> None:
    """Write the calibration JSON atomically (temp file, then rename)."""
    write_json(path, cal.to_json(), indent=1)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subjects", type=int, default=1000, help="fit population size (>= 300)")
    ap.add_argument("--verify", type=int, default=300, help="subjects generated as maps")
    ap.add_argument("--height", type=int, default=64, help="atlas height for verification")
    ap.add_argument("--iterations", type=int, default=4, help="target-shift iterations")
    ap.add_argument("--dry-run", action="store_true", help="do not write calibration.json")
    a = ap.parse_args(argv)
    if a.subjects < 300:
        ap.error("--subjects must be >= 300")
    # Fit the base albedo, generate maps, and shift the base targets by the generator's
    # measured offset (fixed-point iteration T_i+1 = T_i + (T - V_i)), so that the
    # *generated maps* meet the measured targets, not only the base chromophores.
    tg = {k: v.copy() for k, v in TARGETS.items()}
    ita_hi, x0, history = ITA_SPAN[1], None, []
    for it in range(max(1, a.iterations)):
        cal, rep = fit(a.subjects, tg, ita_hi, x0)
        x0 = np.asarray(rep.pop("x"))
        if not a.verify:
            break
        v = verify(cal, a.verify, a.height)
        v["height"] = a.height
        history.append({"iteration": it, "base_targets": {k: t.round(4).tolist()
                                                          for k, t in tg.items()}, "verify": v})
        print(f"iteration {it}: generated-map max error {v['max_abs_error']:.4f}, "
              f"ITA {v['ita_min']:.1f} .. {v['ita_max']:.1f}")
        rep["verify_generated_maps"] = v
        if v["max_abs_error"] <= 0.01 and v["ita_max"] >= 55 and v["ita_min"] <= -40:
            break
        for k in tg:
            tg[k] = tg[k] + (TARGETS[k] - np.asarray(v[k]))
        ita_hi += max(0.0, 56.0 - v["ita_max"])
    rep["iterations"] = history
    cal = Calibration(cal.optics, cal.population, rep)
    print(json.dumps(rep, indent=1))
    # The criterion is on what users get: the generated maps (the base fit is only a
    # means, its targets are shifted by the generator's offsets).
    if a.verify:
        v = rep["verify_generated_maps"]
        ok = [v["max_abs_error"] <= TOLERANCE and v["ita_min"] <= -40 and v["ita_max"] >= 55]
    else:
        ok = [rep["fit_population"]["max_abs_error"] <= TOLERANCE]
    print("calibration targets met:", all(ok))
    if not a.dry_run:
        write_calibration(cal)
        print("wrote", CALIBRATION_FILE)
    return rep


if __name__ == "__main__":
    main()
