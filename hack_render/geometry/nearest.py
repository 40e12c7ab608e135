"""Nearest-point queries in 3-D: a k-d tree with the interface of SciPy's ``cKDTree.query``
the hair needs (nearest ``k``, a distance bound), on pykdtree.

The grooms' collisions query hundreds of thousands of control points against the skin's
vertices per pose (``hair.pose``) and per growth step (``hair.groom``). pykdtree answers
them about twice as fast as ``cKDTree`` (OpenMP over the queries, a leaner traversal) with
the same answers: the same nearest vertex and distance on every point of the grooms the
benchmark draws (bench/bench_dataset_hair.py; ``tests/test_nearest.py`` checks it against
``cKDTree`` with and without a bound). A point with no vertex within the bound gets
distance inf and index ``len(points)``, as in SciPy.

Threads: pykdtree's OpenMP runtime reads ``OMP_NUM_THREADS`` and ``OMP_WAIT_POLICY`` when
it loads (``hack_render.threads``: ``--threads``, and the package's passive wait policy).
"""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree


class PointTree:
    """A k-d tree over ``points`` (N, 3), float64."""

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
        if len(self.points) == 0:
            raise ValueError("PointTree: expected at least one point, found none.")
        self._tree = KDTree(self.points)

    @property
    def n(self) -> int:
        return len(self.points)

    def query(self, x: np.ndarray, k: int = 1, distance_upper_bound: float = np.inf
              ) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the ``k`` nearest points to each of ``x`` (..., 3):
        shapes (...) for k = 1, else (..., k); beyond ``distance_upper_bound``: inf and
        :attr:`n`, as ``scipy.spatial.cKDTree.query``."""
        x = np.asarray(x, np.float64)
        lead = x.shape[:-1]
        q = np.ascontiguousarray(x.reshape(-1, 3))
        bound = None if not np.isfinite(distance_upper_bound) else float(distance_upper_bound)
        if len(q) == 0:
            d, i = np.zeros((0, k)), np.zeros((0, k), np.intp)
        else:
            d, i = self._tree.query(q, k=k, distance_upper_bound=bound)
        d, i = np.asarray(d, np.float64), np.asarray(i).astype(np.intp)
        shape = lead if k == 1 else lead + (k,)
        return d.reshape(shape), i.reshape(shape)
