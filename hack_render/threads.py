"""CPU threads of the engines: torch's intra-op pool, Dr.Jit's pool and Open Image Denoise's.

One number for all three, set by :func:`set_threads` (the long commands' ``--threads``):

- torch: ``torch.set_num_threads(n)``, at once;
- Dr.Jit: ``drjit.set_thread_count(n)``, at once when Dr.Jit is loaded, else when
  ``hack_render.render.engine`` activates a Mitsuba variant (:func:`apply_drjit`), so that
  a command that never renders never pays for importing it;
- OIDN: ``OIDN_NUM_THREADS``, read when the denoiser creates its device (the first
  denoised image of the process).

The OpenMP wait policy (``OMP_WAIT_POLICY``, set by the package's ``__init__`` before torch
loads) is the other half of thread behaviour: see docs/troubleshooting.md (cluster jobs)
for what to set where other jobs share the cores.

Imports nothing heavy at module level: torch and drjit are imported by the functions that
set them.
"""

from __future__ import annotations

import os
import sys

from hack_render.errors import HackError

#: The most threads ``--threads`` accepts (a sanity bound, not a hardware one).
MAX_THREADS = 1024
#: Torch's intra-op threads when a command is not given ``--threads`` (see
#: :func:`default_torch_threads`): small-tensor work (a B = 1 forward, skin maps of one
#: subject) gains little from more threads and loses much when other jobs share the cores.
DEFAULT_TORCH_THREADS = 2

_requested: int | None = None


def requested() -> int | None:
    """The thread count :func:`set_threads` was last given (None: never called)."""
    return _requested


def check_threads(n, name: str = "--threads") -> int:
    """``n`` as a thread count in 1..MAX_THREADS, else HackError naming ``name``."""
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_THREADS:
        raise HackError(f"{name}: expected a whole number of threads in 1..{MAX_THREADS}, "
                        f"found {n!r}.")
    return n


def set_threads(n: int) -> int:
    """Use ``n`` CPU threads in torch, Dr.Jit and OIDN (see the module docstring); returns n.

    Raises:
        HackError: n is not a whole number in 1..MAX_THREADS.
    """
    global _requested
    n = check_threads(n)
    _requested = n
    import torch

    torch.set_num_threads(n)
    os.environ["OIDN_NUM_THREADS"] = str(n)
    if "drjit" in sys.modules:
        apply_drjit()
    return n


def apply_drjit() -> None:
    """Give Dr.Jit the requested thread count (no-op when none was requested)."""
    if _requested is None:
        return
    import drjit as dr

    if dr.thread_count() != _requested:
        dr.set_thread_count(_requested)


def default_torch_threads() -> int:
    """Torch threads for a command run without ``--threads``: at most
    :data:`DEFAULT_TORCH_THREADS`, fewer when torch would use fewer (``OMP_NUM_THREADS``,
    a CPU affinity mask)."""
    import torch

    return max(1, min(DEFAULT_TORCH_THREADS, torch.get_num_threads()))


def command_threads(n: int | None) -> int | None:
    """A command's thread set-up: ``--threads n`` for every engine when given; else torch
    at :func:`default_torch_threads` and Dr.Jit and OIDN at their own defaults (every
    core). Returns n (None when not given)."""
    if n is not None:
        return set_threads(n)
    import torch

    torch.set_num_threads(default_torch_threads())
    return None
