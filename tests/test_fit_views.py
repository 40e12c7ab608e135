"""The landmark stages on noiseless synthetic views (issue 25, part 3): a three-quarter
camera is a turned body, not a twisted neck; a second view improves the identity;
strong expressions come back near their strength."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    torch.set_num_threads(1)
    return load_default_model()


def _view(model, beta=None, psi=None, head=(0.0, 0.0, 0.0), torso=(0.0, 0.0, 0.0),
          res=256, name="v"):
    """(Photo, Detection): the true landmark vertices of the model with the neck turned by
    ``head`` and the whole body by ``torso`` (degrees: pitch, yaw, roll), seen by a
    frontal camera (110 mm equivalent, 1 m). A body turned by 30 deg before a frontal
    camera is a frontal body seen by a camera 30 deg to its side."""
    from hack_render.fit.fitter import R0
    from hack_render.fit.photo import Photo
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.vision.detection import Detection
    from scenes.cameras import Camera

    th = distribute_head_rotation(torch.deg2rad(torch.tensor(head, dtype=torch.float32)))[None]
    go = torch.deg2rad(torch.tensor([torso], dtype=torch.float32))
    with torch.no_grad():
        out = model(beta=beta, psi=psi, theta=th, global_orient=go)
    f = 50.0 / 36.0 * res * 2.2
    K = np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1.0]])
    cam = Camera(K, R0.numpy().astype(np.float64), np.array([0.0, -0.03, 1.0]), res, res, "v")
    lm = cam.project(out.landmarks[0].numpy().astype(np.float64))
    return (Photo(np.full((res, res, 3), 0.5, np.float32), name),
            Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth"))


def _fit(model, views, over=None):
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter

    cfg = load_config(None, {"camera": {"iterations": 80},
                             "shape": {"iterations": 150, "n_beta": 20},
                             "silhouette": {"mode": "off"}, **(over or {})})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = Fitter([v[0] for v in views], [v[1] for v in views], cfg, model=model,
                   appearance=None, progress=False)
        f.fit_camera()
        f.fit_shape()
    return f


def test_01_three_quarter_camera_is_a_turned_body(model):
    """Camera 30 deg to the side of the body (the body turned 30 deg), neck turned 3 deg:
    with camera.rotate "torso" the fitted neck stays small and the torso takes the turn;
    with "head" (the default) the same view is read as a neck twisted by ~30 deg."""
    view = _view(model, head=(0.0, 3.0, 0.0), torso=(0.0, 30.0, 0.0))
    f = _fit(model, [view], {"camera": {"iterations": 80, "rotate": "torso"}})
    v = f.state.views[0]
    neck_yaw = float(torch.rad2deg(f.theta(v).detach()[0, :, 1].sum()))
    torso_yaw = float(torch.rad2deg(v.global_orient.detach()[1]))
    assert abs(neck_yaw) < 12.0, neck_yaw
    assert torso_yaw > 18.0, torso_yaw
    old = _fit(model, [view])  # the default, camera.rotate "head"
    old_yaw = float(torch.rad2deg(old.theta(old.state.views[0]).detach()[0, :, 1].sum()))
    assert old_yaw > 20.0 and abs(neck_yaw) < 0.5 * old_yaw, (old_yaw, neck_yaw)


@pytest.mark.slow
def test_02_second_view_improves_identity(model):
    """Shared beta over a near-frontal and a 45-degree view: the neutral shape's error
    is below either view's alone."""
    from hack_render.fit.metrics import similarity_error

    g = torch.Generator().manual_seed(3)
    beta = torch.randn(1, 20, generator=g)
    a = _view(model, beta=beta, head=(0.0, 5.0, 0.0), name="a")
    b = _view(model, beta=beta, head=(0.0, 45.0, 0.0), name="b")
    with torch.no_grad():
        true = model(beta=beta).vertices[0].numpy()[:9409]
    err = {}
    for key, views in (("a", [a]), ("b", [b]), ("ab", [a, b])):
        f = _fit(model, views)
        with torch.no_grad():
            err[key] = similarity_error(model(beta=f.state.beta).vertices[0].numpy()[:9409], true)
    assert err["ab"] < 0.93 * min(err["a"], err["b"]), err


# one unit (jaw open) runs the same path as the two of the broad smile (the harder case: two
# units the L1 prior could share out among their neighbours): opt-in (--runslow)
@pytest.mark.parametrize("units", [pytest.param(["jawOpen"], marks=pytest.mark.slow),
                                   ["mouthSmile_L", "mouthSmile_R"]], ids=["jaw", "smile"])
def test_03_strong_expressions_reach_their_strength(model, units):
    """Jaw open and a broad smile at 0.9, neck turned 10 deg: the fitted units reach at
    least 75 % of it (the L1 prior's shrinkage), and little else switches on."""
    names = list(model.expression_names)
    idx = [names.index(u) for u in units]
    psi = torch.zeros(1, model.num_expressions)
    psi[0, idx] = 0.9
    f = _fit(model, [_view(model, psi=psi, head=(5.0, 10.0, 0.0))])
    p = f.state.psi.detach()[0]
    assert float(p[idx].min()) > 0.75 * 0.9, (units, p[idx])
    assert float(p.sum() - p[idx].sum()) < 0.3, (units, float(p.sum()))


def test_04_mesh_fallback_and_hidden_points(model, monkeypatch):
    """Where dlib finds no face, ``landmarks.detect`` takes the face mesh's detection
    (source "mesh", its visibility kept); the landmark term gives hidden points no
    weight, so moving them anywhere leaves it unchanged, and the mesh's fixed points are
    not re-matched to the jaw contour."""
    from hack_render.errors import HackError
    from hack_render.fit import landmarks, terms
    from hack_render.vision import detect as vd
    from hack_render.vision.detection import FaceWarning

    photo, det = _view(model, head=(0.0, 60.0, 0.0))
    hidden = np.zeros(68, bool)
    hidden[36:42] = True  # an eye (inside the face's box, whose size scales the term)

    def no_face(*a, **k):
        raise HackError("photo: no face found. Use a photo ...")

    fake = vd.FaceLandmarks(det.points.copy(), det.box, 1, "mesh", visible=~hidden,
                            convention="3d")
    monkeypatch.setattr(landmarks, "detect_landmarks", no_face)
    monkeypatch.setattr(vd, "detect_face", lambda *a, **k: fake)
    with pytest.warns(FaceWarning, match="face mesh"):
        got = landmarks.detect(photo.uint8())
    assert got.source == "mesh" and (got.visible == ~hidden).all()
    f = _fit(model, [(photo, got)], {"camera": {"iterations": 0},
                                     "shape": {"iterations": 0}})
    v = f.state.views[0]
    with torch.no_grad():
        verts = f.forward(v).vertices[0]
        a = float(terms.landmark_loss(f.state, f.cfg, v, verts, 0))
        v.detection.points[hidden] += 3.0
        b = float(terms.landmark_loss(f.state, f.cfg, v, verts, 0))
    assert a == pytest.approx(b) and v.jaw is None
    # the photometric stage holds the shape predictors' less sure points more loosely
    # than the face mesh's and dlib's
    pc = f.cfg.photometric
    assert pc.w_landmarks_fallback < pc.w_landmarks
    assert terms.landmark_scale(f.cfg, v) == pc.w_landmarks
    v.detection.source = "ert"
    assert terms.landmark_scale(f.cfg, v) == pc.w_landmarks_fallback
    v.detection.source = "dlib"
    assert terms.landmark_scale(f.cfg, v) == pc.w_landmarks
    monkeypatch.setattr(landmarks, "detect_landmarks", no_face)
    from hack_render.fit.config import LandmarkConfig

    with pytest.raises(HackError, match="no face found"):
        landmarks.detect(photo.uint8(), LandmarkConfig(fallback="off"))


def _random_state(model, heads, n_beta: int, seed: int, density: float):
    """(FitState, config) of a landmark fit of views of the model turned by ``heads``
    (per-view expressions, no silhouette), its parameters set at random: beta N(0, 1),
    head turns about 0.2 rad, joint residuals, torso turns, and a share ``density`` of
    each view's expression weights nonzero."""
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter

    views = [_view(model, head=h, name=f"v{i}") for i, h in enumerate(heads)]
    cfg = load_config(None, {"per_view_expression": True, "silhouette": {"mode": "off"},
                             "shape": {"n_beta": n_beta}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        st = Fitter([v[0] for v in views], [v[1] for v in views], cfg, model=model,
                    appearance=None, progress=False).state
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        st.beta.copy_(torch.randn(st.beta.shape, generator=g))
        for v in st.views:
            v.head_angles.copy_(0.2 * torch.randn(3, generator=g))
            v.dtheta.copy_(0.02 * torch.randn(8, 3, generator=g))
            v.global_orient.copy_(0.05 * torch.randn(3, generator=g))
            on = torch.rand(v.psi.shape, generator=g) < density
            v.psi.copy_(torch.rand(v.psi.shape, generator=g) * on)
    return st, cfg


def test_05_batched_views_match_one_forward_per_view(model):
    """The landmark stages evaluate the views in one batched forward
    (``FitState.forward_views``; on the identity's personalised bases while beta takes no
    gradient): the same vertices as one forward per view, and the same gradients for the
    stage's own parameters (the others frozen by ``grads_only``, their flags restored)."""
    st, _ = _random_state(model, [(0, 0, 0), (10, -25, 5), (-8, 30, 0)], 20, seed=0,
                          density=0.2)

    def grads(batched: bool, params):
        for p in st.leaves():
            p.grad = None
        verts = (st.forward_views() if batched
                 else [st.forward(v).vertices[0] for v in st.views])
        sum((vv[::97] ** 2).sum() * (i + 1) for i, vv in enumerate(verts)).backward()
        assert all(p.grad is not None for p in params), [p.grad is None for p in params]
        return [vv.detach() for vv in verts], [p.grad.clone() for p in params]

    # the shape stage (beta takes gradients): the batched forward of the model
    shape_params = [st.beta] + [p for v in st.views for p in (v.head_angles, v.psi)]
    with st.grads_only(shape_params):
        (va, ga), (vb, gb) = grads(True, shape_params), grads(False, shape_params)
    for a, b in zip(va + ga, vb + gb):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    # the camera stage (beta frozen): the personalised bases, made once for this beta
    cam_params = [p for v in st.views for p in (v.head_angles, v.global_orient)]
    with st.grads_only(cam_params):
        assert not st.beta.requires_grad and not st.views[0].psi.requires_grad
        (va, ga), (vb, gb) = grads(True, cam_params), grads(False, cam_params)
        assert st.personal is not None and torch.equal(st.personal[0], st.beta)
        first = st.personal[1]
        st.forward_views()
        assert st.personal[1] is first          # kept while beta is unchanged
    for a, b in zip(va + ga, vb + gb):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    assert all(p.requires_grad for p in st.leaves())
    with torch.no_grad():
        st.beta.add_(0.5)
    with st.grads_only(cam_params):
        st.forward_views()
        assert torch.equal(st.personal[0], st.beta)   # rebuilt for the new identity


def test_06_landmark_stages_read_a_vertex_subset(model):
    """The camera stage and the shape stage without a silhouette term compute only the
    vertices their terms read (``FitState.landmark_reads``, ``geometry/subset.py``): there
    the same vertices and normals as the whole model's forward, the same objective and
    the same gradients for every parameter; a vertex the model blends between joints, or
    one carrying a pose corrective or the larynx, sends the forward back to the model."""
    from hack_render.fit import terms
    from hack_render.geometry.subset import VertexSubset
    from hack_render.render.bridge import vertex_normals_torch

    st, cfg = _random_state(model, [(0, 0, 0), (10, -25, 5)], 30, seed=1, density=0.3)
    index, sub = st.landmark_reads()
    assert sub is not None and torch.equal(sub.index, torch.as_tensor(index))
    cand = np.concatenate(st.jaw.candidates)
    need = np.r_[st.lmk_idx.numpy(), cand, st.embedding.vertex_ids.reshape(-1)]
    assert np.isin(need, index).all() and len(index) < model.num_vertices // 20
    full = [x.detach() for x in st.forward_views()]
    part = [x.detach() for x in st.forward_views(landmarks_only=True)]
    outside = np.setdiff1d(np.arange(model.num_vertices), index)
    for a, b in zip(full, part):
        torch.testing.assert_close(b[index], a[index], rtol=0, atol=2e-6)
        assert not b[outside].any()
        # the jawline re-match reads the normals at its candidates: every face about
        # them is in the subset
        na, nb = (vertex_normals_torch(x, st.faces)[cand] for x in (a, b))
        torch.testing.assert_close(nb, na, rtol=0, atol=1e-5)

    def objective(subset: bool, fn):
        saved = st.reads
        if not subset:
            st.reads = (index, None)          # no subset: the whole model's forward
        for p in st.leaves():
            p.grad = None
        loss, _ = fn(st, cfg, 0)
        loss.backward()
        st.reads = saved
        # eta and tau move no vertex read here: no gradient (None) or zeros
        return [loss.detach()] + [torch.zeros_like(p) if p.grad is None else p.grad.clone()
                                  for p in st.leaves()]

    for fn in (terms.shape_objective, terms.camera_objective):
        a, b = objective(False, fn), objective(True, fn)
        assert len(a) == len(b) > 8
        for x, y in zip(a, b):
            torch.testing.assert_close(y, x, rtol=1e-4, atol=1e-6)
    for moved in (model.blended_vertices[:1], model.pose_personal.vertices[:1],
                  model.larynx_vertices[:1]):
        assert VertexSubset.build(model, np.r_[index, moved.numpy()]) is None
    assert VertexSubset.build(model, [model.num_vertices]) is None
