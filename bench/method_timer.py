"""Seconds spent in wrapped methods, per name: the benchmarks' way to split a pipeline's
time into its parts without touching the library (bench-only patching).

    from method_timer import MethodTimer     # bench/ is on sys.path when run as a script
    timer = MethodTimer()
    timer.wrap(HeadScene, "render")          # every later call is timed
    ...
    parts = timer.take()                     # {"render": seconds}, and the totals reset
"""

from __future__ import annotations

import time


class MethodTimer:
    """Accumulates the seconds spent in wrapped methods, per name."""

    def __init__(self, clock=time.perf_counter):
        """``clock``: what is summed; ``time.process_time`` gives the process's CPU seconds
        (every thread's: meaningful where the wrapped calls run one at a time)."""
        self.total: dict[str, float] = {}
        self.clock = clock

    def wrap(self, owner, method: str, name: str | None = None):
        """Replace ``owner.method`` (a class's, a module's) by a timed version that adds
        its seconds to ``name`` (default the method's name), exceptions included; returns
        the original."""
        orig = getattr(owner, method)
        key = name or method

        def timed(*args, **kwargs):
            t0 = self.clock()
            try:
                return orig(*args, **kwargs)
            finally:
                self.total[key] = self.total.get(key, 0.0) + self.clock() - t0

        setattr(owner, method, timed)
        return orig

    def take(self) -> dict[str, float]:
        """The seconds per name since the last call (or the wrapping), and a reset."""
        out, self.total = self.total, {}
        return out
