"""The larynx's slide tau from a plain video (no normal maps): the shading of the
Adam's apple, read in the larynx chart's coordinates, slides with tau.

For each frame the fitted model (its pose, at tau = 0) places a grid over the front of
the neck in the larynx chart (``model.larynx_uv``: the chart in which tau is a vertical
shift of ``larynx_v_per_metre`` per metre); the frame's luminance under the grid,
normalised per frame (mean and spread: the light may change), is averaged across the
chart's middle into a vertical profile. The bump's shading moves with tau, the skin's
texture does not; a reference profile at rest and each frame's shift against it are
estimated in turn (a 1-D search over tau's range), and tau is reported relative to the
clip's resting position (its 10th percentile). This is the paper's photometric cue in
its cheapest form: one profile a frame, no rendering.
"""

from __future__ import annotations

import numpy as np
import torch

from hack_render.geometry.larynx import TAU_RANGE_M

#: Grid over the larynx chart: columns across the neck's middle, rows along it
GRID = (9, 48)
#: Fraction of the chart's width the columns span (the middle, where the bump is)
MIDDLE = 0.5
#: Resting position: tau is reported relative to this percentile of the clip's
REST_PERCENTILE = 10.0


def _chart_grid(model):
    """Grid points as (face index, barycentric) on the larynx region's triangles, and
    the grid's chart v per row."""
    from matplotlib.tri import Triangulation

    verts = model.larynx_vertices.numpy()
    uv = model.larynx_uv.double().numpy()
    local = {int(v): i for i, v in enumerate(verts)}
    faces = model.faces.numpy()
    inside = np.isin(faces, verts).all(1)
    tri_faces = faces[inside]
    tri_local = np.vectorize(local.get)(tri_faces)
    tri = Triangulation(uv[:, 0], uv[:, 1], tri_local)
    finder = tri.get_trifinder()
    u0, v0 = uv.min(0)
    u1, v1 = uv.max(0)
    uc, half = (u0 + u1) / 2, MIDDLE * (u1 - u0) / 2
    us = np.linspace(uc - half, uc + half, GRID[0])
    vs = np.linspace(v0, v1, GRID[1])
    U, V = np.meshgrid(us, vs)  # (rows, cols)
    t = finder(U.ravel(), V.ravel())
    ok = t >= 0
    p = np.stack([U.ravel(), V.ravel()], 1)
    corners = uv[tri_local[np.maximum(t, 0)]]  # (P, 3, 2)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    m = np.stack([b - a, c - a], -1)  # (P, 2, 2)
    m[~ok] = np.eye(2)
    lb = np.linalg.solve(m, (p - a)[..., None])[..., 0]
    bary = np.stack([1 - lb.sum(1), lb[:, 0], lb[:, 1]], 1)
    return tri_faces[np.maximum(t, 0)], bary, ok, vs


def _bilinear(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h, w = img.shape
    x = np.clip(xy[:, 0] - 0.5, 0, w - 1.001)
    y = np.clip(xy[:, 1] - 0.5, 0, h - 1.001)
    x0, y0 = x.astype(int), y.astype(int)
    fx, fy = x - x0, y - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def neck_profiles(clip, model, fit, camera, params, found, progress: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(T, rows) normalised luminance profiles along the larynx chart (NaN where the
    face was lost or the neck faces away), and the rows' chart v."""
    from tqdm import tqdm

    from hack_render.geometry.skeleton import distribute_head_rotation

    tri, bary, ok, vs = _chart_grid(model)
    T = clip.frames
    prof = np.full((T, GRID[1]), np.nan)
    chunk = 32
    verts = None
    for i, img in enumerate(tqdm(clip.read(), total=T, desc="larynx", unit="frame",
                                 disable=not progress, leave=False)):
        if i % chunk == 0:
            sl = slice(i, min(T, i + chunk))
            n = sl.stop - sl.start
            with torch.no_grad():
                out = model(beta=fit.beta.detach(), psi=torch.as_tensor(params.psi[sl]).float(),
                            theta=distribute_head_rotation(torch.as_tensor(params.h[sl]).float(),
                                                           clamp=False),
                            global_orient=torch.as_tensor(params.g[sl]).float(),
                            transl=torch.as_tensor(params.t[sl]).float(),
                            eta=fit.eta.detach().expand(n), tau=torch.zeros(n))
            verts = out.vertices.double()
        if not found[i]:
            continue
        v = verts[i % chunk]
        P = (v[torch.as_tensor(tri)] * torch.as_tensor(bary)[..., None]).sum(1)  # (G, 3)
        fv = v[torch.as_tensor(tri)]
        nrm = torch.linalg.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
        from hack_render.fit.camera import R0

        R = R0.double()
        cam_pts = P @ R.T + torch.as_tensor(camera.cam_t)
        facing = ((nrm @ R.T) * cam_pts).sum(1) < 0
        xy = camera.project(P).numpy()
        lum = img.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
        vals = _bilinear(lum, xy)
        good = ok & facing.numpy() & (xy[:, 0] > 1) & (xy[:, 1] > 1) & \
            (xy[:, 0] < clip.work[0] - 2) & (xy[:, 1] < clip.work[1] - 2)
        if good.sum() < 0.5 * good.size:
            continue
        g = np.where(good, vals, np.nan).reshape(GRID[1], GRID[0])
        g = (g - np.nanmean(g)) / max(np.nanstd(g), 1e-6)
        prof[i] = np.nanmean(g, 1)
    return prof, vs


def _shifted(profile: np.ndarray, vs: np.ndarray, dv: float) -> np.ndarray:
    """profile(v - dv) on the rows ``vs`` (NaN outside)."""
    ok = np.isfinite(profile)
    if ok.sum() < 2:
        return np.full_like(profile, np.nan)
    return np.interp(vs - dv, vs[ok], profile[ok], left=np.nan, right=np.nan)


def estimate_tau(prof: np.ndarray, vs: np.ndarray, v_per_metre: float,
                 iterations: int = 3, step_m: float = 2.5e-4) -> np.ndarray:
    """Per-frame tau (metres, NaN where there is no profile) from the profiles: a frame
    at slide tau shows the rest profile moved by ``-tau * v_per_metre`` in chart v."""
    lo, hi = TAU_RANGE_M
    cands = np.arange(lo, hi + step_m / 2, step_m)
    has = np.isfinite(prof).any(1)
    tau = np.zeros(len(prof))
    for _ in range(iterations):
        # the rest profile: every frame moved back by its slide, then the median
        back = np.stack([_shifted(p, vs, tau[i] * v_per_metre) if has[i] else
                         np.full(len(vs), np.nan) for i, p in enumerate(prof)])
        ref = np.nanmedian(back[has], 0)
        shifted = np.stack([_shifted(ref, vs, -c * v_per_metre) for c in cands])  # (C, R)
        for i in np.flatnonzero(has):
            d = shifted - prof[i]
            score = np.nanmean(d ** 2, 1)
            score[np.isfinite(d).sum(1) < 0.6 * len(vs)] = np.inf
            tau[i] = cands[int(np.argmin(score))]
        tau[has] -= np.percentile(tau[has], REST_PERCENTILE)
    tau[~has] = np.nan
    return tau


def track_tau(clip, model, fit, rig, camera, params, found, progress: bool = True
              ) -> tuple[np.ndarray, str]:
    """(tau per frame, metres, relative to the clip's rest; a note). Frames without a
    profile are interpolated from their neighbours."""
    if not getattr(model, "has_larynx", False):
        return np.zeros(clip.frames), "the model has no larynx: tau = 0"
    prof, vs = neck_profiles(clip, model, fit, camera, params, found, progress)
    tau = estimate_tau(prof, vs, float(model.larynx_v_per_metre))
    ok = np.isfinite(tau)
    if ok.sum() < 2:
        return np.zeros(clip.frames), "the neck was not visible: tau = 0"
    idx = np.arange(len(tau))
    tau = np.interp(idx, idx[ok], tau[ok])
    # a light temporal smoothing (the search steps 0.25 mm): 3-frame median, then mean
    if len(tau) >= 3:
        from scipy.ndimage import median_filter, uniform_filter1d

        tau = uniform_filter1d(median_filter(tau, 3, mode="nearest"), 3, mode="nearest")
    lo, hi = TAU_RANGE_M
    return np.clip(tau, lo, hi), (f"tau from the neck's shading, relative to the clip's rest "
                                  f"(its {REST_PERCENTILE:g}th percentile)")
