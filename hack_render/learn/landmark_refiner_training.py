"""Training of the landmark refiner (:mod:`hack_render.fit.landmark_refiner`): the
supervised-descent stages learned on synthetic renders, the training set (rendered in
resumable chunks) and the shipped file. Training code, off the fitter's runtime path.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.fit import landmark_embedding as le
from hack_render.fit.landmark_refiner import (
    INNER,
    LandmarkRefiner,
    PatchSpec,
    mirror_points,
    patch_features,
    to_gray,
)
from hack_render.fit.metrics import similarity_transform
from hack_render.geometry import load_default_model
from hack_render.io.npz import write_npz
from hack_render.learn import landmark_calibration as lc


# --- training -------------------------------------------------------------------------
def mean_shape_of(points: list[np.ndarray]) -> np.ndarray:
    """Generalised Procrustes mean of 68-point shapes (inner points aligned), scaled to
    inter-ocular distance 1 with the inner points centred at the origin."""
    ref = np.asarray(points[0], np.float64)
    for _ in range(3):
        al = []
        for p in points:
            s, R, t = similarity_transform(p[INNER], ref[INNER])
            al.append(s * p @ R.T + t)
        ref = np.mean(al, 0)
    ref = ref - ref[INNER].mean(0)
    return ref / np.linalg.norm(ref[36] - ref[45])


def _ridge(X: np.ndarray, Y: np.ndarray, lam: float):
    """Centred ridge regression Y ~ (X - mx) W + my (dual form when samples < dims)."""
    mx, my = X.mean(0), Y.mean(0)
    Xc, Yc = X - mx, Y - my
    if len(X) < X.shape[1]:
        A = np.linalg.solve(Xc @ Xc.T + lam * np.eye(len(X)), Yc)
        W = Xc.T @ A
    else:
        W = np.linalg.solve(Xc.T @ Xc + lam * np.eye(X.shape[1]), Xc.T @ Yc)
    return W, mx, my


def train(grays: list[np.ndarray], starts: list[np.ndarray], targets: list[np.ndarray],
          stages: int = 2, lam: float = 100.0, jitter: float = 0.03, copies: int = 3,
          mirror: bool = True, spec: PatchSpec = PatchSpec(), seed: int = 0,  # noqa: B008 (frozen)
          progress: bool = True) -> LandmarkRefiner:
    """Train the SDM stages on images (gray, (H, W) in [0, 1]), dlib's points on them
    (``starts``, (68, 2) pixels) and the target points (``targets``, (68, 2)).

    Each image is used as it is and mirrored (``mirror``); each with dlib's points and
    ``copies`` more starts jittered by ``jitter`` (inter-ocular units, Gaussian). ``lam``:
    the ridge penalty on the feature weights (features are L2-Hys normalised per point)."""
    if not (len(grays) == len(starts) == len(targets)) or not grays:
        raise HackError("landmark refiner: expected as many images, starts and targets, "
                        "and at least one.")
    rng = np.random.default_rng(seed)
    G, S, T = [], [], []
    for g, s, t in zip(grays, starts, targets):
        s, t = np.asarray(s, np.float64), np.asarray(t, np.float64)
        variants = [(g, s, t)]
        if mirror:
            w = g.shape[1]
            variants.append((np.ascontiguousarray(g[:, ::-1]), mirror_points(s, w),
                             mirror_points(t, w)))
        for gg, ss, tt in variants:
            iod = np.linalg.norm(tt[36] - tt[45])
            G.append(gg), S.append(ss), T.append(tt)
            for _ in range(copies):
                G.append(gg), S.append(ss + rng.normal(0.0, jitter * iod, ss.shape))
                T.append(tt)
    mean_shape = mean_shape_of(list(starts))
    cur = [s.copy() for s in S]
    Ws, mxs, mys = [], [], []
    for k in range(stages):
        X = np.empty((len(G), spec.dim))
        Y = np.empty((len(G), 2 * len(INNER)))
        frames = []
        it = range(len(G))
        if progress:
            it = tqdm(it, desc=f"refiner stage {k + 1}/{stages}: features", unit="image")
        for i in it:
            X[i], s, R = patch_features(G[i], cur[i], mean_shape, spec)
            Y[i] = (((T[i] - cur[i])[INNER] @ R.T) * s).ravel()
            frames.append((s, R))
        W, mx, my = _ridge(X, Y, lam)
        Ws.append(W), mxs.append(mx), mys.append(my)
        pred = (X - mx) @ W + my
        for i, (s, R) in enumerate(frames):
            cur[i][INNER] += (pred[i].reshape(-1, 2) / s) @ R
    return LandmarkRefiner(np.array(Ws), np.array(mxs), np.array(mys), mean_shape, spec)


# --- the training set and the shipped file ---------------------------------------------
def render_training_set(subjects: int, seed: int, cache: str | Path | None = None,
                        chunk: int = 50, progress: bool = True) -> dict:
    """Synthetic renders with dlib's points and the embedding's projected points: dataset
    samples 0 .. ``subjects`` - 1 of ``seed`` (the landmark calibration's sampler and
    settings, :func:`~hack_render.fit.landmark_embedding.render_subjects`), rendered in
    chunks of ``chunk``; with ``cache``, each chunk is written there as it completes and
    read back on a rerun (an interrupted build resumes). Returns images (S, H, W) gray
    uint8, dlib (S, 68, 2), targets (S, 68, 2), iod (S,), indices (S,), missed, and
    chunks_from_cache (how many chunks were read back rather than rendered)."""
    model = load_default_model()
    emb = le.load_default(model)
    if emb is None:
        raise HackError("landmark refiner: the calibrated landmark embedding is missing "
                        "(hack-render learn landmark-embedding builds it); it defines the targets.")
    li = model.landmark_indices.numpy()
    tag = f"{seed}-{emb.meta.get('command', '')}-{emb.vertex_ids.sum()}-{emb.bary.sum():.9f}"
    cache = Path(cache) if cache else None
    parts, missed, cached = [], [], 0
    for start in range(0, subjects, chunk):
        n = min(chunk, subjects - start)
        path = cache / f"refiner_{seed}_{start:06d}_{n}.npz" if cache else None
        if path is not None and path.is_file():
            with np.load(path, allow_pickle=False) as z:
                if str(z["tag"]) == tag:
                    if "images" in z.files:  # else: no face in the whole chunk
                        parts.append({k: z[k] for k in ("images", "dlib", "targets", "iod",
                                                        "indices")})
                    missed += json.loads(str(z["missed"]))
                    cached += 1
                    continue
        try:
            data = lc.render_subjects(n, seed, start=start, progress=progress, images=True)
        except HackError as err:  # no face in the whole chunk
            gone = [[i, str(err)] for i in range(start, start + n)]
            missed += gone
            if path is not None:
                _save_chunk(path, {"tag": np.array(tag), "missed": np.array(json.dumps(gone))})
            continue
        tg, iod = [], []
        for s in range(len(data.indices)):
            V = data.vertices[s].astype(np.float64)
            lv = data.project(s, V[li])
            iod.append(float(np.linalg.norm(lv[36] - lv[45])))
            tg.append(data.project(s, emb.points_np(V)))
        part = {"images": np.stack([np.round(to_gray(im) * 255).astype(np.uint8)
                                    for im in data.images]),
                "dlib": data.points.astype(np.float64), "targets": np.asarray(tg),
                "iod": np.asarray(iod), "indices": data.indices.astype(np.int64)}
        parts.append(part)
        missed += [[int(i), why] for i, why in data.missed]
        if path is not None:
            _save_chunk(path, {**part, "tag": np.array(tag),
                               "missed": np.array(json.dumps(data.missed))})
    if not parts:
        raise HackError("landmark refiner: the detector found no face in any subject.")
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["missed"] = missed
    out["chunks_from_cache"] = cached
    return out


def _save_chunk(path: Path, arrays: dict) -> None:
    write_npz(path, arrays, compressed=True)


def inner_nme(points: np.ndarray, targets: np.ndarray, iod: np.ndarray) -> np.ndarray:
    """Per subject: rms distance over the inner points (and chin) / inter-ocular distance."""
    d = np.linalg.norm((np.asarray(points) - np.asarray(targets))[:, INNER], axis=2)
    return np.sqrt((d ** 2).mean(1)) / np.asarray(iod)


def build(output: str | Path, subjects: int = 1200, seed: int | None = None,
          stages: int = 3, lam: float = 100.0, holdout: float = 0.1,
          cache: str | Path | None = None, command: str = "",
          progress: bool = True) -> tuple[LandmarkRefiner, dict]:
    """Render the training set, train on all but the last ``holdout`` share of the
    subjects, measure dlib's and the refined points' error on those held out, take the
    loss weights from the refined points' scatter there, and write the file."""
    seed = le.CALIBRATION_SEED if seed is None else int(seed)
    t0 = time.perf_counter()
    data = render_training_set(subjects, seed, cache, progress=progress)
    t_render = time.perf_counter() - t0
    n = len(data["indices"])
    n_val = round(holdout * n)
    if n - n_val < 10:
        raise HackError(f"landmark refiner: {n} usable subjects; expected at least "
                        f"{10 + n_val} (raise --subjects).")
    tr, va = slice(0, n - n_val), slice(n - n_val, n)
    grays = [im.astype(np.float32) / 255.0 for im in data["images"]]
    t1 = time.perf_counter()
    ref = train(grays[tr], list(data["dlib"][tr]), list(data["targets"][tr]), stages=stages,
                lam=lam, progress=progress)
    t_train = time.perf_counter() - t1
    report = {"subjects_used": int(n), "train": int(n - n_val), "holdout": int(n_val),
              "left_out": data["missed"]}
    if n_val:
        refined = np.array([ref.refine(g, p) for g, p in zip(grays[va], data["dlib"][va])])
        before = inner_nme(data["dlib"][va], data["targets"][va], data["iod"][va])
        after = inner_nme(refined, data["targets"][va], data["iod"][va])
        ref.weights = lc.scatter_weights(
            (refined - data["targets"][va]) / data["iod"][va, None, None],
            np.isin(np.arange(68), INNER))
        report["holdout_nme_percent"] = {
            "dlib_median": 100 * float(np.median(before)), "dlib_mean": 100 * float(before.mean()),
            "refined_median": 100 * float(np.median(after)),
            "refined_mean": 100 * float(after.mean()),
            "refined_better": int((after < before).sum())}
    ref.meta = {
        "provenance": (f"derived: trained on {n - n_val} synthetic renders of the default "
                       f"model (dataset sampler seed {seed}, the landmark calibration's "
                       f"settings), targets the calibrated embedding's points projected "
                       f"from the known geometry; no captured data"),
        "detector": "dlib shape_predictor_68_face_landmarks",
        "method": "supervised descent (SDM): ridge regression of HOG-like patch features",
        "command": command or f"hack-render learn landmark-refiner -o {output} "
                              f"--subjects {subjects}",
        "dataset_seed": seed, "subjects_requested": int(subjects), "stages": int(stages),
        "lambda": float(lam), "render_seconds": t_render, "train_seconds": t_train,
        "chunks_from_cache": int(data["chunks_from_cache"]),
        **{k: v for k, v in report.items() if k != "left_out"},
        "left_out": len(data["missed"]),
        "weights": "scatter_weights(): inverse variance of the refined points' scatter "
                   "about the embedding on the held-out renders",
    }
    ref.save(output)
    return ref, report
