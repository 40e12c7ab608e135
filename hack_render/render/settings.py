"""Render settings: image size, samples per pixel and their sampler, integrator, path
depth and seed (:class:`RenderSettings`), checked before anything is allocated; the
samplers' and integrators' names and limits. Used by :mod:`hack_render.render.scene`
(which re-exports these names) and the commands that build scenes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError

MAX_SIDE = 8192
MAX_PIXELS = 8192 * 8192
MAX_SPP = 1 << 16
#: Samples per render pass (one kernel launch); more spp are split into equal passes.
SAMPLES_PER_PASS = 1 << 24


#: Mitsuba samplers offered. Measured at about 32 spp on a 128 px studio portrait against
#: a 2,048-spp reference (docs/render.md): independent 30.5 dB, stratified (36) 35.3 dB,
#: multijitter (35) 36.7 dB, orthogonal (49) 40.5 dB, independent at 64 spp 33.8 dB.
#: ``auto``: Mitsuba's orthogonal array sampler where the count is the square of a prime
#: of at least 5 (25, 49, 121, 169, ...) or a little under one, else multijitter
#: (:func:`auto_sampler`); never fewer samples than asked for.
SAMPLERS = ("auto", "multijitter", "stratified", "orthogonal", "ldsampler", "independent")
DEFAULT_SAMPLER = "auto"
#: ``auto``'s smallest orthogonal count (5^2). On two 256 px stills (hack_path, depth 8;
#: docs/render.md, "Samplers and denoising") the orthogonal array at 25-169 spp is
#: 2.4-4.8 dB less noisy than multijitter at the same count, at 9 spp about 1 dB better.
#: (Under volpath, whose samples lay out their dimensions otherwise, 25 was 2.6 dB worse.)
AUTO_ORTHOGONAL_MIN = 25
#: Integrators of final renders. ``path`` treats every surface as opaque to shadow rays,
#: so the lash cards' whole area blocks direct light from the lights' point of view and
#: what lies under them is lit by BSDF-sampled paths alone (speckled); ``volpath`` and
#: ``hack_path`` (render/integrator.py: ``path`` plus volpath's null surfaces, 0.74x
#: volpath's cost per sample on the README still) trace shadow rays through
#: null-transmissive surfaces, weighted by the ``mask`` BSDF's transparency (see
#: docs/render.md, "Integrator").
INTEGRATORS = ("hack_path", "volpath", "path")
DEFAULT_INTEGRATOR = "hack_path"


def _next_prime(n: int) -> int:
    n = max(n, 2)
    while any(n % d == 0 for d in range(2, math.isqrt(n) + 1)):
        n += 1
    return n


#: ``auto`` takes the orthogonal array up to this many times the requested count (the
#: next prime square up: 20-25 spp render 25, 38-49 render 49, 94-121 render 121)
AUTO_ORTHOGONAL_UP = 1.3


def auto_sampler(spp: int, cap: int | None = None) -> tuple[str, int]:
    """(Mitsuba sampler, sample count) that ``auto`` renders for a requested ``spp``, never
    fewer than ``spp``: the orthogonal array at the smallest prime square >= ``spp``, where
    that is at least :data:`AUTO_ORTHOGONAL_MIN`, at most ``cap`` (a pass's sample budget)
    and at most :data:`AUTO_ORTHOGONAL_UP` x ``spp`` (25 -> 25, 40 -> 49, 100 -> 121), else
    multijitter, which rounds up by less than sqrt(spp) (16 -> 16, 32 -> 35, 64 -> 64).
    (Before issue 65 it took the nearest prime square either way: 32 -> 25, 64 -> 49.)"""
    p = _next_prime(max(math.isqrt(AUTO_ORTHOGONAL_MIN), math.isqrt(spp - 1) + 1))
    if p * p <= AUTO_ORTHOGONAL_UP * spp and (cap is None or p * p <= cap):
        return "orthogonal", p * p
    return "multijitter", sampler_spp("multijitter", spp)


def sampler_spp(sampler: str, spp: int) -> int:
    """The sample count Mitsuba's ``sampler`` actually takes for a requested ``spp``, at
    least ``spp`` (its own rounding, checked against Mitsuba in the tests): stratified
    rounds up to a square, multijitter to floor(sqrt n) x ceil(n / floor(sqrt n)),
    orthogonal to the square of a prime (at least 4), ldsampler to a power of 4 (at least
    4); ``auto`` as :func:`auto_sampler` chooses."""
    if sampler == "auto":
        return auto_sampler(spp)[1]
    if sampler == "independent":
        return spp
    if sampler == "stratified":
        return math.ceil(math.sqrt(spp)) ** 2 if math.isqrt(spp) ** 2 != spp else spp
    if sampler == "multijitter":
        rx = max(1, math.isqrt(spp))
        return rx * math.ceil(spp / rx)
    if sampler == "orthogonal":
        p = math.isqrt(spp)
        p = p if p * p == spp else p + 1
        return _next_prime(p) ** 2
    if sampler == "ldsampler":
        k = 4
        while k < spp:
            k *= 4
        return k
    raise HackError(f"sampler: expected one of {', '.join(SAMPLERS)}, found {sampler!r}.")


@dataclass(frozen=True)
class RenderSettings:
    """Image size, samples per pixel, path depth, seed and sampler, validated on creation.

    Every sampler but ``independent`` rounds the sample count up, never down
    (:func:`sampler_spp`): :attr:`effective_spp` is what is rendered."""

    width: int = 512
    height: int = 512
    spp: int = 49  # the orthogonal array's count (auto renders it as it is)
    max_depth: int = 8
    seed: int = 0
    #: ``gaussian`` (smoother) or ``box`` (bit-reproducible, see ``emitters.sensor_dict``).
    pixel_filter: str = "gaussian"
    sampler: str = DEFAULT_SAMPLER
    #: ``hack_path`` or ``volpath`` (shadow rays see through the lash cards' transparent
    #: parts: less noise under the lashes; the same image, hack_path the cheaper; non-JIT
    #: variants render ``hack_path`` as ``volpath``) or ``path`` (every surface blocks
    #: shadow rays; earlier versions)
    integrator: str = DEFAULT_INTEGRATOR

    def __post_init__(self):
        validate_size(self.width, self.height, self.spp)
        if self.integrator not in INTEGRATORS:
            raise HackError(f"integrator: expected one of {', '.join(INTEGRATORS)}, found "
                            f"{self.integrator!r}.")
        if self.sampler not in SAMPLERS:
            raise HackError(f"sampler: expected one of {', '.join(SAMPLERS)}, found "
                            f"{self.sampler!r}.")
        if self.pixel_filter not in ("gaussian", "box"):
            raise HackError(f"pixel filter: expected 'gaussian' or 'box', found "
                            f"{self.pixel_filter!r}.")
        if not 1 <= self.max_depth <= 64:
            raise HackError(f"max depth: expected 1..64 bounces, found {self.max_depth}.")
        if not 0 <= self.seed < 2 ** 31:
            raise HackError(f"seed: expected 0 <= seed < 2^31, found {self.seed}.")

    @property
    def passes(self) -> tuple[int, int]:
        """(number of passes, spp per pass) covering at least ``spp`` samples; the spp per
        pass is rounded as the sampler takes it."""
        n = max(1, math.ceil(self.width * self.height * self.spp / SAMPLES_PER_PASS))
        n = min(n, self.spp)
        return n, self._plan(n)[1]

    def _plan(self, n: int) -> tuple[str, int]:
        per = math.ceil(self.spp / n)
        if self.sampler == "auto":
            return auto_sampler(per, cap=max(per, SAMPLES_PER_PASS // (self.width
                                                                         * self.height)))
        return self.sampler, sampler_spp(self.sampler, per)

    @property
    def mitsuba_sampler(self) -> str:
        """The Mitsuba sampler rendered (``auto`` resolved for this size and count)."""
        return self._plan(self.passes[0])[0]

    @property
    def sampler_label(self) -> str:
        """The sampler as the commands report it (``auto`` with what it chose)."""
        if self.sampler == "auto":
            return f"auto: {self.mitsuba_sampler}"
        return self.sampler

    @property
    def effective_spp(self) -> int:
        """Samples per pixel actually rendered (passes x the sampler's rounded count)."""
        n, per = self.passes
        return n * per

    def spp_note(self) -> str | None:
        """One line when the sampler rounded the requested spp, else None."""
        if self.effective_spp == self.spp:
            return None
        how = ("next prime square" if self.mitsuba_sampler == "orthogonal"
               else "count it rounds up to")
        return (f"spp: {self.spp} requested, {self.effective_spp} rendered (the "
                f"{self.sampler_label} sampler takes {self.passes[1]} per pass, the "
                f"{how}; --sampler independent takes any count)")


def validate_size(width: int, height: int, spp: int) -> None:
    """Refuse zero, negative or absurd resolutions and sample counts (before allocating)."""
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_SIDE:
            raise HackError(f"image {name}: expected an integer in 1..{MAX_SIDE} pixels, found "
                            f"{v!r}. Pass e.g. --resolution 512.")
    if width * height > MAX_PIXELS:
        raise HackError(f"image size: expected at most {MAX_PIXELS} pixels, found "
                        f"{width}x{height}. Render a smaller image.")
    if not isinstance(spp, (int, np.integer)) or not 1 <= spp <= MAX_SPP:
        raise HackError(f"samples per pixel: expected an integer in 1..{MAX_SPP}, found "
                        f"{spp!r}. 16-64 spp is plenty for previews, 256+ for finals.")
