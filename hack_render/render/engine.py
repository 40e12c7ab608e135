"""Choosing and activating a Mitsuba variant (the engine adapter's entry point).

Order of preference: ``cuda_ad_rgb`` when a CUDA GPU works, else ``llvm_ad_rgb`` (CPU,
JIT-compiled through LLVM), else ``scalar_rgb`` with a warning (no inverse rendering, and
the skin material falls back to Mitsuba's ``principled``). ``HACK_RENDER_VARIANT`` or the
CLI's ``--variant`` override the choice. Every other module in this package calls
:func:`ensure_variant` before touching ``mitsuba``.
"""

from __future__ import annotations

import os
import threading
import warnings
import weakref
from dataclasses import dataclass

from hack_render import threads
from hack_render.errors import HackError
from hack_render.render import integrator, skin_bsdf

ENV_VAR = "HACK_RENDER_VARIANT"
PREFERENCE = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
#: Oldest LLVM that Dr.Jit's kernels compile with: 14 and 15 abort with
#: "Cannot select: fminimum" on Mitsuba 3.6+ kernels.
MIN_LLVM = (16, 0, 0)
LLVM_FIX = (
    "Install a current LLVM with `apt-get install libllvm19` (Debian/Ubuntu; "
    "`dnf install llvm-libs` on Fedora, `brew install llvm` on macOS), or point "
    "DRJIT_LIBLLVM_PATH at an existing libLLVM.so of version 16 or newer."
)


@dataclass(frozen=True)
class Backends:
    """What this machine offers: Mitsuba's compiled variants and Dr.Jit's JIT backends."""

    variants: tuple[str, ...]
    cuda: bool
    llvm: bool
    llvm_version: tuple[int, int, int]


class VariantWarning(UserWarning):
    """Rendering falls back to a slower or less capable Mitsuba variant."""


def probe_backends() -> Backends:
    """Ask Mitsuba and Dr.Jit what is available here (cheap; compiles nothing)."""
    import drjit as dr
    import mitsuba as mi

    llvm = bool(dr.has_backend(dr.JitBackend.LLVM))
    version = tuple(dr.detail.llvm_version()) if llvm else (0, 0, 0)
    return Backends(tuple(mi.variants()), bool(dr.has_backend(dr.JitBackend.CUDA)), llvm,
                    version)  # type: ignore[arg-type]


def _usable(variant: str, b: Backends) -> str | None:
    """None if ``variant`` can run on ``b``, else the reason it cannot."""
    if variant not in b.variants:
        return f"this Mitsuba build has no variant {variant!r} (it has {', '.join(b.variants)})"
    if variant.startswith("cuda") and not b.cuda:
        return "no working CUDA GPU/driver was found"
    if variant.startswith("llvm"):
        if not b.llvm:
            return "Dr.Jit could not load LLVM (libLLVM.so)"
        if b.llvm_version < MIN_LLVM:
            found = ".".join(map(str, b.llvm_version))
            return f"LLVM {found} is too old (need 16 or newer; 19 is tested)"
    return None


def choose_variant(requested: str | None = None, backends: Backends | None = None) -> str:
    """Pick the Mitsuba variant to use.

    Args:
        requested: an explicit variant (CLI ``--variant``); else ``$HACK_RENDER_VARIANT``;
            else the first usable one of :data:`PREFERENCE`.
        backends: what is available (tests pass a made-up one); probed when None.

    Returns:
        The variant name. Warns (:class:`VariantWarning`) when falling back to
        ``scalar_rgb``, naming the LLVM package to install.

    Raises:
        HackError: if an explicitly requested variant cannot run here.
    """
    b = backends or probe_backends()
    requested = requested or os.environ.get(ENV_VAR) or None
    if requested:
        why = _usable(requested, b)
        if why:
            fix = LLVM_FIX if requested.startswith("llvm") else (
                f"Pick one of {', '.join(v for v in PREFERENCE if not _usable(v, b))} "
                f"with --variant or {ENV_VAR}, or unset it to choose automatically.")
            raise HackError(f"Mitsuba variant {requested!r}: expected a variant that runs "
                            f"here, found that {why}. {fix}")
        return requested
    for variant in PREFERENCE[:2]:
        if not _usable(variant, b):
            return variant
    if "scalar_rgb" not in b.variants:
        raise HackError("Mitsuba: expected one of the variants cuda_ad_rgb, llvm_ad_rgb or "
                        f"scalar_rgb, found only {', '.join(b.variants)}. Reinstall mitsuba "
                        "from PyPI (`pip install mitsuba`).")
    warnings.warn(
        f"Rendering with scalar_rgb: {_usable('llvm_ad_rgb', b)}. Scalar rendering is slow, "
        f"inverse rendering (fitting) is unavailable and skin uses Mitsuba's principled "
        f"BSDF instead of the hack_skin plugin. {LLVM_FIX}", VariantWarning, stacklevel=2)
    return "scalar_rgb"


def ensure_variant(requested: str | None = None) -> str:
    """Activate a variant once per process (see :func:`choose_variant`) and return it.

    A later call with a different explicit ``requested`` switches variants; a call
    without one keeps whatever is active.
    """
    import mitsuba as mi

    current = mi.variant()
    if current is not None and (requested is None or requested == current):
        if requested is None and os.environ.get(ENV_VAR) not in (None, "", current):
            requested = os.environ[ENV_VAR]
        else:
            return current
    variant = choose_variant(requested)
    if variant != current:
        mi.set_variant(variant)
        register_plugins()
        threads.apply_drjit()  # a `--threads` given before Dr.Jit was loaded
    return variant


_registered: set[str] = set()


def register_plugins() -> None:
    """Register the project's Python plugins, the ``hack_skin`` BSDF and the ``hack_path``
    integrator, for the active variant (JIT variants only; idempotent)."""
    import mitsuba as mi

    variant = mi.variant()
    if variant in _registered or not is_jit(variant):
        return

    bsdf, integ = skin_bsdf.make_class(), integrator.make_class()
    mi.register_bsdf(skin_bsdf.NAME, lambda props: bsdf(props))
    mi.register_integrator(integrator.NAME, lambda props: integ(props))
    _registered.add(variant)


def is_jit(variant: str | None = None) -> bool:
    """True for the JIT (differentiable, vectorised) variants."""
    import mitsuba as mi

    v = variant or mi.variant() or ""
    return v.startswith(("cuda", "llvm"))


def set_thread_count(n: int) -> None:
    """Limit Dr.Jit's CPU thread pool to ``n`` threads (e.g. one per Ray worker, so that
    several worker processes on one machine do not oversubscribe its cores)."""
    import drjit as dr

    if n < 1:
        raise HackError(f"thread count: expected >= 1, found {n}.")
    dr.set_thread_count(int(n))


# --- where Mitsuba objects die ---------------------------------------------------------
# Mitsuba releases the GIL while it renders, and Dr.Jit keeps every BSDF, emitter and
# shape of the process in one registry that a render walks as it traces. An object that
# dies on another thread meanwhile (a garbage cycle holding an old scene, collected
# when the dataset's writer thread happens to allocate) changes that registry under the
# render: "jit_registry_id(...): pointer is not registered", or a segmentation fault
# (found in CI: a resumed dataset run in the process of an interrupted one). So the
# objects of a dropped scene are parked instead, whichever thread drops it, and freed
# by the thread that renders, at the start of its next scene or render.
_parked: list[tuple] = []
_parked_lock = threading.Lock()


def release_when_safe(owner, *objects) -> None:
    """Keep ``objects`` (Mitsuba scenes, their parameters, integrators) alive past
    ``owner``'s death until :func:`release_parked` frees them on the rendering thread.
    ``objects`` must not refer back to ``owner`` (it would then never die)."""
    fin = weakref.finalize(owner, _park, objects)
    fin.atexit = False


def _park(objects: tuple) -> None:
    with _parked_lock:
        _parked.append(objects)


def release_parked() -> int:
    """Free the Mitsuba objects of owners that died since the last call (see
    :func:`release_when_safe`); call where no render is in progress. Returns how many
    owners' objects were freed."""
    with _parked_lock:
        batch = _parked[:]
        _parked.clear()
    n = len(batch)
    del batch  # the objects die here, on this thread
    return n
