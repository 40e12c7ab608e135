"""The swallow (paper Sec. 7, "swallowing simulation"): tau sequences aligned at their
peaks and valleys, then averaged.

A swallow lifts the larynx by about 2-3 cm and lowers it again (ANATOMY.md). In a tau
sequence (metres, up positive) each swallow is a peak between two valleys: the onset,
where the larynx leaves its rest height, and the offset, where it is back. The procedure:

1. find the swallows (:func:`find_swallows`): peaks of at least ``min_rise`` metres above
   their surroundings; each one's valleys are the last frame before and the first frame
   after the peak within ``onset_fraction`` of the peak's height above the local base;
2. align them (:func:`average_swallows`): every swallow's rise (valley to peak) and fall
   (peak to valley) are resampled, by linear interpolation in time, onto the mean rise and
   the mean fall duration, and its base (the mean of its two valley heights) subtracted;
3. average the aligned swallows sample by sample (and keep their standard deviation).

The curve the turntable's ``--swallow`` plays (``hack_render/data/swallow_tau.npz``) was
made by this procedure from *procedural* clips (:func:`procedural_swallow_clips`; no
recorded larynx motion is available here); ``python -m hack_render.motion.swallow`` writes
it again, and :func:`average_swallows` takes a user's recorded tau sequences instead.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.io.npz import write_npz

#: Samples of an averaged curve (rise and fall together).
CURVE_SAMPLES = 96


@dataclass(frozen=True)
class Swallow:
    """One swallow in a sequence: frame indices of its onset valley, peak and offset valley."""

    onset: int
    peak: int
    offset: int


@dataclass(frozen=True)
class SwallowCurve:
    """An averaged swallow.

    Attributes:
        times: (S,) seconds from the onset valley; the peak is at ``rise_s``.
        tau: (S,) metres above the valleys' base (0 at both ends).
        std: (S,) metres, the aligned swallows' standard deviation per sample.
        rise_s, fall_s: mean durations, onset to peak and peak to offset, seconds.
        count: how many swallows were averaged.
        provenance: where the tau sequences came from (free text, kept in the file).
    """

    times: np.ndarray
    tau: np.ndarray
    std: np.ndarray
    rise_s: float
    fall_s: float
    count: int
    provenance: dict = field(default_factory=dict)

    def save(self, path: str | Path) -> Path:
        """Write as ``.npz`` (arrays plus a JSON ``meta`` string; no pickle)."""
        meta = {"format": "hack-swallow", "version": 1, "rise_s": self.rise_s,
                "fall_s": self.fall_s, "count": self.count, "provenance": self.provenance,
                "units": "seconds from onset; metres of larynx slide (tau) above the base"}
        return write_npz(path, {"times": self.times, "tau": self.tau, "std": self.std,
                                "meta": np.str_(json.dumps(meta))})


def load_swallow_curve(path: str | Path) -> SwallowCurve:
    """Read a curve written by :meth:`SwallowCurve.save`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: np.asarray(z[k], np.float64) for k in ("times", "tau", "std")}
    except (OSError, KeyError, ValueError) as exc:
        raise HackError(f"{path}: not a swallow curve (.npz with times, tau, std, meta): "
                        f"{exc}.") from exc
    return SwallowCurve(rise_s=float(meta["rise_s"]), fall_s=float(meta["fall_s"]),
                        count=int(meta["count"]), provenance=meta.get("provenance", {}),
                        **arrays)


def _check_tau(tau, where: str) -> np.ndarray:
    t = np.asarray(tau, np.float64)
    if t.ndim != 1 or len(t) < 3:
        raise HackError(f"{where}: expected a tau sequence of shape (T,), T >= 3, found "
                        f"shape {t.shape}.")
    if not np.isfinite(t).all():
        raise HackError(f"{where}: frame {int(np.flatnonzero(~np.isfinite(t))[0])} is NaN or "
                        "inf; pass finite larynx slides (metres).")
    return t


def find_swallows(tau, min_rise: float = 0.008, onset_fraction: float = 0.05) -> list[Swallow]:
    """The swallows in a tau sequence (T,) metres: peaks rising at least ``min_rise`` metres
    above both sides (their prominence), each with its onset and offset valleys: the last
    frame before and the first after the peak whose height is within ``onset_fraction`` of
    the rise above the base on that side (scipy's peak bases)."""
    from scipy.signal import find_peaks

    t = _check_tau(tau, "tau")
    peaks, props = find_peaks(t, prominence=min_rise)
    out = []
    for p, lb, rb in zip(peaks, props["left_bases"], props["right_bases"], strict=True):
        lo_l = t[lb] + onset_fraction * (t[p] - t[lb])
        lo_r = t[rb] + onset_fraction * (t[p] - t[rb])
        left = np.flatnonzero(t[lb:p] <= lo_l)
        right = np.flatnonzero(t[p:rb + 1] <= lo_r)
        onset = int(lb + left[-1]) if len(left) else int(lb)
        offset = int(p + right[0]) if len(right) else int(rb)
        if onset < p < offset:
            out.append(Swallow(onset, int(p), offset))
    return out


def _resample(y: np.ndarray, n: int) -> np.ndarray:
    """y (m,) at evenly spaced times, linearly resampled to n samples over the same span."""
    return np.interp(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, len(y)), y)


def average_swallows(sequences, fps, min_rise: float = 0.008, samples: int = CURVE_SAMPLES,
                     provenance: dict | None = None) -> SwallowCurve:
    """Align every swallow of ``sequences`` (tau arrays (T_i,), metres) at its valleys and
    peak, and average (the module docstring's procedure).

    Args:
        sequences: tau sequences, one array per clip; each may hold several swallows.
        fps: frames per second, one number or one per sequence.
        min_rise: the smallest swallow, metres (smaller peaks are speech, not swallows).
        samples: samples of the averaged curve (rise and fall split by their durations).
        provenance: what the sequences are, stored with the curve.
    """
    seqs = [_check_tau(s, f"sequence {i}") for i, s in enumerate(sequences)]
    rates = np.broadcast_to(np.asarray(fps, np.float64), (len(seqs),))
    if not seqs or not (np.isfinite(rates).all() and (rates > 0).all()):
        raise HackError("average_swallows: expected at least one tau sequence and positive "
                        f"frame rates, found {len(seqs)} sequences, fps {np.asarray(fps)}.")
    found = [(s, r, sw) for s, r in zip(seqs, rates, strict=True)
             for sw in find_swallows(s, min_rise)]
    if not found:
        raise HackError(f"average_swallows: no swallow (a peak rising >= {min_rise * 1e3:.0f} "
                        f"mm above both sides) in {len(seqs)} sequences.")
    rise = float(np.mean([(sw.peak - sw.onset) / r for _, r, sw in found]))
    fall = float(np.mean([(sw.offset - sw.peak) / r for _, r, sw in found]))
    n_rise = max(2, round(samples * rise / (rise + fall)))
    n_fall = max(2, samples - n_rise + 1)  # the peak sample is shared
    aligned = []
    for s, _, sw in found:
        base = 0.5 * (s[sw.onset] + s[sw.offset])
        up = _resample(s[sw.onset:sw.peak + 1], n_rise)
        down = _resample(s[sw.peak:sw.offset + 1], n_fall)
        aligned.append(np.r_[up, down[1:]] - base)
    aligned = np.asarray(aligned)
    times = np.r_[np.linspace(0.0, rise, n_rise), np.linspace(rise, rise + fall, n_fall)[1:]]
    curve = aligned.mean(0)
    curve = curve - np.linspace(curve[0], curve[-1], len(curve))  # both ends exactly 0
    return SwallowCurve(times=times, tau=curve, std=aligned.std(0), rise_s=rise, fall_s=fall,
                        count=len(found), provenance=dict(provenance or {}))


# ------------------------------------------------------------------ procedural clips
def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


def procedural_swallow_clips(n: int = 16, fps: float = 30.0, seed: int = 26
                             ) -> list[np.ndarray]:
    """``n`` procedural tau clips (metres), one swallow each, for tests and for the default
    curve. NOT recorded data: each clip is a smooth rise of 1.2-2.0 cm over 0.25-0.45 s, a
    hold of 0.1-0.35 s and a return over 0.3-0.6 s (the larynx rises 2-3 cm in a swallow,
    ANATOMY.md, but the model's slide ends at 2 cm, ``larynx.TAU_RANGE_M``; durations of
    the order of the pharyngeal phase, about 1 s), at a
    random time in a 3 s clip, over slow speech-like motion of about 1 mm and 0.2 mm of
    tracking noise."""
    rng = np.random.default_rng(seed)
    clips = []
    for _ in range(n):
        t = np.arange(int(3.0 * fps)) / fps
        rise, hold, fall = rng.uniform(0.25, 0.45), rng.uniform(0.1, 0.35), rng.uniform(0.3, 0.6)
        amp, t0 = rng.uniform(0.012, 0.020), rng.uniform(0.6, 1.2)
        bump = amp * (_smoothstep((t - t0) / rise) - _smoothstep((t - t0 - rise - hold) / fall))
        drift = 0.001 * np.sin(2 * np.pi * rng.uniform(0.3, 0.8) * t + rng.uniform(0, 2 * np.pi))
        clips.append(bump + drift + rng.normal(0.0, 0.0002, len(t)))
    return clips


def default_curve(seed: int = 26) -> SwallowCurve:
    """The curve shipped for the turntable: :func:`average_swallows` over 16 procedural
    clips (:func:`procedural_swallow_clips`), labelled as derived from procedural data."""
    clips = procedural_swallow_clips(16, 30.0, seed)
    prov = {"kind": "derived from procedural data",
            "source": f"hack_render.motion.swallow.procedural_swallow_clips(16, fps=30, "
                      f"seed={seed}): synthetic tau clips, not recorded larynx motion",
            "procedure": "hack_render.motion.swallow.average_swallows: aligned at onset "
                         "valley, peak and offset valley, then averaged",
            "regenerate": "python -m hack_render.motion.swallow"}
    return average_swallows(clips, 30.0, provenance=prov)


if __name__ == "__main__":  # rewrite the shipped curve
    from importlib import resources

    out = Path(str(resources.files("hack_render") / "data" / "swallow_tau.npz"))
    c = default_curve()
    print(f"wrote {c.save(out)}: {c.count} swallows, peak {c.tau.max() * 1e3:.1f} mm, "
          f"rise {c.rise_s:.2f} s, fall {c.fall_s:.2f} s")
