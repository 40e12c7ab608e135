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

The commands' side of the policy lives here too, so that every command applies it alike:
:class:`LimitPolicy` (the ``--limits`` choice, :func:`limit_policy` parses it) and
:func:`apply_limit_policy`, which adds the plausible identities (``beta`` within
:data:`BETA_PLAUSIBLE`) to :func:`enforce_limits` and prints the warnings on stderr.
"""

from __future__ import annotations

from enum import Enum
from typing import Any

import numpy as np
import typer

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


class LimitPolicy(str, Enum):
    """The ``--limits`` choice of the commands that pose the model."""

    warn = "warn"
    clamp = "clamp"
    error = "error"


def limit_policy(value: str | LimitPolicy) -> LimitPolicy:
    """``--limits``'s text as a :class:`LimitPolicy` (a user error when it is none)."""
    try:
        return LimitPolicy(value)
    except ValueError as err:
        raise HackError(f"--limits: expected warn, clamp or error, found {value!r}.") from err


#: Identities beyond this many standard deviations (per component) are implausible: the
#: shape space is N(0, I), and the dataset sampler truncates at 2.5 by default.
BETA_PLAUSIBLE = 5.0


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
    # a tensor's clamp; skeleton imports torch, which posing with NumPy alone (posing.py:
    # `hack-render mesh`, the render's mesh cache) must not import (a listed deferral,
    # tests/test_structure.py DEFERRED_OWN)
    from hack_render.geometry.skeleton import clamp_to_limits  # noqa: PLC0415

    return clamp_to_limits(theta)


def beta_messages(beta) -> list[str]:
    """Shape coefficients beyond :data:`BETA_PLAUSIBLE`, as phrases (a tensor or an array)."""
    b = np.asarray(beta.detach().cpu() if hasattr(beta, "detach") else beta).reshape(-1)
    return [f"beta[{i}] = {float(v):.3g} (plausible identities lie within "
            f"+-{BETA_PLAUSIBLE:g} standard deviations; clamped to "
            f"{max(-BETA_PLAUSIBLE, min(BETA_PLAUSIBLE, float(v))):g})"
            for i, v in enumerate(b.tolist()) if abs(v) > BETA_PLAUSIBLE]


def apply_limit_policy(kw: dict, policy: LimitPolicy, head_rotation_deg=None) -> dict:
    """Warn about, clamp, or refuse (exit 2) out-of-range joint rotations, whole-head
    rotations, larynx slide tau and size eta (:func:`enforce_limits`) and implausible
    identities (``beta`` beyond :data:`BETA_PLAUSIBLE`); warnings name each value and its
    limit, and go to stderr (once)."""
    policy_name = str(getattr(policy, "value", policy))
    ident = beta_messages(kw["beta"]) if kw.get("beta") is not None else []
    if ident and policy_name == "error":
        text = "; ".join(m.split("; clamped to")[0] + ")" for m in ident)
        raise HackError(f"--beta: outside the plausible identities: {text}. Change the value, "
                        "or use --limits clamp (clamp and warn) or --limits warn.")
    kw, messages = enforce_limits(kw, policy, head_rotation_deg)
    if ident and policy_name == "clamp":
        kw = dict(kw, beta=kw["beta"].clip(-BETA_PLAUSIBLE, BETA_PLAUSIBLE))
    elif ident:
        ident = [m.split("; clamped to")[0] + "; kept, use --limits clamp to clamp)"
                 for m in ident]
    messages = messages + ident
    if messages:
        typer.secho(f"warning: outside the anatomical limits: {'; '.join(messages)}", err=True,
                    fg="yellow")
    return kw
