"""CPU threads of the engines: torch's intra-op pool, Dr.Jit's pool and Open Image Denoise's.

One number for all three, set by :func:`set_threads` (the long commands' ``--threads``):

- torch: ``torch.set_num_threads(n)`` when torch is loaded, else ``OMP_NUM_THREADS``,
  which torch reads as it loads (a render whose pose comes from the disk cache never
  loads torch);
- Dr.Jit: ``drjit.set_thread_count(n)``, at once when Dr.Jit is loaded, else when
  ``hack_render.render.engine`` activates a Mitsuba variant (:func:`apply_drjit`), so that
  a command that never renders never pays for importing it;
- OIDN: ``OIDN_NUM_THREADS``, read when the denoiser creates its device (the first
  denoised image of the process).

The OpenMP wait policy (``OMP_WAIT_POLICY``, set by the package's ``__init__`` before torch
loads) is the other half of thread behaviour: see docs/troubleshooting.md (cluster jobs)
for what to set where other jobs share the cores.

Imports nothing heavy: drjit is imported by :func:`apply_drjit` alone, once a variant is
active; torch never (it is set through ``sys.modules`` when loaded).
"""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager

from hack_render.errors import HackError

#: The most threads ``--threads`` accepts (a sanity bound, not a hardware one).
MAX_THREADS = 1024
#: Torch's intra-op threads when a command is not given ``--threads`` (see
#: :func:`default_torch_threads`): small-tensor work (a B = 1 forward, skin maps of one
#: subject) gains little from more threads and loses much when other jobs share the cores.
DEFAULT_TORCH_THREADS = 2

_requested: int | None = None
#: Per Python thread: the torch thread count outside the innermost :func:`small_work`.
_outer = threading.local()


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

    Loads none of them: torch, when not loaded yet, reads ``OMP_NUM_THREADS`` (set here)
    as it loads; Dr.Jit gets the count when a variant is activated.

    Raises:
        HackError: n is not a whole number in 1..MAX_THREADS.
    """
    global _requested
    n = check_threads(n)
    _requested = n
    _set_torch_threads(n)
    os.environ["OIDN_NUM_THREADS"] = str(n)
    if "drjit" in sys.modules:
        apply_drjit()
    return n


def _set_torch_threads(n: int) -> None:
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
    else:  # read by torch's OpenMP runtime when it loads
        os.environ["OMP_NUM_THREADS"] = str(n)


def apply_drjit() -> None:
    """Give Dr.Jit the requested thread count (no-op when none was requested)."""
    if _requested is None:
        return
    import drjit as dr

    if dr.thread_count() != _requested:
        dr.set_thread_count(_requested)


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity mask, e.g. a cluster job's
    allocation, where the platform has one; else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def default_torch_threads() -> int:
    """Torch threads for a command run without ``--threads``: at most
    :data:`DEFAULT_TORCH_THREADS`, fewer when fewer cores are available or torch (or
    ``OMP_NUM_THREADS``) says fewer."""
    if "torch" in sys.modules:
        have = sys.modules["torch"].get_num_threads()
    else:
        env = os.environ.get("OMP_NUM_THREADS", "")
        have = int(env) if env.isdigit() and int(env) > 0 else available_cores()
    return max(1, min(DEFAULT_TORCH_THREADS, have, available_cores()))


def command_threads(n: int | None, torch_default: int | None = None) -> int | None:
    """A command's thread set-up: ``--threads n`` for every engine when given; else torch
    at ``torch_default`` (default: :func:`default_torch_threads`) and Dr.Jit and OIDN at
    their own defaults (every core). A user's ``OMP_NUM_THREADS`` is kept when torch is
    not loaded yet. Returns n (None when not given)."""
    if n is not None:
        return set_threads(n)
    want = default_torch_threads() if torch_default is None else check_threads(torch_default)
    if "torch" in sys.modules or "OMP_NUM_THREADS" not in os.environ:
        _set_torch_threads(want)
    return None


@contextmanager
def small_work(active: bool = True):
    """Torch on one thread inside (when ``active`` and torch has more): for a chain of small
    operations, such as a B = 1 forward's rotations, joints, skinning and MLPs. Under
    OpenMP's passive wait policy (the package's default) every parallel region wakes the
    sleeping workers, which costs more than a small operation's work: a (1372, 9) x (9, 12)
    product measured 0.08 ms on 2 threads and 0.011 ms on one. :func:`bulk_work` gives a
    streaming product inside the block the caller's threads back. Torch's count is the
    calling thread's own (OpenMP's per-thread setting and MKL's local one), restored on
    exit."""
    torch = sys.modules["torch"]
    n = torch.get_num_threads()
    if not active or n == 1:
        yield
        return
    outer = getattr(_outer, "n", None)
    _outer.n = n
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
        _outer.n = outer


@contextmanager
def bulk_work():
    """Inside :func:`small_work`: the caller's torch thread count again, for a product that
    streams megabytes (a basis product), where more threads may read memory faster."""
    n = getattr(_outer, "n", None)
    if n is None:
        yield
        return
    torch = sys.modules["torch"]
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(1)


#: The package's helper thread (:func:`beside`): one per process, started at the first use.
_helper: ThreadPoolExecutor | None = None
_helper_lock = threading.Lock()


def _one_torch_thread() -> None:
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def beside(fn, *args) -> Future:
    """Run ``fn(*args)`` on the package's helper thread (torch on one thread there) and
    return its future: for one streaming product that a single thread reads at the
    memory's speed, run while the calling thread does other work (a B = 1 forward's
    expression products, 60 MB, beside its small operations:
    :meth:`hack_render.geometry.model.HackModel.forward`). Callers use it only where
    torch has two or more threads (``--threads 1`` keeps everything on one). Calls from
    several threads queue on the one helper. A forked child starts its own."""
    global _helper
    with _helper_lock:
        if _helper is None:
            _helper = ThreadPoolExecutor(1, thread_name_prefix="hack-render-beside",
                                         initializer=_one_torch_thread)
        return _helper.submit(fn, *args)


def spare_core() -> bool:
    """Whether a core of this process's is idle now: fewer threads runnable on the machine
    (the kernel's instantaneous count, ``/proc/loadavg``'s fourth field, the caller
    included) than :func:`available_cores`. False where the count is not known. What
    :func:`beside`'s callers check first: on cores that other work keeps busy, a second
    thread of ours only takes turns with ours (a B = 1 forward at S = 20 beside one
    CPU-bound process, interleaved in one process: 1.56x smplx with the helper forced,
    1.48x without; docs/model.md, "Geometry timings")."""
    try:
        with open("/proc/loadavg", "rb") as f:
            running = int(f.read().split()[3].split(b"/")[0])
    except (OSError, ValueError, IndexError):
        return False
    return running < available_cores()


def _forget_helper() -> None:
    """In a forked child: the parent's helper thread does not exist there."""
    global _helper, _helper_lock
    _helper = None
    _helper_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_helper)
