"""The command line's shared vocabulary: options declared once, and deprecated names.

One option name means one thing in every command (`-o/--output`, `--resolution` in
pixels, `--spp`, `--params`, `--seed`, `--quiet`, `--limits`); the options that several
commands share are declared here once, as ``Annotated`` types, and used by each command's
signature (``params: opts.Params = None``). Old spellings stay for one release as hidden
options or hidden commands that print a deprecation message on stderr and then behave as
the new name does.

Imports nothing heavy: every `--help` imports this module.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from hack_render.errors import HackError


def warn_deprecated(old: str, new: str) -> None:
    """Say on stderr that ``old`` is deprecated in favour of ``new``."""
    typer.secho(f"warning: {old} is deprecated and will be removed in the next release; "
                f"use {new}.", err=True, fg=typer.colors.YELLOW)


def renamed(value: Any, old_value: Any, old: str, new: str) -> Any:
    """The value of an option given under its new name or its deprecated old one.

    ``value`` is what the new option received (None or empty when not given), ``old_value``
    what the hidden old spelling received. Giving both is an error; giving the old one
    prints a deprecation message.
    """
    if old_value is None or (isinstance(old_value, (list, tuple)) and not old_value):
        return value
    warn_deprecated(old, new)
    if value is not None and not (isinstance(value, (list, tuple)) and not value):
        raise HackError(f"{new} and {old}: expected one of them ({old} is its old name), "
                        f"found both.")
    return old_value


def deprecated_command(func: Callable, old: str, new: str) -> Callable:
    """``func`` under an old command name: the same options, plus a deprecation message."""

    @functools.wraps(func)  # typer reads the signature through __wrapped__
    def wrapper(*args, **kwargs):
        warn_deprecated(f"`hack-render {old}`", f"`hack-render {new}`")
        return func(*args, **kwargs)

    return wrapper


def add_deprecated(app: typer.Typer, name: str, func: Callable, old: str, new: str) -> None:
    """Register ``func`` on ``app`` as the hidden command ``name`` (full path ``old``)."""
    app.command(name, hidden=True,
                help=f"Deprecated: use `hack-render {new}`.")(deprecated_command(func, old, new))


# --- options shared by several commands (help text in one place) ----------------------
Params = Annotated[Optional[Path], typer.Option(
    "--params", help="JSON/YAML parameter file (keys: beta, psi, expression, "
    "head_rotation_deg, theta, global_orient, transl, eta, tau); flags override it. "
    "`hack-render fit` writes one.")]
Beta = Annotated[Optional[str], typer.Option("--beta", help="Identity, comma-separated, "
                                             "e.g. '1.0,-0.5'.")]
Expression = Annotated[Optional[str], typer.Option(
    "--expr", help="FACS AUs and/or shape names, e.g. 'AU12=0.7,jawOpen=0.3'.")]
HeadRotation = Annotated[Optional[str], typer.Option(
    "--head-rotation", help="Whole-head 'flexion,axial,lateral' in degrees, shared over the "
    "8 cervical joints by their ranges, e.g. '15,40,0'.")]
Eta = Annotated[Optional[float], typer.Option("--eta", help="Larynx size, 0..1.5 (default 1: "
                                              "the identity's own larynx; 0: none).")]
Tau = Annotated[Optional[float], typer.Option("--tau", help="Larynx vertical slide, metres, up "
                                              "positive, -0.01..0.02 (a swallow rises ~0.02).")]
Limits = Annotated[str, typer.Option("--limits", help="Values beyond the anatomical limits "
                                     "(joint rotations, --head-rotation, --eta, --tau) or the "
                                     "plausible identities (--beta beyond +-5): warn, clamp "
                                     "(and warn) or error. Values beyond any meaning (NaN, "
                                     "--beta 1e30) are always refused.")]
ModelPath = Annotated[Optional[Path], typer.Option("--model", help="Model file (default: "
                                                   "built-in).")]
Alpha = Annotated[Optional[str], typer.Option("--alpha", help="Appearance coefficients, "
                                              "comma-separated, e.g. '0.8,-0.6,0.4'.")]
AppearanceSeed = Annotated[Optional[int], typer.Option(
    "--appearance-seed", help="Random appearance from this seed.")]
Textures = Annotated[Optional[Path], typer.Option(
    "--textures", help="Folder with diffuse/specular/roughness(, normal).exr skin maps.")]
Lighting = Annotated[str, typer.Option(
    "--lighting", help="Lighting preset: studio, light_stage, overcast_sun, window, or "
    "env:PATH.exr/.hdr (a lat-long HDR map).")]
EnvRotation = Annotated[float, typer.Option("--env-rotation", help="Rotate the lighting "
                                            "about +Y, degrees.")]
Exposure = Annotated[float, typer.Option("--exposure", help="Lighting exposure, stops.")]
Resolution = Annotated[str, typer.Option("--resolution", help="Image size in pixels: 'W' "
                                         "or 'WxH'.")]
Spp = Annotated[int, typer.Option("--spp", help="Samples per pixel: at least this many are "
                                  "rendered (a sampler may round up, and says so).")]
Seed = Annotated[int, typer.Option("--seed", help="Sampler seed.")]
Tonemap = Annotated[str, typer.Option("--tonemap", help="PNG tone map: aces, reinhard or "
                                      "clip.")]
Variant = Annotated[Optional[str], typer.Option(
    "--variant", help="Mitsuba variant (default: $HACK_RENDER_VARIANT or automatic).")]
Quiet = Annotated[bool, typer.Option("--quiet", help="No progress bars.")]
Threads = Annotated[Optional[int], typer.Option(
    "--threads", help="CPU threads for torch, Dr.Jit and Open Image Denoise. Default: torch "
    "2 (register: 1), the renderer and the denoiser every core. On a shared machine or a "
    "cluster job, the cores you were given (docs/troubleshooting.md).")]
