"""A landmark embedding calibrated to the detector (static, as in FLAME / DECA).

Each of the 68 landmarks is a point on the mesh surface: a triangle (its three vertex
ids) and barycentric coordinates. The model's own landmark vertices (ICT-FaceKit's 68) do
not follow dlib's annotation convention (dlib's points differ from them by ~6 % of the
inter-ocular distance on synthetic renders, docs/fit.md); a fit to dlib's
points through those vertices inherits that bias. The calibration
(:func:`hack_render.learn.landmark_calibration.calibrate`) chooses, per
landmark, the surface point whose projection is nearest (robust mean, in units of each
subject's inter-ocular distance) to what the detector finds on renders of synthetic
subjects with known geometry and cameras.

- :class:`LandmarkEmbedding`: ids + barycentrics, :meth:`~LandmarkEmbedding.points`
  (differentiable barycentric interpolation in torch), save/load with validation.
- :func:`load_default`: the shipped ``hack_render/data/landmark_embedding_dlib.npz``,
  or None (with a warning) when it is missing or does not fit the model.

The calibration (renders of synthetic subjects, the search, the shipped file) is
training code and lives in :mod:`hack_render.learn.landmark_calibration`; this module is
the runtime part the fitter loads.

Jawline landmarks (0-7, 9-16) are contours, matched in the fitter to the occluding contour
(:class:`~hack_render.fit.landmarks.JawContour`); they are not calibrated here and stay
one-hot on the model's landmark vertices (``calibrated`` is False for them in the file).
The chin (8) has no contour strip and is calibrated like the inner points.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.io.npz import write_npz

DEFAULT_FILE = Path(__file__).resolve().parents[1] / "data" / "landmark_embedding_dlib.npz"
#: Landmarks calibrated by default: all but the jawline contours (0-7, 9-16); the chin
#: (8) has no contour strip (a fixed point in the fitter), so it is calibrated too.
CALIBRATED = (8,) + tuple(range(17, 68))
#: Dataset-config overrides of the calibration renders (hack_render.dataset.config keys):
#: faces the frontal HOG detector finds (yaw within +-40 deg of camera and head
#: together), mild expressions, all lighting presets, procedural skin.
CALIBRATION_DATASET = {
    "render": {"resolution": 320, "spp": 16, "max_depth": 4, "tonemap": "aces",
               "soft_mask_samples": 0},
    "expression": {"p_neutral": 0.4, "max_active": 2, "intensity": [0.2, 0.6]},
    "neck": {"head_std_deg": [8.0, 12.0, 5.0], "joint_noise_deg": 1.0},
    "camera": {"views": 1, "yaw_deg": [-25.0, 25.0], "pitch_deg": [-8.0, 12.0],
               "distance_scale": [0.75, 1.0], "focal_mm": [50.0, 105.0]},
    "appearance": {"source": "seed"},
}
#: Calibration dataset seed: bench/bench_fit.py's subjects come from torch generators
#: seeded 100 + k, a different sampler, so the two sets share no subject.
CALIBRATION_SEED = 5150


# --- the embedding --------------------------------------------------------------------
def embedded_points(vertices: torch.Tensor, vertex_ids: torch.Tensor,
                    bary: torch.Tensor) -> torch.Tensor:
    """Barycentric interpolation: vertices (..., N, 3), vertex_ids (L, 3), bary (L, 3)
    -> (..., L, 3). Differentiable in ``vertices`` (and ``bary``)."""
    tri = vertices[..., vertex_ids, :]                       # (..., L, 3, 3)
    return (tri * bary.to(vertices.dtype)[..., None]).sum(-2)


@dataclass
class LandmarkEmbedding:
    """68 surface points: ``face_ids`` (68,) into the model's faces, ``vertex_ids``
    (68, 3) the triangles' corners (what the interpolation uses), ``bary`` (68, 3)
    barycentric coordinates (non-negative, summing to 1), ``calibrated`` (68,) bool,
    ``weights`` (68,) the landmark loss's per-point weights for this detector (inverse
    variances of its scatter, :func:`detector_weights`) or None."""

    face_ids: np.ndarray
    vertex_ids: np.ndarray
    bary: np.ndarray
    calibrated: np.ndarray
    meta: dict = field(default_factory=dict)
    weights: np.ndarray | None = None

    @classmethod
    def from_vertices(cls, landmark_indices, faces, meta: dict | None = None
                      ) -> LandmarkEmbedding:
        """The model's landmark vertices as an embedding (one-hot barycentrics)."""
        li = np.asarray(landmark_indices, dtype=np.int64)
        f = np.asarray(faces, dtype=np.int64)
        fid, vid, bary = [], [], []
        for v in li:
            rows, cols = np.nonzero(f == v)
            if len(rows) == 0:
                raise HackError(f"landmark embedding: vertex {v} is in no face.")
            fid.append(rows[0])
            vid.append(f[rows[0]])
            b = np.zeros(3)
            b[cols[0]] = 1.0
            bary.append(b)
        return cls(np.array(fid), np.array(vid), np.array(bary), np.zeros(len(li), bool),
                   dict(meta or {"provenance": "the model's landmark vertices"}))

    def points(self, vertices: torch.Tensor) -> torch.Tensor:
        """(..., N, 3) vertices -> (..., 68, 3) landmark points."""
        return embedded_points(vertices, torch.as_tensor(self.vertex_ids),
                               torch.as_tensor(self.bary))

    def points_np(self, vertices: np.ndarray) -> np.ndarray:
        return (vertices[..., self.vertex_ids, :] * self.bary[..., None]).sum(-2)

    def validate(self, num_vertices: int | None = None, faces=None,
                 where: str = "landmark embedding") -> LandmarkEmbedding:
        """Shapes, finiteness, barycentrics in [0, 1] summing to 1, ids in range and (with
        ``faces``) each triangle's corners equal to the model's face. HackError if not."""
        n = len(self.face_ids)
        ok = (self.face_ids.shape == (n,) and self.vertex_ids.shape == (n, 3)
              and self.bary.shape == (n, 3) and self.calibrated.shape == (n,) and n == 68)
        if not ok:
            raise HackError(f"{where}: expected 68 landmarks (face_ids (68,), vertex_ids and "
                            f"bary (68, 3)), found {self.face_ids.shape}, "
                            f"{self.vertex_ids.shape}, {self.bary.shape}.")
        if not np.all(np.isfinite(self.bary)) or np.any(self.bary < -1e-6) or \
                np.any(np.abs(self.bary.sum(1) - 1.0) > 1e-5):
            raise HackError(f"{where}: expected finite barycentrics in [0, 1] summing to 1.")
        if self.vertex_ids.min() < 0 or (num_vertices is not None
                                         and self.vertex_ids.max() >= num_vertices):
            raise HackError(f"{where}: vertex ids outside [0, {num_vertices}).")
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=np.float64)
            if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
                raise HackError(f"{where}: expected 68 finite weights >= 0 with a positive "
                                f"sum, found shape {w.shape}.")
        if faces is not None:
            f = np.asarray(faces)
            if self.face_ids.min() < 0 or self.face_ids.max() >= len(f):
                raise HackError(f"{where}: face ids outside [0, {len(f)}).")
            if not np.array_equal(f[self.face_ids], self.vertex_ids):
                raise HackError(f"{where}: its triangles are not the model's faces (another "
                                "topology?). Rebuild it: hack-render learn landmark-embedding.")
        return self

    def save(self, path: str | Path) -> Path:
        return write_npz(path, dict(face_ids=self.face_ids.astype(np.int64),
                                    vertex_ids=self.vertex_ids.astype(np.int64),
                                    bary=self.bary.astype(np.float64),
                                    calibrated=self.calibrated.astype(bool),
                                    meta=np.array(json.dumps(self.meta, sort_keys=True)),
                                    **({} if self.weights is None else
                                       {"weights": np.asarray(self.weights, np.float64)})),
                         compressed=True)

    @classmethod
    def load(cls, path: str | Path, model=None) -> LandmarkEmbedding:
        path = Path(path)
        if not path.is_file():
            raise HackError(f"landmark embedding {path}: file not found.")
        try:
            with np.load(path, allow_pickle=False) as z:
                emb = cls(z["face_ids"].astype(np.int64), z["vertex_ids"].astype(np.int64),
                          z["bary"].astype(np.float64), z["calibrated"].astype(bool),
                          json.loads(str(z["meta"])),
                          z["weights"].astype(np.float64) if "weights" in z.files else None)
        except (KeyError, ValueError, OSError) as err:
            raise HackError(f"landmark embedding {path}: not a landmark embedding file "
                            f"({err}).") from err
        if model is not None:
            return emb.validate(model.num_vertices, model.faces.numpy(), str(path))
        return emb.validate(where=str(path))


class EmbeddingWarning(UserWarning):
    """The calibrated landmark embedding is unavailable; the model's vertices are used."""


def load_default(model, path: str | Path | None = None) -> LandmarkEmbedding | None:
    """The shipped (or given) embedding validated against ``model``, or None with a
    warning when the file is missing or does not fit the model."""
    path = Path(path) if path is not None else DEFAULT_FILE
    try:
        return LandmarkEmbedding.load(path, model)
    except HackError as err:
        warnings.warn(f"{err} Using the model's landmark vertices instead.", EmbeddingWarning,
                      stacklevel=2)
        return None
