"""hack-render: the HACK head-and-neck model, rendered and fitted with Mitsuba 3.

Layers (see README.md and docs/):
  hack_render.geometry  G(beta, psi, theta, eta, tau) in torch
  appearance            A(alpha) texture model in torch
  hack_render.render    the only Mitsuba / Dr.Jit code
  hack_render.fit       inverse rendering

Importing any ``hack_render`` module (and ``appearance``, which imports this package
first) sets ``OMP_WAIT_POLICY=PASSIVE`` unless the environment already sets it: idle
OpenMP threads (torch's intra-op pool, MKL) then sleep instead of spinning. OpenMP reads
the variable once, when torch loads its runtime, so it takes effect only where this
package is imported before torch (always in the ``hack-render`` command); a script that
imports torch first sets it itself (``export OMP_WAIT_POLICY=PASSIVE``). Measured with two
torch threads on two cores shared with other jobs (``bench/bench_threads.py``): a B = 1
forward 53 ms with idle threads spinning, 6.7 ms sleeping (beside one more CPU-bound
process: 80 and 15 ms); a fit's torch step 341 and 19 ms. docs/troubleshooting.md
(Threads and cluster jobs) says what to set on a shared machine or a cluster.
"""

import os as _os

__version__ = "0.1.0"

#: The OpenMP wait policy the package chooses where the environment names none.
OMP_WAIT_POLICY = "PASSIVE"
_os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY)
