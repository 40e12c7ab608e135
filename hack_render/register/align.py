"""3-D landmarks and the similarity alignment that starts every registration.

- :func:`read_landmarks_3d`: the 68 Multi-PIE points or the 51 inner ones (no jaw line)
  from JSON (``{"landmarks": [[x, y, z], ...]}`` or a bare list), NPY or TXT/CSV, in the
  scan's own units.
- :func:`umeyama`: the least-squares similarity (Umeyama 1991) taking one point set onto
  another, with the scale fixed or free.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hack_render.errors import HackError

#: Multi-PIE indices of the 51 inner landmarks (brows, nose, eyes, mouth): no jaw line.
INNER = tuple(range(17, 68))


def read_landmarks_3d(path: str | Path) -> tuple[np.ndarray, tuple[int, ...]]:
    """(K, 3) landmarks and their Multi-PIE indices (K = 68, or 51 = indices 17..67)."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--landmarks {path}: no such file.")
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
            arr = data.get("landmarks") if isinstance(data, dict) else data
            if arr is None:
                raise ValueError("no 'landmarks' key")
            arr = np.asarray(arr, dtype=np.float64)
        else:
            arr = np.loadtxt(path, delimiter="," if path.suffix.lower() == ".csv" else None,
                             ndmin=2)
    except (ValueError, OSError, EOFError, TypeError) as exc:
        raise HackError(f"--landmarks {path}: cannot read 3-D landmarks ({exc}). Expected 68 "
                        "or 51 rows of x y z (JSON {\"landmarks\": [[x, y, z], ...]}, NPY or "
                        "TXT).") from exc
    arr = np.asarray(arr)
    if arr.dtype.kind not in "fiu" or arr.ndim != 2 or arr.shape[1] != 3 \
            or arr.shape[0] not in (68, 51):
        raise HackError(f"--landmarks {path}: expected shape (68, 3) (Multi-PIE) or (51, 3) "
                        f"(the inner points, without the jaw line), found shape {arr.shape}.")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise HackError(f"--landmarks {path}: expected finite coordinates, found NaN or "
                        "infinite values.")
    return arr, (tuple(range(68)) if len(arr) == 68 else INNER)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True,
            weights: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising sum w_i |s R src_i + t - dst_i|^2.

    Args:
        src, dst: (K, 3) corresponding points, K >= 3, not collinear.
        with_scale: estimate s; otherwise s = 1 (a rigid motion).
        weights: (K,) non-negative weights (default 1).
    Returns:
        s (float), R (3, 3) proper rotation, t (3,).
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64)
    if len(src) < 3 or w.sum() <= 0:
        raise HackError(f"alignment: expected at least 3 weighted point pairs, found "
                        f"{int((w > 0).sum())}.")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    cov = (xd * w[:, None]).T @ xs
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = float((w * (xs ** 2).sum(1)).sum())
    if var_s <= 1e-20:
        raise HackError("alignment: the landmarks are all at one point.")
    s = float(np.trace(np.diag(S) @ D) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t
