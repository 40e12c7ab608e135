"""The 468 face-mesh points as the 68 Multi-PIE landmarks, and their visibility.

Each of the 68 landmarks is a fixed affine combination (weights summing to 1) of a few
face-mesh points, calibrated on the model's renders against the true landmarks
(:mod:`hack_render.learn.dense68`, ``python -m hack_render.learn.dense68``): the shipped
``hack_render/data/dense68_mediapipe.npz``. Derived data: fitted on procedural renders
(hack_render.dataset.composites), not on annotated photographs.

Visibility (:meth:`DenseMap.visible`) comes from the dense mesh itself: its triangles
(the face mesh's tessellation, oriented so that a triangle facing the camera has a
positive signed area in image coordinates, x right and y down) tell which points face
the camera, and a z test against the nearer triangles tells which are behind the nose
or the cheek.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hack_render.errors import HackError

DEFAULT_FILE = Path(__file__).resolve().parents[1] / "data" / "dense68_mediapipe.npz"
FORMAT_VERSION = 1
N_DENSE = 468


def tessellation_triangles() -> np.ndarray:
    """(T, 3) triangles of MediaPipe's face-mesh tessellation (its edge list's
    3-cliques whose three edges are all tessellation edges), unoriented."""
    from mediapipe.python.solutions.face_mesh_connections import FACEMESH_TESSELATION

    nb: dict[int, set] = {}
    for a, b in FACEMESH_TESSELATION:
        nb.setdefault(a, set()).add(b)
        nb.setdefault(b, set()).add(a)
    tris = {tuple(sorted((a, b, c))) for a in nb for b in nb[a] if b > a
            for c in nb[a] & nb[b] if c > b}
    return np.array(sorted(tris), np.int64)


def signed_areas(xy: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(T,) twice the signed area of each triangle of points xy (N, 2)."""
    a, b, c = xy[tris[:, 0]], xy[tris[:, 1]], xy[tris[:, 2]]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


@dataclass
class DenseMap:
    """index (68, K) face-mesh point ids, weight (68, K) (rows sum to 1), triangles
    (T, 3) oriented (facing the camera: positive signed area), meta (provenance)."""

    index: np.ndarray
    weight: np.ndarray
    triangles: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.index = np.asarray(self.index, np.int64)
        self.weight = np.asarray(self.weight, np.float64)
        self.triangles = np.asarray(self.triangles, np.int64)
        ok = (self.index.shape == self.weight.shape and self.index.ndim == 2
              and self.index.shape[0] == 68 and self.triangles.ndim == 2
              and self.triangles.shape[1] == 3 and self.index.min() >= 0
              and self.index.max() < N_DENSE and self.triangles.max() < N_DENSE
              and np.isfinite(self.weight).all()
              and np.allclose(self.weight.sum(1), 1.0, atol=1e-6))
        if not ok:
            raise HackError(f"dense-to-68 map: expected index and weight (68, K) with rows "
                            f"summing to 1 and triangles (T, 3) into {N_DENSE} points, found "
                            f"index {self.index.shape}, weight {self.weight.shape}, "
                            f"triangles {self.triangles.shape}. Rebuild it: python -m "
                            "hack_render.learn.dense68")

    def to68(self, dense: np.ndarray) -> np.ndarray:
        """(468, >=2) dense points -> (68, 2) landmarks (same units)."""
        return np.einsum("lk,lkc->lc", self.weight, np.asarray(dense)[self.index, :2])

    def dense_visible(self, dense: np.ndarray) -> np.ndarray:
        """(468,) bool: the point's triangles face the camera (by area, at least half)."""
        area = signed_areas(dense[:, :2], self.triangles)
        front = np.zeros(N_DENSE)
        total = np.zeros(N_DENSE)
        for k in range(3):
            np.add.at(front, self.triangles[:, k], np.maximum(area, 0.0))
            np.add.at(total, self.triangles[:, k], np.abs(area))
        return front > 0.5 * np.maximum(total, 1e-12)

    def visible(self, dense: np.ndarray, margin: float = 0.03) -> np.ndarray:
        """(68,) bool: the landmark faces the camera (the weighted share of its points that
        do, over one half) and no triangle facing the camera lies in front of it by more
        than ``margin`` face sizes (z from the mesh model; smaller is nearer)."""
        dense = np.asarray(dense, np.float64)
        if dense.shape[1] < 3:
            return np.ones(68, bool)
        facing = (np.abs(self.weight) * self.dense_visible(dense)[self.index]).sum(1) \
            / np.abs(self.weight).sum(1) > 0.5
        pts = self.to68(dense)
        z = np.einsum("lk,lk->l", self.weight, dense[self.index, 2])
        size = float(np.ptp(dense[:, :2], axis=0).max())
        tri = self.triangles[signed_areas(dense[:, :2], self.triangles) > 0]
        a, b, c = (dense[tri[:, k]] for k in range(3))
        # barycentric coordinates of every landmark in every facing triangle: (68, T)
        v0, v1 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
        v2 = pts[:, None, :] - a[None, :, :2]
        den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
        den = np.where(np.abs(den) < 1e-12, 1e-12, den)
        s = (v2[..., 0] * v1[:, 1] - v2[..., 1] * v1[:, 0]) / den
        t = (v0[:, 0] * v2[..., 1] - v0[:, 1] * v2[..., 0]) / den
        inside = (s >= 0) & (t >= 0) & (s + t <= 1)
        zt = a[:, 2] + s * (b[:, 2] - a[:, 2]) + t * (c[:, 2] - a[:, 2])
        covered = (inside & (zt < z[:, None] - margin * size)).any(1)
        return facing & ~covered

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp.npz")
        np.savez_compressed(tmp, format_version=FORMAT_VERSION, index=self.index,
                            weight=self.weight, triangles=self.triangles,
                            meta=np.array(json.dumps(self.meta)))
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> DenseMap:
        path = Path(path)
        if not path.is_file():
            raise HackError(f"dense-to-68 map {path}: file not found. Rebuild it: python -m "
                            "hack_render.learn.dense68")
        with np.load(path) as z:
            if int(z["format_version"]) != FORMAT_VERSION:
                raise HackError(f"dense-to-68 map {path}: expected format version "
                                f"{FORMAT_VERSION}, found {int(z['format_version'])}.")
            return cls(z["index"], z["weight"], z["triangles"], json.loads(str(z["meta"])))


_DEFAULT: list = []


def load_map(path: str | Path | None = None) -> DenseMap:
    """The shipped map (cached) or one from ``path``."""
    if path is not None:
        return DenseMap.load(path)
    if not _DEFAULT:
        _DEFAULT.append(DenseMap.load(DEFAULT_FILE))
    return _DEFAULT[0]
