"""One scan, start to end: read, landmarks, similarity alignment, fit, measure.

:func:`register` returns a :class:`Registration` (the registered mesh in the model's
vertex order, in the scan's own frame and units, the parameters, the offsets, and the
measured errors); :mod:`hack_render.register.outputs` writes it.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.register.align import INNER, umeyama
from hack_render.register.fitting import (
    RegisterConfig,
    RegisterState,
    faces_within,
    initial_state,
    model_subsets,
    posed_vertices,
    run_registration,
)
from hack_render.register.measure import (
    MeshDistance,
    beyond_open_boundary,
    beyond_point_cloud,
    face_normals,
)
from hack_render.register.scan import Scan, SurfaceIndex, transformed, vertex_normals

#: a registration whose scan-to-mesh mean over the scan points near the model exceeds this
#: (or that leaves most of the scan unexplained) is reported as failed, not as a result
FAIL_MEAN_MM = 3.0
FAIL_COVERAGE = 0.5  # fraction of scan points within 1 cm of the registered mesh
FAIL_LANDMARK_MM = 12.0
#: a skin vertex's distance to the scan is measured (vertex_error, error.png) where the
#: fit could pair it with the scan: its nearest scan point within this many metres (the
#: fit's RegisterConfig.max_distance), not on the scan's edge, on a surface facing its
#: way (normals' dot product at least this, as the fit's model-to-scan term asks)
MEASURED_WITHIN_M = 0.02
MEASURED_NORMAL_DOT = 0.3
#: landmarks found on the scan (not given) weigh this much of the given ones'
AUTO_LANDMARK_WEIGHT = 0.1


@dataclass
class Registration:
    """The result of registering one scan.

    Attributes:
        vertices: (N, 3) registered mesh in the model's vertex order, scan frame and units
            (free-form offsets included).
        model_vertices: (N, 3) the same without the offsets (the model's own fit).
        params: parameter-file dict (model frame, metres): beta, psi, theta, global_orient,
            transl, eta, tau.
        offsets: (N, 3) free-form offsets, metres, model frame (zero off the skin).
        scan_error: (M,) distance of each scan vertex to the registered mesh, millimetres.
        vertex_error: (N,) distance of each model vertex to the scan surface, millimetres
            (nan where not measured: off the skin, and beyond the scan's edge, where the
            scan does not cover the model).
        report: JSON-ready dict.
    """

    vertices: np.ndarray
    model_vertices: np.ndarray
    params: dict
    offsets: np.ndarray
    scan_error: np.ndarray
    vertex_error: np.ndarray
    report: dict = field(default_factory=dict)


def similarity_to_model(model, landmarks: np.ndarray, ids: tuple[int, ...], scale_free: bool
                        ) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) taking scan points (metres) onto the mean model: x_model = s R x + t.

    The inner landmarks carry the rotation; the jaw line (a contour, not fixed points) is
    left out when the inner ones are there."""
    with torch.no_grad():
        mean_lmk = model().landmarks[0].double().numpy()
    use = [k for k, i in enumerate(ids) if i in INNER] or list(range(len(ids)))
    return umeyama(landmarks[use], mean_lmk[[ids[k] for k in use]], with_scale=scale_free)


def stats_mm(d_mm: np.ndarray) -> dict:
    d = d_mm[np.isfinite(d_mm)]
    if not len(d):
        return {"n": 0}
    return {"n": len(d), "mean": float(d.mean()), "median": float(np.median(d)),
            "p95": float(np.quantile(d, 0.95)), "std": float(d.std())}


def measure(model, scan: Scan, verts_model: np.ndarray, to_scan) -> tuple[np.ndarray, np.ndarray, dict]:
    """Scan-to-mesh distances (mm) per scan vertex over face, neck and all, and the
    model-to-scan distance per skin vertex. ``verts_model``: (N, 3) model frame, metres;
    ``to_scan``: model frame -> scan metres."""
    skin, cand = model_subsets(model)
    faces = model.faces.numpy()

    f_eval = faces_within(faces, cand)
    v_scan = to_scan(verts_model)
    md = MeshDistance(v_scan, f_eval)
    d, _, fid = md.closest(scan.points)
    d_mm = 1000.0 * d
    region = model.vertex_region.numpy()[f_eval[fid, 0]]
    names = model.region_names
    near = d_mm < 10.0
    out = {"all": stats_mm(d_mm[near]), "face": stats_mm(d_mm[near & (region == names.index("face"))]),
           "neck": stats_mm(d_mm[near & (region == names.index("neck"))]),
           "coverage_1cm": float(near.mean()), "points": len(d_mm)}
    # each skin vertex's distance to the scan where the scan covers it, as the fit pairs
    # them (fitting.TwoWayDistance): a vertex whose nearest scan point is on the scan's
    # edge (a mesh) or off to the side of it (a point cloud), or on a surface facing the
    # other way (the inside of a face-only scan, seen from the back of the head) or
    # farther than MEASURED_WITHIN_M, lies where the scan has no surface for it: not
    # measured (nan: grey in error.png, -1 in error.ply), not a ">= 3 mm" red
    vert_err = np.full(len(v_scan), np.nan)
    v_skin = v_scan[skin]
    v_normal = vertex_normals(v_scan, f_eval)[skin]
    if scan.is_mesh:
        d, q, fid = MeshDistance(scan.points, scan.faces).closest(v_skin)
        s_normal = face_normals(scan.points, scan.faces)[fid]
        off = beyond_open_boundary(v_skin, q, fid, scan.points, scan.faces)
    else:
        from scipy.spatial import cKDTree

        tree = cKDTree(scan.points)
        d, j = tree.query(v_skin, workers=-1)
        some = scan.points[:: max(1, len(scan.points) // 20_000)]
        spacing = float(np.median(tree.query(some, k=2, workers=-1)[0][:, 1]))
        s_normal = scan.normals[j]
        off = beyond_point_cloud(v_skin, scan.points, scan.normals, j, spacing)
    off |= ((v_normal * s_normal).sum(1) < MEASURED_NORMAL_DOT) | (d > MEASURED_WITHIN_M)
    d[off & (d > 1e-6)] = np.nan  # a vertex on the scan is measured, whatever the normals
    vert_err[skin] = 1000.0 * d
    out["skin_measured"] = float(np.isfinite(d).mean())  # share of the skin the scan covers
    return d_mm, vert_err, out


def register(model, scan: Scan, landmarks: np.ndarray | None, landmark_ids: tuple[int, ...],
             cfg: RegisterConfig, progress: bool = True, landmark_source: str = "file"
             ) -> Registration:
    """Register ``model`` to ``scan`` (metres) with 3-D ``landmarks`` (K, 3), scan metres."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    if landmarks is None:
        raise HackError(f"{scan.name}: no landmarks to start from. Pass --landmarks FILE, or "
                        "let `register` find them (a mesh scan with the fit extra installed).")
    s, R, t = similarity_to_model(model, landmarks, landmark_ids, scale_free=False)
    moved = transformed(scan, s, R, t)
    lmk_model = s * landmarks @ R.T + t
    t_align = time.perf_counter()
    index = SurfaceIndex(moved)
    t_index = time.perf_counter()
    if landmark_source != "file":
        # found landmarks are a few millimetres off (a detector on renders of the scan):
        # they start the alignment and the rigid stage, the surface does the rest

        cfg = replace(cfg, w_lmk=cfg.w_lmk * AUTO_LANDMARK_WEIGHT)
    num_shape = min(cfg.num_shape, model.num_shape)
    st = initial_state(model, num_shape, np.eye(3))
    st = run_registration(model, index, lmk_model, landmark_ids, st, cfg, progress)
    t_fit = time.perf_counter()
    skin, _ = model_subsets(model)
    with torch.no_grad():
        v_free, lm = posed_vertices(model, st, torch.as_tensor(skin), True)
        v_model, _ = posed_vertices(model, st, torch.as_tensor(skin), False)
    v_free, v_model = v_free.double().numpy(), v_model.double().numpy()
    inv = lambda x: ((x - t) @ R) / s  # model frame -> scan metres
    to_scan_units = lambda x: inv(x) / scan.scale
    d_mm, vert_err, errs = measure(model, scan, v_free, inv)
    lm_err = 1000.0 * np.linalg.norm(lm.double().numpy()[list(landmark_ids)] - lmk_model, axis=1)
    offsets = np.zeros((model.num_vertices, 3))
    offsets[skin] = st.offsets.double().numpy()
    failed = []
    if errs["all"].get("mean", np.inf) > FAIL_MEAN_MM:
        failed.append(f"scan-to-mesh mean {errs['all'].get('mean', float('nan')):.2f} mm > "
                      f"{FAIL_MEAN_MM} mm")
    if errs["coverage_1cm"] < FAIL_COVERAGE:
        failed.append(f"only {100 * errs['coverage_1cm']:.0f} % of the scan within 1 cm of the "
                      f"registration (< {100 * FAIL_COVERAGE:.0f} %)")
    inner = np.isin(landmark_ids, INNER)
    if np.median(lm_err[inner] if inner.any() else lm_err) > FAIL_LANDMARK_MM:
        failed.append(f"landmark error median > {FAIL_LANDMARK_MM} mm")
    t_end = time.perf_counter()
    report = {
        "scan": scan.name, "units": scan.units, "scan_scale_m": scan.scale,
        "config": asdict(cfg), "status": "failed" if failed else "ok",
        "failure": failed, "preset": cfg.preset, "free_form": cfg.free_form,
        "scan_to_mesh_mm": errs, "landmarks": {
            "source": landmark_source, "count": len(landmark_ids),
            "mean_mm": float(lm_err.mean()), "median_mm": float(np.median(lm_err))},
        "model_only_scan_to_mesh_mm": measure(model, scan, v_model, inv)[2]["all"]
        if cfg.free_form else errs["all"],
        "similarity_scan_to_model": {"scale": s, "R": R.tolist(), "t": t.tolist(),
                                     "note": "x_model = scale * R @ x_scan_metres + t"},
        "seconds": {"align": t_align - t0, "index": t_index - t_align, "fit": t_fit - t_index,
                    "measure": t_end - t_fit, "total": t_end - t0,
                    # CPU seconds of the process (all threads): the wall time on an idle
                    # machine with as many cores as threads used, whatever the load now
                    "cpu_total": time.process_time() - cpu0,
                    **{f"stage_{r.name}": r.seconds for r in st.reports}},
        "notes": list(scan.notes),
        "thresholds": {"fail_mean_mm": FAIL_MEAN_MM, "fail_coverage_1cm": FAIL_COVERAGE,
                       "fail_landmark_median_mm": FAIL_LANDMARK_MM},
    }
    return Registration(to_scan_units(v_free), to_scan_units(v_model), st.params(), offsets,
                        d_mm, vert_err, report)


def state_summary(st: RegisterState) -> dict:
    return {r.name: {"iterations": r.iterations, "seconds": r.seconds,
                     "final": {k: v[-1] for k, v in r.history.items()}} for r in st.reports}
