"""The mouth's stage (hack_render/fit/mouth.py): the model's teeth tips, what a photo's
mouth shows (drawn mouths of known rows), and the jaw moved to the teeth with the 68
points held. No renders."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthetic import landmark_view


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def test_01_teeth_tips(model):
    """The upper tips stay with the skull, the lower ones go down with the jaw; at rest
    they lie within 3 mm of each other (the bite) near the midline."""
    from hack_render.fit import teeth

    rig = teeth.teeth_rig(model)
    assert rig is not None and len(rig.upper) >= 2 and len(rig.lower) >= 2
    names = list(model.expression_names)
    with torch.no_grad():
        rest = model(psi=torch.zeros(1, len(names))).vertices[0]
        psi = torch.zeros(1, len(names))
        psi[0, names.index("jawOpen")] = 1.0
        open_ = model(psi=psi).vertices[0]
    up, lo = rig.upper, rig.lower
    assert abs(float(rest[up, 1].mean() - rest[lo, 1].mean())) < 0.003
    assert float(rest[np.r_[up, lo], 0].abs().max()) < teeth.MID_X
    assert float((open_[up] - rest[up]).norm(dim=1).max()) < 1e-6
    assert float(rest[lo, 1].mean() - open_[lo, 1].mean()) > 0.01   # 1 cm down or more


def _mouth_photo(rows: list[tuple[str, int]], grey: bool = False):
    """A photo of a mouth: an outer lip ellipse and an inner opening 60 px wide whose
    rows from the top are filled as ``rows`` says (("teeth" | "dark" | "tongue", count));
    and the face mesh's 478 points with its two lip loops on the ellipses (the rest at
    the centre). Returns (rgb8, points, the opening's top row)."""
    from hack_render.fit import face_mesh

    h = sum(n for _, n in rows)
    cx, cy, rx, ry = 100.0, 100.0, 30.0, h / 2.0
    colours = {"teeth": (235, 232, 222), "dark": (22, 12, 12), "tongue": (205, 90, 100)}
    img = np.zeros((200, 200, 3), np.uint8)
    img[:] = (205, 150, 125)
    yy, xx = np.mgrid[0:200, 0:200] + 0.5
    outer = ((xx - cx) / (rx + 8)) ** 2 + ((yy - cy) / (ry + 8)) ** 2 <= 1
    inner = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1
    img[outer] = (170, 80, 80)
    top = round(cy - ry)
    r = top
    for what, n in rows:
        band = inner & (yy >= r) & (yy < r + n)
        img[band] = colours[what]
        r += n
    if grey:
        img = np.repeat((img @ np.array([0.2126, 0.7152, 0.0722]))[..., None], 3, 2).astype(np.uint8)
    pts = np.full((478, 2), [cx, cy])
    loops = face_mesh.mesh_loops("FACEMESH_LIPS")
    for loop, (ax, ay) in zip(sorted(loops, key=len), ((rx, ry), (rx + 8, ry + 8))):
        ang = np.linspace(0, 2 * np.pi, len(loop), endpoint=False)
        pts[loop] = np.c_[cx + ax * np.cos(ang), cy + ay * np.sin(ang)]
    return img, pts, top


@pytest.mark.parametrize("grey", [False, True])
def test_02_what_the_photo_shows(grey):
    """Drawn mouths: teeth that meet, a dark gap over the lower teeth (its rows found
    within 1.5 px), a dark gap down to the tongue, a dark mouth without teeth, one showing
    only the tongue and a closed one are told apart, in colour and in grey."""
    from hack_render.fit import mouth

    def read(rows):
        img, pts, top = _mouth_photo(rows, grey)
        return mouth.photo_mouth(img, pts, grey), top

    r, top = read([("teeth", 10), ("teeth", 10)])
    assert r["state"] == "teeth meet"
    w = r["frame"][3]
    # teeth down to the lower lip, which hides their tips: no target for them
    assert r.get("upper") is None
    # the teeth meet behind the upper ones: their run's bottom is the upper tips' target
    r, top = read([("teeth", 12), ("tongue", 8)])
    assert r["state"] == "teeth meet" and abs(100.0 - r["upper"][1] * w - (top + 12)) < 1.5
    r, top = read([("teeth", 8), ("dark", 10), ("teeth", 6)])
    assert r["state"] == "gap, teeth below"
    # the gap's rows in pixels below the corners' chord (y = 100 - height * w)
    got = [100.0 - g * w for g in r["gap"]]
    assert abs(got[0] - (top + 8)) < 1.5 and abs(got[1] - (top + 18)) < 1.5, got
    assert r["upper"] == ("at", r["gap"][0])
    assert abs(100.0 - r["lower"] * w - (top + 18)) < 1.5
    # a tongue over the lower teeth: they begin below it
    r, top = read([("teeth", 8), ("dark", 10), ("tongue", 4), ("teeth", 6)])
    assert r["state"] == "gap, teeth below"
    assert abs(100.0 - r["lower"] * w - (top + 22)) < 1.5
    assert abs(100.0 - r["gap"][1] * w - (top + 18)) < 1.5
    r, _ = read([("teeth", 8), ("dark", 10), ("tongue", 6)])
    assert r["state"] == "gap to the lip" and r["upper"][0] == "at"
    # the upper lip's colour (a tongue's here) just above the gap: the tips only above it
    r, _ = read([("teeth", 4), ("tongue", 6), ("dark", 10), ("teeth", 6)])
    assert r["state"] == "gap, teeth below" and r["upper"] == ("above", r["gap"][0])
    r, _ = read([("dark", 8), ("tongue", 10)])
    assert r["state"] == "no teeth"
    r, _ = read([("tongue", 12)])
    assert r["state"] == "lips only"
    r, _ = read([("teeth", 1)])
    assert r["state"] == "closed"


def test_03_tip_loss_targets():
    """Each state's target: two-sided on the gap's bottom, one-sided otherwise."""
    from hack_render.fit.mouth import SCALE, tip_loss

    h = torch.tensor([0.0, -0.1])
    assert float(tip_loss(h, {"state": "gap, teeth below", "gap": (0.0, -0.1)})) == 0
    assert float(tip_loss(h, {"state": "gap, teeth below", "gap": (0.0, -0.2)})) == \
        pytest.approx((0.1 / SCALE) ** 2)
    # the teeth's top below a tongue, not the gap's bottom
    assert float(tip_loss(h, {"state": "gap, teeth below", "gap": (0.0, -0.05),
                              "lower": -0.1})) == 0
    assert float(tip_loss(h, {"state": "gap to the lip", "gap": (0.0, -0.05)})) == 0
    assert float(tip_loss(h, {"state": "gap to the lip", "gap": (0.0, -0.2)})) > 0
    assert float(tip_loss(h, {"state": "teeth meet"})) == pytest.approx((0.1 / SCALE) ** 2)
    assert float(tip_loss(torch.tensor([-0.1, 0.0]), {"state": "teeth meet"})) == 0
    assert float(tip_loss(h, {"state": "lips only"})) == pytest.approx((0.1 / SCALE) ** 2)
    assert float(tip_loss(h, {"state": "no teeth"})) == 0
    assert float(tip_loss(h, {"state": "closed"})) == 0
    # the upper tips: at the gap's top, or (lip above it) not inside the gap
    gap = {"state": "gap, teeth below", "gap": (0.05, -0.1)}
    assert float(tip_loss(h, gap | {"upper": ("at", 0.05)})) == pytest.approx((0.05 / SCALE) ** 2)
    assert float(tip_loss(h, gap | {"upper": ("above", 0.05)})) == pytest.approx((0.05 / SCALE) ** 2)
    assert float(tip_loss(h, gap | {"upper": ("above", -0.05)})) == 0
    assert float(tip_loss(h, {"state": "teeth meet", "upper": ("at", 0.05)})) == \
        pytest.approx((0.1 / SCALE) ** 2 + (0.05 / SCALE) ** 2)
    assert float(tip_loss(h, {"state": "lips only", "upper": ("at", 0.05)})) == \
        pytest.approx((0.1 / SCALE) ** 2)


def _state(model):
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter

    photo, det = landmark_view(model, angles_deg=(0.0, 10.0, 0.0), res=256)
    cfg = load_config(None, {"silhouette": {"mode": "off"}, "mouth": {"iterations": 120}})
    f = Fitter([photo], [det], cfg, model=model, progress=False)
    v = f.state.views[0]
    with torch.no_grad():
        v.head_angles.copy_(torch.deg2rad(torch.tensor([0.0, 10.0, 0.0])))
        v.transl.copy_(torch.tensor([0.0, -0.03, 1.0]))
        v.log_focal.fill_(float(np.log(50.0 / 36.0 * 256 * 2.2)))
    return f.state, cfg


def test_04_jaw_moved_to_the_teeth(model):
    """A smile whose lips part over a nearly closed jaw, fitted with the jaw dropped: told
    that the photo's teeth meet, the stage raises the lower teeth to the upper ones (from
    a quarter of the mouth's width below them to within 7 %) with the 68 points held (the
    lips within 4 % of the mouth's width, the rest within 2.5 %), and the jaw drop falls; told nothing (a closed mouth), it
    changes nothing."""
    from hack_render.fit import mouth, teeth

    st, cfg = _state(model)
    v = st.views[0]
    names = [str(n) for n in model.expression_names]
    with torch.no_grad():
        for k, x in {"jawOpen": 0.4, "mouthSmile_L": 0.6, "mouthSmile_R": 0.6}.items():
            st.psi[0, names.index(k)] = x
        verts = st.forward(v).vertices[0]
        pts = mouth._points(st, v, verts).numpy()
    # the photo's frame: the model's own inner lip corners (the 68's 60 and 64)
    a, b = pts[60], pts[64]
    t, n, w = mouth._frame(a, b)
    frame = (a, t, n, w)
    rig = teeth.teeth_rig(model)
    with torch.no_grad():
        before = mouth._tips(st, v, verts, rig, frame)
    assert float(before[0] - before[1]) > 0.25
    psi0, beta0 = st.psi.detach().clone(), st.beta.detach().clone()
    rep = mouth.fit_mouth(st, cfg, reads=[{"state": "closed", "frame": frame, "gap": None}])
    assert torch.equal(st.psi, psi0) and torch.equal(st.beta, beta0)
    assert rep["views"][0]["note"] == "mouth kept"
    read = {"state": "teeth meet", "frame": frame, "gap": None, "opening": (0.1, -0.3)}
    rep = mouth.fit_mouth(st, cfg, reads=[read])
    with torch.no_grad():
        verts = st.forward(v).vertices[0]
        after = mouth._tips(st, v, verts, rig, frame)
        moved = ((mouth._points(st, v, verts) - torch.as_tensor(pts)).norm(dim=1) / w).numpy()
    assert float(after[0] - after[1]) < 0.07, (before, after)
    # the lips give most (the model's lips cannot part as far over a closed jaw), the
    # chin, nose, eyes and brows less
    assert moved[48:].max() < 0.04 and moved[:48].max() < 0.025, moved
    assert float(st.psi.detach()[0, names.index("jawOpen")]) < 0.2
    assert rep["views"][0]["state"] == "teeth meet"


def test_06_teeth_drop_moves_the_upper_teeth_only(model):
    """The upper teeth's drop (fit/teeth.py) lowers the upper teeth, and nothing else, by
    the drop along the posed head's down (a turned and tilted head), clamped to the
    limit; its gradient matches finite differences."""
    from hack_render.fit import teeth

    rig = teeth.teeth_rig(model)
    names = list(model.expression_names)
    theta = torch.zeros(1, 8, 3)
    theta[0, 7] = torch.deg2rad(torch.tensor([20.0, -35.0, 10.0]))
    with torch.no_grad():
        out = model(psi=torch.zeros(1, len(names)), theta=theta)
        v, rest = out.vertices[0].double(), out.rest_vertices[0].double()
    d = torch.tensor([0.002], dtype=torch.float64, requires_grad=True)
    moved = teeth.apply_teeth(rig, v, rest, d)
    delta = (moved - v).detach()
    others = np.setdiff1d(np.arange(model.num_vertices), rig.upper_set)
    assert float(delta[others].abs().max()) == 0
    # the skull's down, posed: the rest -y through the head's rotation
    from hack_render.geometry.rigid import kabsch

    r, _ = kabsch(rest[rig.upper_set].numpy(), v[rig.upper_set].numpy())
    want = 0.002 * -r[:, 1]
    np.testing.assert_allclose(delta[rig.upper_set].numpy(), np.broadcast_to(want, (len(rig.upper_set), 3)),
                               atol=1e-9)
    assert float(-r[1, 1]) < -0.8   # still mostly downwards
    big = teeth.apply_teeth(rig, v, rest, torch.tensor([0.01], dtype=torch.float64))
    assert float((big - v)[rig.upper_set].norm(dim=1).max()) == pytest.approx(teeth.TEETH_LIMIT)
    # gradient of a tip's height against central differences
    def f(x):
        return teeth.apply_teeth(rig, v, rest, x)[rig.upper, 1].mean()

    f(d).backward()
    eps = 1e-5
    fd = (f(torch.tensor([0.002 + eps], dtype=torch.float64))
          - f(torch.tensor([0.002 - eps], dtype=torch.float64))) / (2 * eps)
    assert float(d.grad) == pytest.approx(float(fd), rel=1e-6)


def test_07_teeth_drop_recovered(model):
    """A photo whose dark gap begins 1.5 mm below the model's upper tips (the teeth seen
    above it): the stage lowers the upper teeth to within 0.35 mm of that (the prior
    shrinks it a little), the lower tips go to the gap's bottom, and the drop goes into
    params.npz's ``teeth_drop``. Teeth that meet with no teeth run read fit no drop."""
    from hack_render.fit import mouth, teeth

    st, cfg = _state(model)
    v = st.views[0]
    rig = teeth.teeth_rig(model)
    names = [str(n) for n in model.expression_names]
    with torch.no_grad():
        st.psi[0, names.index("jawOpen")] = 0.3
        verts = st.forward(v).vertices[0]
        pts = mouth._points(st, v, verts).numpy()
        a, b = pts[60], pts[64]
        t, n, w = mouth._frame(a, b)
        frame = (a, t, n, w)
        h0 = mouth._tips(st, v, verts, rig, frame)
        st.teeth = torch.tensor([0.0015])
        h1 = mouth._tips(st, v, st.forward(v).vertices[0], rig, frame)
        st.teeth = None
    assert float(h0[0] - h1[0]) > 0.01     # 1.5 mm is visible in the frame
    read = {"state": "gap, teeth below", "frame": frame, "gap": (float(h1[0]), float(h0[1])),
            "opening": (0.2, -0.4), "upper": ("at", float(h1[0]))}
    rep = mouth.fit_mouth(st, cfg, reads=[read])
    assert st.teeth is not None and abs(float(st.teeth) - 0.0015) < 0.00035, rep["teeth_drop_mm"]
    with torch.no_grad():
        after = mouth._tips(st, v, st.forward(v).vertices[0], rig, frame)
    assert abs(float(after[0] - h1[0])) < 0.35 * float(h0[0] - h1[0])
    assert abs(float(after[1] - h0[1])) < 0.02
    assert rep["teeth_drop_mm"] == pytest.approx(float(st.teeth) * 1e3, abs=1e-3)
    st2, _ = _state(model)
    mouth.fit_mouth(st2, cfg, reads=[{"state": "teeth meet", "frame": frame, "gap": None,
                                      "opening": (0.1, -0.3)}])
    assert st2.teeth is None
    # teeth that meet, their run ending 1.5 mm below the model's upper tips: the upper
    # teeth drop to it and the lower ones stay behind them (up to the upper tips)
    st3, _ = _state(model)
    with torch.no_grad():
        st3.psi[0, names.index("jawOpen")] = 0.3
    mouth.fit_mouth(st3, cfg, reads=[{"state": "teeth meet", "frame": frame, "gap": None,
                                      "opening": (0.2, -0.4), "upper": ("at", float(h1[0]))}])
    assert st3.teeth is not None and abs(float(st3.teeth) - 0.0015) < 0.00045, st3.teeth
    with torch.no_grad():
        v3 = st3.views[0]
        after = mouth._tips(st3, v3, st3.forward(v3).vertices[0], rig, frame)
    assert float(after[0] - after[1]) < 0.07


@pytest.mark.parametrize("bad", [{"iterations": -1}, {"iterations": 2.5}, {"lr": 0},
                                 {"w_hold": float("nan")}, {"w_teeth": -1.0}, {"teeth": 1},
                                 {"enabled": True, "w_hold": True}])
def test_05_bad_settings_are_refused(bad):
    """The mouth section's settings are checked when the config loads, naming the key."""
    from hack_render.errors import HackError
    from hack_render.fit.config import load_config

    key = next(k for k in bad if k != "enabled")
    with pytest.raises(HackError, match=f"mouth.{key}: expected"):
        load_config(None, {"mouth": bad})


def test_08_the_face_mesh_runs_once_per_view(monkeypatch):
    """The mouth's and the final stages read one face mesh per view
    (``face_mesh.view_mesh``): found once, again only when the detected points change,
    and handed out as copies (a caller's edit does not reach the next)."""
    from types import SimpleNamespace

    from hack_render.fit import face_mesh

    calls = []

    def fake(rgb8, points=None):
        calls.append(np.asarray(points).copy())
        return np.full((478, 2), float(len(calls)))

    monkeypatch.setattr(face_mesh, "iris_landmarks", fake)
    photo = SimpleNamespace(uint8=lambda: np.zeros((8, 8, 3), np.uint8), is_grey=False)
    v = SimpleNamespace(photo=photo, detection=SimpleNamespace(points=np.ones((68, 2))),
                        mesh478=None)
    state = SimpleNamespace(views=[v])
    first = face_mesh.views_mesh(state)[0]
    first[:] = -1.0
    again = face_mesh.views_mesh(state, lambda img, pts, grey: pts.sum())
    assert len(calls) == 1 and again[0] == 478 * 2 * 1.0
    v.detection.points = np.ones((68, 2)) * 2
    assert face_mesh.view_mesh(v)[0, 0] == 2.0 and len(calls) == 2
