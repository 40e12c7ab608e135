"""The eyes' stage (hack_render/fit/eyes.py, fit/gaze.py): the lids' closure and the
eyeballs' gaze recovered from the eye points and iris centres of a synthetic photo, and
the gaze carried by the state's forward (only the eyeballs move). No renders."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthetic import landmark_view


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def _fitter(model, yaw=15.0):
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter

    photo, det = landmark_view(model, angles_deg=(0.0, yaw, 0.0), res=256)
    cfg = load_config(None, {"silhouette": {"mode": "off"}, "eyes": {"iterations": 150, "mesh_offset": False}})
    f = Fitter([photo], [det], cfg, model=model, progress=False)
    v = f.state.views[0]
    with torch.no_grad():
        v.head_angles.copy_(torch.deg2rad(torch.tensor([0.0, yaw, 0.0])))
        v.transl.copy_(torch.tensor([0.0, -0.03, 1.0]))
        v.log_focal.fill_(float(np.log(50.0 / 36.0 * 256 * 2.2)))
    return f, cfg


def _photo_points(state, v):
    """The eyes a face mesh would find on the photo of the state: per eye (the 68's
    order) its six points and the iris centre (the eyeball's front) nearest them."""
    from hack_render.fit import eyes, gaze

    with torch.no_grad():
        out = state.forward(v)
        verts = out.vertices[0]
        pts = state.project(v, state.embedding.points(verts) if v.embedded
                            else verts[state.lmk_idx]).numpy()
        rig = gaze.eye_rig(state.model)
        fronts = state.project(v, gaze.iris_centres(rig, verts, out.rest_vertices[0],
                                                    v.gaze)).numpy()
    res = []
    for ids in eyes.EYES_68:
        six = pts[list(ids)]
        res.append((six, min(fronts, key=lambda c: float(np.linalg.norm(c - six.mean(0))))))
    return res


def test_01_lid_closure_and_gaze_are_recovered(model):
    """A person squinting with one eye half closed and looking to her left and down: from
    the neutral eyes the stage recovers the closure (within 0.12) and the gaze (within
    1.5 degrees); without the stage the model's eyes are those of the neutral face."""
    from hack_render.fit import eyes

    f, cfg = _fitter(model)
    st, v = f.state, f.state.views[0]
    names = [str(n) for n in model.expression_names]
    truth = {"eyeBlink_L": 0.45, "eyeSquint_L": 0.2, "eyeSquint_R": 0.6}
    true_gaze = np.radians([12.0, -8.0])
    with torch.no_grad():
        for k, x in truth.items():
            st.psi[0, names.index(k)] = x
        v.gaze = torch.tensor(true_gaze, dtype=torch.float32)
    photo = _photo_points(st, v)
    with torch.no_grad():
        st.psi.zero_()
    v.gaze = None
    start = eyes._photo_targets(_photo_points(st, v))
    target = eyes._photo_targets(photo)
    # the truth is far from the neutral eye
    assert max(abs(a - b).max() for a, b in zip(start, target)) > 0.04
    rep = eyes.fit_eyes(st, cfg, contours=[photo])
    got = {k: float(st.psi[0, names.index(k)]) for k in
           ("eyeBlink_L", "eyeSquint_L", "eyeWide_L", "eyeBlink_R", "eyeSquint_R",
            "eyeWide_R")}
    for k, x in got.items():
        assert abs(x - truth.get(k, 0.0)) < 0.12, (k, x, got)
    assert np.degrees(np.abs(v.gaze.numpy() - true_gaze)).max() < 1.5, rep
    # the measures now match the photo's
    after = eyes._photo_targets(_photo_points(st, v))
    assert max(abs(a - b).max() for a, b in zip(after, target)) < 0.01
    # the other expressions are untouched
    others = [i for i, n in enumerate(names) if n not in got]
    assert float(st.psi[0, others].abs().max()) == 0.0


def test_02_gaze_turns_the_eyeballs_only(model):
    """The gaze moves the eyeballs' vertices (a rotation about the eye's centre: their
    distances from it kept) and nothing else; gaze 0 is the model's own eye."""
    from hack_render.fit import gaze

    f, _ = _fitter(model, yaw=25.0)
    st, v = f.state, f.state.views[0]
    rig = gaze.eye_rig(model)
    assert len(rig) == 2 and [e.side for e in rig] == ["L", "R"]
    with torch.no_grad():
        base = st.forward(v).vertices[0]
        v.gaze = torch.zeros(2)
        assert torch.allclose(st.forward(v).vertices[0], base, atol=1e-6)
        v.gaze = torch.tensor([0.3, 0.2])
        out = st.forward(v)
    moved = (out.vertices[0] - base).norm(dim=1) > 1e-6
    balls = np.zeros(len(base), bool)
    for e in rig:
        balls[e.ball] = True
    assert moved.numpy()[~balls].sum() == 0 and moved.numpy()[balls].mean() > 0.9
    for e in rig:
        c = gaze.sphere_centre(base[e.shell].double().numpy())
        d0 = np.linalg.norm(base[e.ball].numpy() - c, axis=1)
        d1 = np.linalg.norm(out.vertices[0][e.ball].numpy() - c, axis=1)
        np.testing.assert_allclose(d1, d0, atol=2e-6)
