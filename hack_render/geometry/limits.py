"""Anatomical limits on input: warn about, clamp or refuse out-of-range parameters.

One policy (``warn``, ``clamp`` or ``error``; the CLI's ``--limits``) governs every bounded
input of a forward pass: the joints' rotations (:mod:`hack_render.geometry.skeleton`, White &
Panjabi), a whole-head rotation shared over them, and the larynx's slide ``tau`` and size
``eta`` (:mod:`hack_render.geometry.larynx`). Fitting uses the differentiable penalties
instead (``rotation_limit_penalty``, ``larynx_limit_penalty``).

* ``error``: a :class:`~hack_render.errors.HackError` that names every offending joint / axis
  / value / limit (the CLI exits with code 2).
* ``clamp``: the values are clamped and a warning names each one and what it became.
* ``warn``: joint rotations, eta and tau are kept as given and a warning names them; a
  whole-head rotation beyond the neck's range is still clamped (it is shared over joints
  that each stop at their limit), and the warning names the clamped value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry.anatomy import (
    ETA_RANGE,
    TAU_RANGE_M,
    clamp_theta,
    head_rotation_outside_limits,
    larynx_outside_limits,
    outside_limits,
)

POLICIES = ("warn", "clamp", "error")


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def head_rotation_messages(angles_deg) -> list[str]:
    """Whole-head rotation axes beyond the neck's range, as phrases (empty when inside)."""
    return [f"head rotation {axis} {val:.1f} deg (whole-neck range {lo:.1f}..{hi:.1f} deg; "
            f"clamped to {min(max(val, lo), hi):.1f} deg)"
            for axis, val, lo, hi in head_rotation_outside_limits(angles_deg)]


def joint_messages(theta) -> list[str]:
    """Joint rotations of a (B, 8, 3) or (8, 3) pose beyond the limits, as phrases."""
    return [f"joint {name} axis {axis} = {deg:.1f} deg (limits {lo:.1f}..{hi:.1f} deg; "
            f"clamped to {min(max(deg, lo), hi):.1f} deg)"
            for _, name, axis, deg, lo, hi in outside_limits(theta)]


def larynx_messages(eta, tau) -> list[str]:
    """eta / tau values beyond their ranges, as phrases."""
    unit = {"eta": "", "tau": " m"}
    return [f"larynx {name} = {_fmt(val)}{unit[name]} (range {_fmt(lo)}..{_fmt(hi)}{unit[name]}; "
            f"clamped to {_fmt(min(max(val, lo), hi))}{unit[name]})"
            for name, val, lo, hi in larynx_outside_limits(eta, tau)]


def enforce_limits(kw: dict[str, Any], policy: str,
                   head_rotation_deg=None) -> tuple[dict[str, Any], list[str]]:
    """Apply ``policy`` to forward-pass keyword arguments.

    Args:
        kw: forward keyword arguments (``theta`` (B, 8, 3), ``eta`` (B,), ``tau`` (B,), any
            others passed through), e.g. from :func:`hack_render.geometry.params.model_inputs`,
            whose whole-head rotation share is already clamped to the neck's range.
        policy: "warn", "clamp" or "error" (or an Enum whose value is one of them).
        head_rotation_deg: the requested whole-head rotation (3,) degrees, if any, so that a
            request beyond the neck's range is reported as such.

    Returns:
        (kw, warnings): the (possibly clamped) arguments and one message per adjusted or
        out-of-range value (empty when everything is inside).

    Raises:
        HackError: under "error", naming every value beyond its limit.
    """
    policy = str(getattr(policy, "value", policy))
    if policy not in POLICIES:
        raise HackError(f"--limits: expected one of {', '.join(POLICIES)}, found {policy!r}.")
    head = head_rotation_messages(head_rotation_deg) if head_rotation_deg is not None else []
    joints = joint_messages(kw["theta"]) if kw.get("theta") is not None else []
    eta, tau = kw.get("eta"), kw.get("tau")
    lar = larynx_messages(eta if eta is not None else 1.0, tau if tau is not None else 0.0)
    if policy == "error":
        bad = head + joints + lar
        if bad:
            text = "; ".join(m.split("; clamped to")[0] + ")" for m in bad)
            raise HackError(f"outside the anatomical limits: {text}. Change the value, or use "
                            f"--limits clamp (clamp and warn) or --limits warn.")
        return kw, []
    out = dict(kw)
    if policy == "clamp":
        if joints:
            out["theta"] = _clamp_theta(kw["theta"])
        if lar:
            for name, (lo, hi) in (("eta", ETA_RANGE), ("tau", TAU_RANGE_M)):
                x = kw.get(name)
                if x is not None:  # a tensor's or an array's own clip; a number's min/max
                    out[name] = x.clip(lo, hi) if hasattr(x, "clip") else min(max(x, lo), hi)
        return out, head + joints + lar
    keep = [m.split("; clamped to")[0] + "; kept, use --limits clamp to clamp)"
            for m in joints + lar]
    return out, head + keep


def _clamp_theta(theta):
    """``theta`` with each joint clamped to its limits, of the kind it came as."""
    if isinstance(theta, np.ndarray):
        return clamp_theta(theta).astype(theta.dtype)
    from hack_render.geometry.skeleton import clamp_to_limits

    return clamp_to_limits(theta)
