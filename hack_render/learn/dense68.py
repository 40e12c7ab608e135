"""Calibrate the face-mesh-to-68 map (:mod:`hack_render.vision.dense68`) on renders.

    python -m hack_render.learn.dense68 [--samples 240] [--seed 7100] [--out FILE]
    python -m hack_render.learn.dense68 --from ert_5301.npz ert_5302.npz ... [--trim 0.1]

Composites of the model (:mod:`hack_render.dataset.composites`, its own seed, so they share
no subject with the benchmark's or the tests') at yaw U(-90, 90) and pitch U(-45, 45)
degrees are run through the face-mesh model (BlazeFace's box, two passes); those where
it reports a face (presence >= 0.9) are kept. ``--from``: the composites the shape
predictors are trained on instead (``python -m hack_render.learn.face_ert collect``:
images, BlazeFace's boxes and keypoints, true points; rolled up to 25 degrees, a third
with an occluder), each run as ``auto`` runs the mesh model (the keypoints turned the
right way up first). Per landmark,
the ``k`` face-mesh points nearest to the true landmark (median distance over the
samples, in units of the face's box) are combined with affine weights (summing to 1)
fitted by ridge-regularised least squares to the true positions; ``--trim``: that share of
the samples, those the first fit misses most for the landmark (an occluder over it, the
mesh model astray), left out of a second fit. The tessellation's triangles are oriented
by their median signed area on the near-frontal samples.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hack_render.dataset.composites import CompositeRenderer
from hack_render.vision.boxes import find_boxes
from hack_render.vision.dense68 import DEFAULT_FILE, DenseMap, signed_areas, tessellation_triangles
from hack_render.vision.detect import mesh_landmarks
from hack_render.vision.ert import upright_keypoints


def collect(n: int, seed: int, res: int = 256, spp: int = 16, min_presence: float = 0.9):
    """(dense (S, 468, 3), truth (S, 68, 2), yaw (S,), size (S,)) over composites where
    the detector found the face and the mesh model's face presence is at least
    ``min_presence``."""

    rng = np.random.default_rng(seed)
    ren = CompositeRenderer(res, spp, seed)
    dense, truth, yaws, sizes = [], [], [], []
    for _ in tqdm(range(n), desc="calibration composites", unit="sample"):
        yaw, pitch = rng.uniform(-90, 90), rng.uniform(-45, 45)
        c = ren.render(yaw, pitch)
        boxes = find_boxes(c.image)
        if not boxes:
            continue
        # the box nearest the true face (a background may hold another)
        ctr = c.points.mean(0)
        b = min(boxes, key=lambda b: np.hypot((b[0] + b[2]) / 2 - ctr[0], (b[1] + b[3]) / 2 - ctr[1]))
        d, presence = mesh_landmarks(c.image, b[:4], b[5])
        if presence < min_presence:   # the mesh model gave up (profiles): no use here
            continue
        dense.append(d)
        truth.append(c.points)
        yaws.append(yaw)
        sizes.append(c.box_size)
    return np.array(dense), np.array(truth), np.array(yaws), np.array(sizes)


def collect_from(files) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`collect`, from saved composites (``face_ert collect`` files): the mesh
    model run as ``auto`` runs it, on each image's BlazeFace box and keypoints (turned
    the right way up); those with presence >= 0.9 kept. Box size: the truth's."""

    dense, truth, yaws, sizes = [], [], [], []
    for f in files:
        with np.load(f) as z:
            data = {k: z[k] for k in ("images", "boxes", "kps", "points", "yaw")}
        for img, box, kp, pts, yaw in tqdm(zip(*data.values()), total=len(data["images"]),
                                           desc=f"calibration {Path(f).name}", unit="sample"):
            d, presence = mesh_landmarks(img, box, upright_keypoints(img, box, kp))
            if presence < 0.9:
                continue
            lo, hi = pts.min(0), pts.max(0)
            dense.append(d)
            truth.append(pts)
            yaws.append(yaw)
            sizes.append(float(np.sqrt(np.prod(hi - lo))))
    return np.array(dense), np.array(truth), np.array(yaws), np.array(sizes)


def _affine_weights(P: np.ndarray, t: np.ndarray, ridge: float) -> np.ndarray:
    """Weights w (k,), sum 1, minimising sum_s |sum_j w_j P_sj - t_s|^2 + ridge |w - 1/k|^2
    (the KKT system of the equality-constrained least squares)."""
    k = P.shape[1]
    A = np.einsum("skc,sjc->kj", P, P) + ridge * np.eye(k)
    bvec = np.einsum("skc,sc->k", P, t) + ridge / k
    M = np.block([[2 * A, np.ones((k, 1))], [np.ones((1, k)), np.zeros((1, 1))]])
    return np.linalg.solve(M, np.r_[2 * bvec, 1.0])[:k]


def fit_map(dense: np.ndarray, truth: np.ndarray, sizes: np.ndarray, k: int = 6,
            ridge: float = 1e-3, trim: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per landmark: the k nearest mesh points (median normalised distance) and affine
    weights minimising sum_s |sum_j w_j p_sj - t_s|^2 / size_s^2 + ridge |w - 1/k|^2,
    subject to sum_j w_j = 1; ``trim`` > 0: refitted without that share of the samples
    the first fit misses most. Returns (index (68, k), weight (68, k), per-landmark RMS
    residual in box units over the samples kept (68,))."""
    nd = dense[..., :2] / sizes[:, None, None]
    nt = truth / sizes[:, None, None]
    index = np.zeros((68, k), np.int64)
    weight = np.zeros((68, k))
    resid = np.zeros(68)
    for lm in range(68):
        dist = np.median(np.linalg.norm(nd - nt[:, lm:lm + 1], axis=-1), axis=0)
        idx = np.argsort(dist)[:k]
        P, t = nd[:, idx], nt[:, lm]         # (S, k, 2), (S, 2)
        w = _affine_weights(P, t, ridge)
        err = np.linalg.norm(np.einsum("k,skc->sc", w, P) - t, axis=-1)
        if trim > 0:
            keep = err <= np.quantile(err, 1.0 - trim)
            w = _affine_weights(P[keep], t[keep], ridge)
            err = np.linalg.norm(np.einsum("k,skc->sc", w, P[keep]) - t[keep], axis=-1)
        index[lm], weight[lm] = idx, w
        resid[lm] = float(np.sqrt(np.mean(err ** 2)))
    return index, weight, resid


def orient_triangles(dense: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """Tessellation triangles wound so that facing the camera is a positive area (the
    median sign over samples within 20 degrees of frontal)."""
    tris = tessellation_triangles()
    front = dense[np.abs(yaws) < 20] if (np.abs(yaws) < 20).sum() >= 3 else dense
    sign = np.median(np.sign([signed_areas(d[:, :2], tris) for d in front]), axis=0)
    tris[sign < 0] = tris[sign < 0][:, [0, 2, 1]]
    return tris


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=240)
    ap.add_argument("--seed", type=int, default=7100)
    ap.add_argument("--k", type=int, default=6)
    ap.add_argument("--from", dest="files", nargs="+", metavar="NPZ",
                    help="saved composites (python -m hack_render.learn.face_ert collect) "
                         "instead of rendering --samples new ones")
    ap.add_argument("--trim", type=float, default=0.0,
                    help="share of the samples a landmark's first fit misses most, left out "
                         "of its second (0: one fit)")
    ap.add_argument("--out", default=str(DEFAULT_FILE))
    a = ap.parse_args(argv)
    if not 0.0 <= a.trim < 0.5:
        ap.error(f"--trim: expected a share in [0, 0.5), found {a.trim}")
    t0 = time.time()
    if a.files:
        dense, truth, yaws, sizes = collect_from(a.files)
    else:
        dense, truth, yaws, sizes = collect(a.samples, a.seed)
    index, weight, resid = fit_map(dense, truth, sizes, a.k, trim=a.trim)
    tris = orient_triangles(dense, yaws)
    meta = {"what": "face-mesh (MediaPipe 468) to Multi-PIE 68 map, derived: calibrated on "
                    "procedural renders of the HACK model composited over photographs",
            "samples": len(dense), "k": a.k, "trim": a.trim,
            **({"from": [Path(f).name for f in a.files]} if a.files
               else {"requested": a.samples, "seed": a.seed}),
            "rms_residual_box": float(np.sqrt(np.mean(resid ** 2))),
            "seconds": round(time.time() - t0, 1)}
    DenseMap(index, weight, tris, meta).save(a.out)
    print(meta)


if __name__ == "__main__":
    main()
