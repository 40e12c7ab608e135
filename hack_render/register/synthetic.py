"""Synthetic scans with known truth, for tests and the registration benchmark.

Derived data, labelled as such: a scan here is a model surface (any model file's, e.g.
a leave-k-out truth model) re-tessellated, with noise, holes and a random similarity
transform, the way a capture differs from a registration. Nothing in here is a real scan.

:func:`make_scan` takes posed vertices and the model's faces and returns a
``trimesh.Trimesh`` plus the transform and units, so the truth (the vertices in the
scan's frame) is known exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.register.fitting import faces_within, model_subsets
from hack_render.register.measure import MeshDistance
from hack_render.register.scan import vertex_normals


@dataclass
class SyntheticScan:
    """A synthetic scan and its truth.

    Attributes:
        vertices: (M, 3) scan vertices in the scan's units and frame.
        faces: (F, 3) triangles.
        truth: (N, 3) the model vertices that made it, in the scan's units and frame.
        scale, R, t: model metres -> scan: x_scan = scale * R x + t (scale = units per metre).
        units: "m", "cm" or "mm".
        clean: (M, 3) scan vertices before noise (scan units).
    """

    vertices: np.ndarray
    faces: np.ndarray
    truth: np.ndarray
    scale: float
    R: np.ndarray
    t: np.ndarray
    units: str
    clean: np.ndarray

    def mesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation (3, 3)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def scan_faces(model, vertices: np.ndarray) -> np.ndarray:
    """The faces a scanner sees: the outer skin and the front halves of the eyeballs."""
    skin, cand = model_subsets(model)
    faces = model.faces.numpy()
    f = faces_within(faces, cand)
    eye = ~np.isin(f, skin).all(1)
    centre = vertices[np.setdiff1d(cand, skin)].mean(0)
    front = (vertices[f].mean(1) - centre)[:, 2] > 0.0
    return f[~eye | front]


def retessellate(v: np.ndarray, f: np.ndarray, rng: np.random.Generator, jitter: float = 0.3
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The same surface with other vertices: each triangle split in four, every vertex slid
    along the surface by up to ``jitter`` of its local edge length and put back on it."""
    import trimesh

    nv, nf = trimesh.remesh.subdivide(v, f)
    nv, nf = np.asarray(nv), np.asarray(nf)
    edge = np.linalg.norm(nv[nf[:, 0]] - nv[nf[:, 1]], axis=1)
    local = np.zeros(len(nv))
    np.maximum.at(local, nf[:, 0], edge)
    moved = nv + rng.uniform(-1, 1, nv.shape) * jitter * local[:, None]
    _, on_surface, _ = MeshDistance(v, f).closest(moved)
    return on_surface, nf


def punch_holes(v: np.ndarray, f: np.ndarray, rng: np.random.Generator, count: int,
                radius: tuple[float, float] = (0.006, 0.012)) -> np.ndarray:
    """Faces left after removing ``count`` discs of the given radius range (metres)."""
    keep = np.ones(len(f), bool)
    centres = v[rng.choice(len(v), size=count, replace=False)]
    fc = v[f].mean(1)
    for c, r in zip(centres, rng.uniform(*radius, size=count)):
        keep &= np.linalg.norm(fc - c, axis=1) > r
    return f[keep]


def make_scan(model, vertices: np.ndarray, seed: int = 0, noise_m: float = 0.0005,
              holes: int = 3, transform: bool = True, retessellated: bool = True
              ) -> SyntheticScan:
    """A synthetic scan of posed model ``vertices`` (N, 3), metres.

    Args:
        noise_m: standard deviation of the noise along the normals, metres.
        holes: discs of 6-12 mm radius removed.
        transform: a random rotation, translation and unit (m, cm or mm); else metres as is.
    """
    rng = np.random.default_rng(seed)
    f = scan_faces(model, vertices)
    v = vertices
    if retessellated:
        v, f = retessellate(vertices, f, rng)
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    v, f = v[used], remap[f]
    if holes:
        f = punch_holes(v, f, rng, holes)
        used = np.unique(f)
        remap = np.full(len(v), -1)
        remap[used] = np.arange(len(used))
        v, f = v[used], remap[f]
    clean = v.copy()
    if noise_m > 0:
        v = v + vertex_normals(v, f) * rng.normal(0, noise_m, (len(v), 1))
    scale, R, t, units = 1.0, np.eye(3), np.zeros(3), "m"
    if transform:
        units = str(rng.choice(["m", "cm", "mm"]))
        scale = {"m": 1.0, "cm": 100.0, "mm": 1000.0}[units]
        R = random_rotation(rng)
        t = rng.uniform(-0.5, 0.5, 3) * scale
    move = lambda x: scale * x @ R.T + t
    return SyntheticScan(move(v), f, move(np.asarray(vertices)), scale, R, t, units, move(clean))
