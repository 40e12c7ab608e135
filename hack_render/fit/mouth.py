"""The mouth's stage: the jaw placed by the teeth the photo shows, after the photometric
stage and before the final one.

The 68 points hold the lips, not the teeth: a smile whose teeth meet came back with the
jaw dropped and the lower lip held up by the identity's shape, so the opening the lips
frame showed the upper teeth over the mouth's dark inside where the photo has the lower
teeth (obama's smile: 78 % of the face oval's squared error inside the lips).

Here, per view, the photo's mouth is read between the face mesh's inner lip contour
(MediaPipe's ``FACEMESH_LIPS``, its inner loop) in the frame of its two corners (as
``eyes.py`` does for the lids: the chord from corner to corner, length 1, ``h`` the
height above it): over the middle of the opening (:data:`MIDDLE` of the chord), each
pixel row is called teeth (brighter than the lips' median and, in a colour photo, less
saturated), dark (the mouth's inside: darker than :data:`DARK` times the lips) or neither
(tongue, lips, a shadow's edge), and the longest run of dark rows is the gap between the
teeth. The model's teeth are read as their tips near the midline (the upper incisors'
lowest vertices, the lower ones' highest; ``teeth_rig``), projected, in the same frame.
The targets on the lower tips' height ``h_lo`` (the jaw moves them):

- a dark gap with teeth below it: ``h_lo`` at the first teeth row below the gap (the
  gap's bottom, or a tongue's rows lower where the tongue lies over the lower teeth);
- a dark gap down to the lower lip (the lower teeth hidden): ``h_lo`` at most there;
- no dark gap, teeth seen: the teeth meet, ``h_lo`` at least the upper tips' height;
- no dark gap and no teeth, only rows of the lips' or the tongue's colour between the
  face mesh's inner lips ("lips only": the mouth closed, or a lip or tongue in the
  opening; a small face's mesh often draws a closed mouth open): as "teeth meet", the jaw
  not dropped;
- a dark inside without teeth, or the mouth closed in the face mesh (the opening thinner
  than :data:`CLOSED`): none.

Where a dark gap is seen, the upper tips' height ``h_up`` too: at the gap's top where
teeth are seen just above it (:data:`UPPER_ROWS`), else (the lip's colour, or teeth in
shade, there) not inside the gap. Where the teeth meet, the lower ones behind the upper:
``h_up`` at the end of the longest run of teeth rows, unless that run reaches the
opening's last rows (:data:`UPPER_ROWS`): the lower lip hides the tips there.

The unknowns: the jaw and lip shapes (:data:`SHAPES`, added to the fitted expression,
within [0, 1]), the identity (beta) and, where ``h_up`` has a target, the upper teeth's
drop under the upper lip (``fit/teeth.py``; prior :data:`TEETH_SIGMA`), with every one
of the 68 points held where the stages before placed them (projected, in units of
:data:`HOLD` of the mouth's width) and weak priors on the changes: the jaw can close
only if the lips and chin stay, so a shorter jaw drop is paid by a longer lower face, not
by a moved chin. A view where the face
mesh finds no face, or the photo shows no teeth, keeps its mouth. The report says per
view what was read and the tips' heights before and after.
"""

from __future__ import annotations

import numpy as np
import torch
from skimage.draw import polygon

from hack_render.fit import face_mesh
from hack_render.fit.stages import run_stage
from hack_render.fit.state import FitState, View
from hack_render.fit.teeth import SHAPES, TEETH_LIMIT, TeethRig, teeth_rig

#: The measures' unit (a share of the mouth's width between its inner corners).
SCALE = 0.02
#: The 68 points' hold: their unit, a share of the mouth's width; and each point's
#: weight (the jawline 1, the brows, eyes, nose and lips, whose edges the photo shows
#: sharply, :data:`HOLD_FEATURES`).
HOLD = 0.01
HOLD_FEATURES = 4.0
HOLD_WEIGHTS = torch.cat([torch.ones(17), torch.full((51,), HOLD_FEATURES)])
#: Priors on the changes: the shapes' (their unit) and beta's (its unit, N(0, 1) modes).
PSI_SIGMA = 1.0
BETA_SIGMA = 1.0
#: The part of the chord (from the corner on the photo's left) whose rows are read.
MIDDLE = (0.35, 0.65)
#: A row is dark below this times the lips' median luminance (sRGB-encoded) and teeth
#: above :data:`TEETH` times it and less saturated than the lips; in a grey photo, with
#: no saturation to tell a pink tongue from teeth, above :data:`TEETH_GREY` times it.
DARK = 0.55
TEETH = 1.1
TEETH_GREY = 1.3
#: The mouth is closed where the opening's height in its middle is below this share of
#: its width.
CLOSED = 0.04
#: The fewest rows of a run that counts (a run of one pixel is an edge).
MIN_ROWS = 2
#: Teeth within this many rows above the dark gap are the upper teeth's tips.
UPPER_ROWS = 3
#: The upper teeth's drop (``fit/teeth.py``): its prior (metres) and Adam's step (in mm).
TEETH_SIGMA = 0.003
TEETH_LR = 0.1


def _frame(a: np.ndarray, b: np.ndarray):
    d = b - a
    w = float(np.linalg.norm(d))
    t = d / w
    return t, np.array([t[1], -t[0]]), w


def _luma(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def photo_mouth(rgb8: np.ndarray, points: np.ndarray, grey: bool = False) -> dict:
    """What the photo's mouth shows (the module's docstring): ``points`` the face mesh's
    (478 or 468, pixels). Returns {"state": "closed" | "no teeth" | "teeth meet" | "gap,
    teeth below" | "gap to the lip", "frame": (a, t, n, w), "gap": (top, bottom) heights
    of the dark run or None, "opening": (top, bottom), "rows": the rows' classes}
    ("lips only" too: see the module's docstring)."""
    loops = sorted(face_mesh.mesh_loops("FACEMESH_LIPS"),
                   key=lambda q: face_mesh.loop_area(points[q]))
    inner, outer = points[loops[0]], points[loops[-1]]
    # the inner corners: the inner loop's two points farthest apart along x
    i0, i1 = int(np.argmin(inner[:, 0])), int(np.argmax(inner[:, 0]))
    a, b = inner[i0], inner[i1]
    t, n, w = _frame(a, b)
    h_img, w_img = rgb8.shape[:2]
    inside = np.zeros((h_img, w_img), bool)
    rr, cc = polygon(inner[:, 1] - 0.5, inner[:, 0] - 0.5, (h_img, w_img))
    inside[rr, cc] = True
    lips = np.zeros_like(inside)
    rr, cc = polygon(outer[:, 1] - 0.5, outer[:, 0] - 0.5, (h_img, w_img))
    lips[rr, cc] = True
    lips &= ~inside
    out = {"frame": (a, t, n, w), "gap": None}
    ys, xs = np.nonzero(inside)
    rel = np.c_[xs + 0.5, ys + 0.5] - a
    s, h = rel @ t / w, rel @ n / w
    band = (s >= MIDDLE[0]) & (s <= MIDDLE[1])
    if band.sum() == 0 or h[band].max() - h[band].min() < CLOSED or not lips.any():
        out["state"] = "closed"
        return out
    rgb = rgb8.astype(np.float64) / 255.0
    lip = rgb[lips]
    lip_y = float(np.median(_luma(lip)))
    px = rgb[ys[band], xs[band]]
    y = _luma(px)
    dark = y < DARK * lip_y
    teeth = y > (TEETH_GREY if grey else TEETH) * lip_y
    if not grey:
        def sat(c):
            return (c.max(1) - c.min(1)) / np.maximum(c.max(1), 1e-6)
        teeth &= sat(px) < float(np.median(sat(lip)))
    # rows of one pixel (in the frame's h), top first
    hb = h[band]
    row = np.floor((hb.max() - hb) * w).astype(int)
    k = int(row.max()) + 1
    cnt = np.bincount(row, minlength=k).astype(float)
    frac_d = np.bincount(row, dark, minlength=k) / np.maximum(cnt, 1)
    frac_t = np.bincount(row, teeth, minlength=k) / np.maximum(cnt, 1)
    cls = np.where(cnt == 0, "", np.where(frac_d > 0.5, "d", np.where(frac_t > 0.5, "t", "o")))
    out["rows"] = "".join(c or "." for c in cls)
    top = float(hb.max())
    out["opening"] = (top, float(hb.min()))
    run = _longest(cls, "d")
    if run is None:
        out["state"] = ("teeth meet" if (cls == "t").sum() >= MIN_ROWS else
                        "lips only" if (cls == "o").sum() >= MIN_ROWS else "no teeth")
        teeth_run = _longest(cls, "t")
        if out["state"] == "teeth meet" and teeth_run is not None \
                and teeth_run[1] <= len(cls) - UPPER_ROWS:
            # the lower teeth meet behind the upper ones: the longest run of teeth rows
            # ends at the upper tips (where it runs into the lower lip, the lip hides them:
            # no target, so the jaw, not the upper teeth, meets the bite)
            out["upper"] = ("at", top - teeth_run[1] / w)
        return out
    r0, r1 = run   # rows r0 .. r1 - 1 dark
    out["gap"] = (top - r0 / w, top - r1 / w)
    # the upper teeth end where the gap begins if teeth are seen just above it, else
    # (lip or shade there) somewhere above it
    out["upper"] = ("at" if "t" in cls[max(0, r0 - UPPER_ROWS):r0] else "above", out["gap"][0])
    # the lower teeth begin at the first teeth row below the gap (a tongue's rows may lie
    # between: the gap's bottom is then the tongue's top, above the teeth)
    below_t = np.flatnonzero(cls[r1:] == "t")
    out["lower"] = top - (r1 + int(below_t[0])) / w if len(below_t) else out["gap"][1]
    below = (cls[r1:] == "t").sum()
    out["state"] = "gap, teeth below" if below >= MIN_ROWS else "gap to the lip"
    if (cls[:r0] == "t").sum() < MIN_ROWS and below < MIN_ROWS:
        out["state"] = "no teeth"
    return out


def _longest(cls: np.ndarray, c: str) -> tuple[int, int] | None:
    best, start = None, None
    for i, x in enumerate([*cls, ""]):
        if x == c and start is None:
            start = i
        elif x != c and start is not None:
            if i - start >= MIN_ROWS and (best is None or i - start > best[1] - best[0]):
                best = (start, i)
            start = None
    return best


def _tips(state: FitState, v: View, verts: torch.Tensor, rig: TeethRig, frame) -> torch.Tensor:
    """(h_upper, h_lower): the tips' mean heights in the photo's mouth frame."""
    a, _, n, w = (torch.as_tensor(x, dtype=verts.dtype) if not isinstance(x, float) else x
                  for x in frame)
    hs = []
    for ids in (rig.upper, rig.lower):
        p = state.project(v, verts[torch.as_tensor(ids)]).mean(0)
        hs.append(((p - a) @ n) / w)
    return torch.stack(hs)


def _points(state: FitState, v: View, verts: torch.Tensor) -> torch.Tensor:
    pts = state.embedding.points(verts) if (v.embedded and state.embedding is not None) \
        else verts[state.lmk_idx]
    return state.project(v, pts)


def tip_loss(h: torch.Tensor, read: dict) -> torch.Tensor:
    """The teeth term of one view (squared, in units of :data:`SCALE`): ``h`` the model's
    (upper, lower) tip heights, ``read`` :func:`photo_mouth`'s."""
    return lower_loss(h, read) + upper_loss(h, read)


def lower_loss(h: torch.Tensor, read: dict) -> torch.Tensor:
    """The lower tips' part of :func:`tip_loss` (the jaw's target)."""
    st = read["state"]
    if st == "gap, teeth below":
        return ((h[1] - read.get("lower", read["gap"][1])) / SCALE) ** 2
    if st == "gap to the lip":
        return (torch.relu(h[1] - read["gap"][1]) / SCALE) ** 2
    if st in ("teeth meet", "lips only"):
        return (torch.relu(h[0] - h[1]) / SCALE) ** 2
    return h.new_zeros(())


def upper_loss(h: torch.Tensor, read: dict) -> torch.Tensor:
    """The upper tips' part of :func:`tip_loss`: where the photo shows a dark gap, at
    its top where teeth are seen just above it, else not inside it; where the teeth meet,
    at the end of the teeth's rows."""
    up = read.get("upper")
    if up is None or read["state"] not in ("gap, teeth below", "gap to the lip", "teeth meet"):
        return h.new_zeros(())
    how, top = up
    if how == "at":
        return ((h[0] - top) / SCALE) ** 2
    return (torch.relu(top - h[0]) / SCALE) ** 2


def fit_mouth(state: FitState, cfg, log=None, reads: list | None = None) -> dict:
    """The mouth's stage (the module's docstring) on the state's views; ``reads``: per
    view :func:`photo_mouth`'s (or None: no face), default from each view's photo. Sets
    the shapes in the state's (or each view's) psi and the identity; returns the report."""
    mc = cfg.mouth
    rig = teeth_rig(state.model)
    report: dict = {"views": []}
    if rig is None:
        report["note"] = "the model has no teeth or no jaw and lip shapes: skipped"
        return report
    if reads is None:
        reads = face_mesh.views_mesh(state, photo_mouth)
    views = []
    deltas: dict[int, torch.Tensor] = {}
    with torch.no_grad():
        for v, r in zip(state.views, reads):
            if r is None or r["state"] in ("closed", "no teeth"):
                report["views"].append({"state": "no face" if r is None else r["state"],
                                        "note": "mouth kept"})
                continue
            out = state.forward(v)
            held = _points(state, v, out.vertices[0]).clone()
            deltas.setdefault(id(state.view_psi(v)), torch.zeros(len(SHAPES), requires_grad=True))
            views.append((v, r, held, _tips(state, v, out.vertices[0], rig, r["frame"])))
    if not views:
        return report
    idx = torch.as_tensor(rig.psi)
    beta0 = state.beta.detach().clone()
    dbeta = torch.zeros_like(beta0, requires_grad=True)
    teeth0 = state.teeth
    fit_teeth = bool(mc.teeth) and any(
        r.get("upper") is not None and r["state"] in ("gap, teeth below", "gap to the lip",
                                                      "teeth meet")
        for _, r, _, _ in views)
    # the upper teeth's drop, mm (fit/teeth.py), from where a kept fit left it
    drop_mm = torch.tensor([0.0 if teeth0 is None else float(teeth0) * 1e3],
                           requires_grad=fit_teeth)

    def psi_of(v):
        return state.psi_changed(v, idx, deltas[id(state.view_psi(v))])

    def loss_fn(_it):
        total = torch.zeros(())
        terms = {"teeth": 0.0, "hold": 0.0}
        keep = state.beta
        state.beta = beta0 + dbeta
        if fit_teeth:
            state.teeth = drop_mm * 1e-3
        try:
            for v, r, held, _ in views:
                verts = state.forward(v, psi=psi_of(v)).vertices[0]
                w = r["frame"][3]
                teeth = mc.w_teeth * tip_loss(_tips(state, v, verts, rig, r["frame"]), r)
                hold = mc.w_hold * (HOLD_WEIGHTS * (((_points(state, v, verts) - held)
                                                     / (HOLD * w)) ** 2).sum(1)).mean()
                total = total + teeth + hold
                terms["teeth"] += float(teeth.detach())
                terms["hold"] += float(hold.detach())
        finally:
            state.beta, state.teeth = keep, teeth0
        for d in deltas.values():
            total = total + ((d / PSI_SIGMA) ** 2).sum()
        if fit_teeth:
            total = total + ((drop_mm * 1e-3 / TEETH_SIGMA) ** 2).sum()
        return total + ((dbeta / BETA_SIGMA) ** 2).sum(), terms

    groups = [{"params": list(deltas.values()), "lr": mc.lr},
              {"params": [dbeta], "lr": mc.lr}]
    if fit_teeth:
        groups.append({"params": [drop_mm], "lr": TEETH_LR})
    if log is not None:
        rep = log.run("mouth", groups, loss_fn, mc.iterations)
    else:
        rep = run_stage("mouth", groups, loss_fn, mc.iterations, False)
    names = [str(x) for x in state.model.expression_names]
    with torch.no_grad():
        for v, _, _, _ in views:
            state.view_psi(v).copy_(psi_of(v))
        state.beta.copy_(beta0 + dbeta)
        if fit_teeth:
            state.teeth = (drop_mm * 1e-3).clamp(-TEETH_LIMIT, TEETH_LIMIT).detach().clone()
        for v, r, held, before in views:
            verts = state.forward(v).vertices[0]
            after = _tips(state, v, verts, rig, r["frame"])
            moved = (_points(state, v, verts) - held).norm(dim=1) / r["frame"][3]
            report["views"].append({
                "state": r["state"], "rows": r.get("rows"),
                "gap": None if r["gap"] is None else np.round(r["gap"], 4).tolist(),
                "upper": None if r.get("upper") is None else r["upper"][0],
                "lower": None if r.get("lower") is None else round(float(r["lower"]), 4),
                "opening": np.round(r["opening"], 4).tolist(),
                "tips_before": np.round(before.numpy(), 4).tolist(),
                "tips_after": np.round(after.numpy(), 4).tolist(),
                "points_moved_max": {"jawline": round(float(moved[:17].max()), 4),
                                     "brows, nose and eyes": round(float(moved[17:48].max()), 4),
                                     "lips": round(float(moved[48:].max()), 4)},
                "shapes": {names[i]: round(float(state.view_psi(v)[0, i]), 3)
                           for i in rig.psi}})
    report.update(measures="heights above the inner lip corners' chord, shares of its "
                           "length (the photo's face mesh); tips: (upper, lower) incisors",
                  beta_change=round(float(dbeta.detach().norm()), 4),
                  teeth_drop_mm=None if state.teeth is None else round(float(state.teeth) * 1e3, 3),
                  iterations=rep.iterations, seconds=round(rep.seconds, 2),
                  failure=rep.failure)
    return report
