"""A learned refinement of dlib's inner landmarks toward the embedding's surface points.

dlib's 68 points are 4.1 % of the inter-ocular distance (rms) from the calibrated
embedding's points on synthetic renders (docs/fit.md): 2.3 % of it is an
error common to all faces (the embedding absorbs most of it) and 3.4 % differs from face
to face, a bias of dlib's shape model that no calibration of its points removes. This
module learns that per-face part from the image, as a supervised descent method (SDM,
Xiong and De la Torre, CVPR 2013) started at dlib's points: each stage reads HOG-like
gradient histograms in a patch about every inner point (in the frame that aligns the
current points to a mean shape, so the features do not depend on the face's size or
roll) and moves all inner points at once by a ridge regression of those features,
``x <- x + R^T(A phi(x) + b) / s``.

It is trained (:func:`hack_render.learn.landmark_refiner_training.train`,
``hack-render learn landmark-refiner``) on synthetic renders
of the default model (the dataset sampler with the landmark calibration's settings,
:data:`~hack_render.fit.landmark_embedding.CALIBRATION_DATASET`) whose targets are the
embedding's points projected from the known geometry, each render also mirrored and its
starting points jittered. The jawline (0-7, 9-16) is left alone: the fitter matches it as
contours. The shipped file is ``hack_render/data/landmark_refiner_dlib.npz`` (derived:
synthetic renders only, labelled in its metadata); the fitter applies it to dlib's points
(``landmarks.refiner``), never to landmark files.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.fit.metrics import similarity_transform
from hack_render.io.npz import write_npz

DEFAULT_FILE = Path(__file__).resolve().parents[1] / "data" / "landmark_refiner_dlib.npz"
#: The points the refiner moves: the chin and the 51 inner points (dlib's 9, 18-68).
INNER = np.array((8,) + tuple(range(17, 68)))
#: 68-point index of each landmark's mirror image (iBUG order).
MIRROR = np.array(list(range(16, -1, -1)) + list(range(26, 16, -1)) + [27, 28, 29, 30]
                  + [35, 34, 33, 32, 31] + [45, 44, 43, 42, 47, 46] + [39, 38, 37, 36, 41, 40]
                  + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
                  + [64, 63, 62, 61, 60, 67, 66, 65])


@dataclass(frozen=True)
class PatchSpec:
    """The features' sampling: ``size`` x ``size`` samples ``step`` apart (inter-ocular
    units) about each point, histograms of ``bins`` unsigned gradient orientations over
    ``cells`` x ``cells`` cells, L2-normalised, clipped at ``clip`` and normalised again
    (Dalal and Triggs' L2-Hys) per point."""

    size: int = 16
    step: float = 0.02
    cells: int = 4
    bins: int = 9
    clip: float = 0.2

    @property
    def dim(self) -> int:
        return len(INNER) * self.cells * self.cells * self.bins


def to_gray(rgb8: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 (or (H, W)) -> (H, W) float32 luma in [0, 1] (Rec. 601)."""
    g = np.asarray(rgb8, dtype=np.float32) / 255.0
    return g[..., :3] @ np.array([0.299, 0.587, 0.114], np.float32) if g.ndim == 3 else g


def normalising_frame(points: np.ndarray, mean_shape: np.ndarray):
    """(s, R, t): the similarity taking the inner points (pixels) onto the mean shape."""
    return similarity_transform(points[INNER], mean_shape[INNER])


def patch_features(gray: np.ndarray, points: np.ndarray, mean_shape: np.ndarray,
                   spec: PatchSpec = PatchSpec()) -> tuple[np.ndarray, float, np.ndarray]:
    """HOG-like features (``spec.dim``,) of patches about the inner ``points`` (68, 2),
    pixels, in ``gray`` (H, W); plus (s, R) of the pixel -> normalised frame."""
    from scipy.ndimage import map_coordinates

    s, R, _ = normalising_frame(points, mean_shape)
    n = spec.size + 2  # one more sample each side for central differences
    o = (np.arange(n) - (n - 1) / 2.0) * spec.step
    oy, ox = np.meshgrid(o, o, indexing="ij")
    off = np.stack([ox, oy], -1).reshape(-1, 2) @ R / s     # normalised -> pixel offsets
    q = points[INNER][:, None, :] + off[None]               # (L, n*n, 2) x, y
    # pixel centres at +0.5 (Detection's convention): sample index = coordinate - 0.5
    vals = map_coordinates(gray, [q[..., 1].ravel() - 0.5, q[..., 0].ravel() - 0.5],
                           order=1, mode="nearest").reshape(len(INNER), n, n)
    gx = vals[:, 1:-1, 2:] - vals[:, 1:-1, :-2]
    gy = vals[:, 2:, 1:-1] - vals[:, :-2, 1:-1]
    mag = np.hypot(gx, gy)
    ang = np.mod(np.arctan2(gy, gx), np.pi)
    b = np.minimum((ang * (spec.bins / np.pi)).astype(np.int64), spec.bins - 1)
    cell = np.arange(spec.size) * spec.cells // spec.size
    L = len(INNER)
    flat = ((np.arange(L)[:, None, None] * spec.cells + cell[None, :, None]) * spec.cells
            + cell[None, None, :]) * spec.bins + b
    hist = np.bincount(flat.ravel(), weights=mag.ravel(),
                       minlength=L * spec.cells * spec.cells * spec.bins)
    hist = hist.reshape(L, -1)
    hist /= np.linalg.norm(hist, axis=1, keepdims=True) + 1e-3
    hist = np.minimum(hist, spec.clip)
    hist /= np.linalg.norm(hist, axis=1, keepdims=True) + 1e-3
    return hist.ravel(), s, R


def mirror_points(points: np.ndarray, width: int) -> np.ndarray:
    """68 points (pixels, centres at +0.5) of the horizontally mirrored image."""
    m = np.asarray(points, np.float64)[MIRROR].copy()
    m[:, 0] = width - m[:, 0]
    return m


@dataclass
class LandmarkRefiner:
    """SDM stages: ``W`` (K, D, 2L) ridge weights, ``feat_mean`` (K, D), ``delta_mean``
    (K, 2L), over ``mean_shape`` (68, 2) (inter-ocular distance 1, inner points centred);
    ``weights`` (68,): the landmark loss's per-point weights for the refined points (as
    the embedding file's, :func:`~hack_render.fit.landmark_embedding.detector_weights`)."""

    W: np.ndarray
    feat_mean: np.ndarray
    delta_mean: np.ndarray
    mean_shape: np.ndarray
    spec: PatchSpec = field(default_factory=PatchSpec)
    weights: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def stages(self) -> int:
        return len(self.W)

    def step(self, gray: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
        f, s, R = patch_features(gray, points, self.mean_shape, self.spec)
        d = ((f - self.feat_mean[k]) @ self.W[k] + self.delta_mean[k]).reshape(-1, 2)
        out = np.array(points, np.float64, copy=True)
        out[INNER] += (d / s) @ R
        return out

    def refine(self, image: np.ndarray, points: np.ndarray,
               stages: int | None = None) -> np.ndarray:
        """Refined (68, 2) points (pixels) from dlib's ``points`` in ``image`` ((H, W, 3)
        uint8 or a gray float image in [0, 1]); the jawline's 16 contour points unchanged."""
        gray = to_gray(image) if np.asarray(image).dtype == np.uint8 else \
            np.asarray(image, np.float32)
        pts = np.asarray(points, np.float64)
        if pts.shape != (68, 2) or not np.all(np.isfinite(pts)):
            raise HackError(f"landmark refiner: expected 68 finite (x, y) points, found "
                            f"shape {pts.shape}.")
        for k in range(self.stages if stages is None else min(stages, self.stages)):
            pts = self.step(gray, pts, k)
        return pts

    def validate(self, where: str = "landmark refiner") -> LandmarkRefiner:
        L2 = 2 * len(INNER)
        K = len(self.W)
        ok = (K >= 1 and self.W.ndim == 3 and self.W.shape[1:] == (self.spec.dim, L2)
              and self.feat_mean.shape == (K, self.spec.dim)
              and self.delta_mean.shape == (K, L2) and self.mean_shape.shape == (68, 2))
        if not ok:
            raise HackError(f"{where}: inconsistent shapes (W {self.W.shape}, features "
                            f"{self.feat_mean.shape}, deltas {self.delta_mean.shape}, mean "
                            f"shape {self.mean_shape.shape}; patch dimension {self.spec.dim}).")
        arrays = (self.W, self.feat_mean, self.delta_mean, self.mean_shape)
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise HackError(f"{where}: non-finite values.")
        if self.weights is not None:
            w = np.asarray(self.weights)
            if w.shape != (68,) or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise HackError(f"{where}: expected 68 finite weights >= 0.")
        return self

    def save(self, path: str | Path) -> Path:
        spec = json.dumps(self.spec.__dict__, sort_keys=True)
        return write_npz(path, dict(W=self.W.astype(np.float16),
                                    feat_mean=self.feat_mean.astype(np.float32),
                                    delta_mean=self.delta_mean.astype(np.float32),
                                    mean_shape=self.mean_shape.astype(np.float64),
                                    spec=np.array(spec),
                                    meta=np.array(json.dumps(self.meta, sort_keys=True)),
                                    **({} if self.weights is None else
                                       {"weights": np.asarray(self.weights, np.float64)})),
                         compressed=True)

    @classmethod
    def load(cls, path: str | Path) -> LandmarkRefiner:
        path = Path(path)
        if not path.is_file():
            raise HackError(f"landmark refiner {path}: file not found.")
        try:
            with np.load(path, allow_pickle=False) as z:
                ref = cls(z["W"].astype(np.float64), z["feat_mean"].astype(np.float64),
                          z["delta_mean"].astype(np.float64),
                          z["mean_shape"].astype(np.float64),
                          PatchSpec(**json.loads(str(z["spec"]))),
                          z["weights"].astype(np.float64) if "weights" in z.files else None,
                          json.loads(str(z["meta"])))
        except (KeyError, ValueError, TypeError, OSError) as err:
            raise HackError(f"landmark refiner {path}: not a landmark refiner file "
                            f"({err}).") from err
        return ref.validate(str(path))


class RefinerWarning(UserWarning):
    """The landmark refiner is unavailable; dlib's points are used as they are."""


_CACHE: dict = {}


def load_refiner(name: str) -> LandmarkRefiner | None:
    """``landmarks.refiner``: "off" -> None; "dlib" -> the shipped file (None, with a
    warning, when it is missing); else the path of a refiner file (errors are errors)."""
    if name == "off":
        return None
    path = DEFAULT_FILE if name == "dlib" else Path(name)
    key = str(path.resolve())
    if key not in _CACHE:
        if name == "dlib" and not path.is_file():
            warnings.warn(f"landmark refiner {path} is missing; using dlib's points as they "
                          "are (hack-render learn landmark-refiner builds it).",
                          RefinerWarning, stacklevel=2)
            return None
        _CACHE[key] = LandmarkRefiner.load(path)
    return _CACHE[key]
