"""Calibrate the face-mesh-to-68 map (:mod:`hack_render.vision.dense68`) on renders.

    python -m hack_render.learn.dense68 [--samples 240] [--seed 7100] [--out FILE]

Composites of the model (:mod:`hack_render.vision.synthetic`, its own seed, so they share
no subject with the benchmark's or the tests') at yaw U(-90, 90) and pitch U(-45, 45)
degrees are run through the face-mesh model (BlazeFace's box, two passes); those where
it reports a face (presence >= 0.9) are kept. Per landmark,
the ``k`` face-mesh points nearest to the true landmark (median distance over the
samples, in units of the face's box) are combined with affine weights (summing to 1)
fitted by ridge-regularised least squares to the true positions. The tessellation's
triangles are oriented by their median signed area on the near-frontal samples.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def collect(n: int, seed: int, res: int = 256, spp: int = 16, min_presence: float = 0.9):
    """(dense (S, 468, 3), truth (S, 68, 2), yaw (S,), size (S,)) over composites where
    the detector found the face and the mesh model's face presence is at least
    ``min_presence``."""
    from tqdm import tqdm

    from hack_render.vision.detect import find_boxes, mesh_landmarks
    from hack_render.vision.synthetic import CompositeRenderer

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


def fit_map(dense: np.ndarray, truth: np.ndarray, sizes: np.ndarray, k: int = 6,
            ridge: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per landmark: the k nearest mesh points (median normalised distance) and affine
    weights minimising sum_s |sum_j w_j p_sj - t_s|^2 / size_s^2 + ridge |w - 1/k|^2,
    subject to sum_j w_j = 1. Returns (index (68, k), weight (68, k), per-landmark RMS
    residual in box units (68,))."""
    nd = dense[..., :2] / sizes[:, None, None]
    nt = truth / sizes[:, None, None]
    index = np.zeros((68, k), np.int64)
    weight = np.zeros((68, k))
    resid = np.zeros(68)
    for lm in range(68):
        dist = np.median(np.linalg.norm(nd - nt[:, lm:lm + 1], axis=-1), axis=0)
        idx = np.argsort(dist)[:k]
        P = nd[:, idx]                       # (S, k, 2)
        A = np.einsum("skc,sjc->kj", P, P) + ridge * np.eye(k)
        bvec = np.einsum("skc,sc->k", P, nt[:, lm]) + ridge / k
        # KKT system of the equality-constrained least squares
        M = np.block([[2 * A, np.ones((k, 1))], [np.ones((1, k)), np.zeros((1, 1))]])
        w = np.linalg.solve(M, np.r_[2 * bvec, 1.0])[:k]
        index[lm], weight[lm] = idx, w
        resid[lm] = float(np.sqrt(np.mean(np.sum((np.einsum("k,skc->sc", w, P)
                                                  - nt[:, lm]) ** 2, -1))))
    return index, weight, resid


def orient_triangles(dense: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """Tessellation triangles wound so that facing the camera is a positive area (the
    median sign over samples within 20 degrees of frontal)."""
    from hack_render.vision.dense68 import signed_areas, tessellation_triangles

    tris = tessellation_triangles()
    front = dense[np.abs(yaws) < 20] if (np.abs(yaws) < 20).sum() >= 3 else dense
    sign = np.median(np.sign([signed_areas(d[:, :2], tris) for d in front]), axis=0)
    tris[sign < 0] = tris[sign < 0][:, [0, 2, 1]]
    return tris


def main(argv=None) -> None:
    from hack_render.vision.dense68 import DEFAULT_FILE, DenseMap

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=240)
    ap.add_argument("--seed", type=int, default=7100)
    ap.add_argument("--k", type=int, default=6)
    ap.add_argument("--out", default=str(DEFAULT_FILE))
    a = ap.parse_args(argv)
    t0 = time.time()
    dense, truth, yaws, sizes = collect(a.samples, a.seed)
    index, weight, resid = fit_map(dense, truth, sizes, a.k)
    tris = orient_triangles(dense, yaws)
    meta = {"what": "face-mesh (MediaPipe 468) to Multi-PIE 68 map, derived: calibrated on "
                    "procedural renders of the HACK model composited over photographs",
            "samples": len(dense), "requested": a.samples, "seed": a.seed, "k": a.k,
            "rms_residual_box": float(np.sqrt(np.mean(resid ** 2))),
            "seconds": round(time.time() - t0, 1)}
    DenseMap(index, weight, tris, meta).save(a.out)
    print(meta)


if __name__ == "__main__":
    main()
