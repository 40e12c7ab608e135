"""The fitter's robust losses, one place for all terms (landmarks, silhouette, photo,
and the landmark calibration's search).

- :func:`huber`: 0.5 r^2 below 1, |r| - 0.5 above, on residuals already divided by the
  knee (the landmark and silhouette terms express theirs in units of a fraction of the
  face size).
- :func:`pseudo_huber`: the smooth version, ``knee * (sqrt(d^2 + knee^2) - knee)``, ~d^2/2
  below the knee and ~knee |d| above, in the units of ``d``; :func:`charbonnier` is it
  divided by the knee (a robust L1: ~|d| above the knee), the photometric term's loss.
Both work on torch tensors and numpy arrays.
"""

from __future__ import annotations


def huber(r):
    """Huber's loss of residuals ``r`` in units of the knee (torch or numpy)."""
    a = abs(r)
    return ((a < 1.0) * (0.5 * r * r) + (a >= 1.0) * (a - 0.5))


def pseudo_huber(d, knee: float):
    """Pseudo-Huber loss of residuals ``d`` with the given knee, in the units of ``d``:
    ~d^2/2 below the knee, ~knee |d| above."""
    return knee * charbonnier(d, knee)


def charbonnier(d, eps: float):
    """Charbonnier (robust L1): sqrt(d^2 + eps^2) - eps, ~|d| beyond eps."""
    return (d * d + eps * eps) ** 0.5 - eps
