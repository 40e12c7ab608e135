"""The landmark embedding calibrated to the detector (hack_render/fit/landmark_embedding.py):
barycentric landmark points (vertex landmarks when one-hot, differentiable), the
calibration search on a tiny synthetic problem with a faked detector (known surface points
projected, plus noise; no dlib, no renders), the shipped file, and the fitter's use of it
(and its fallback)."""

import warnings

import numpy as np
import pytest
import torch

from hack_render.fit import landmark_embedding as le
from hack_render.learn import landmark_calibration as lc


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def test_01_one_hot_reproduces_vertex_landmarks(model):
    emb = le.LandmarkEmbedding.from_vertices(model.landmark_indices.numpy(), model.faces.numpy())
    emb.validate(model.num_vertices, model.faces.numpy())
    with torch.no_grad():
        out = model(beta=torch.randn(1, 10, generator=torch.Generator().manual_seed(0)))
    v = out.vertices[0]
    assert torch.equal(emb.points(v), v[model.landmark_indices])
    assert torch.equal(emb.points(v), out.landmarks[0])
    np.testing.assert_array_equal(emb.points_np(v.numpy()), out.landmarks[0].numpy())


def test_02_barycentric_points_are_differentiable():
    g = torch.Generator().manual_seed(1)
    verts = torch.randn(12, 3, dtype=torch.float64, generator=g, requires_grad=True)
    ids = torch.randint(0, 12, (5, 3), generator=g)
    b = torch.rand(5, 3, dtype=torch.float64, generator=g)
    bary = (b / b.sum(1, keepdim=True)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, y: le.embedded_points(x, ids, y), (verts, bary))
    # batched vertices
    vb = torch.randn(2, 12, 3, dtype=torch.float64, generator=g)
    out = le.embedded_points(vb, ids, bary.detach())
    assert out.shape == (2, 5, 3)
    assert torch.allclose(out[1], le.embedded_points(vb[1], ids, bary.detach()))


def _fake_subjects(model, true_points_fn, n=6, noise=0.002, seed=3):
    """Posed subjects with random beta, head rotations and cameras; the 'detector' returns
    the projections of known surface points plus Gaussian noise (inter-ocular units)."""
    from hack_render.geometry.skeleton import distribute_head_rotation
    from scenes.cameras import orbit

    rng = np.random.default_rng(seed)
    V, K, R, t, P = [], [], [], [], []
    for s in range(n):
        beta = torch.tensor(rng.normal(0, 0.8, (1, 10)), dtype=torch.float32)
        ang = torch.deg2rad(torch.tensor(rng.uniform(-1, 1, 3) * [8, 20, 5], dtype=torch.float32))
        with torch.no_grad():
            verts = model(beta=beta, theta=distribute_head_rotation(ang)[None]).vertices[0]
        verts = verts.numpy().astype(np.float64)
        cam = orbit(256, 256, 85.0, float(rng.uniform(-20, 20)), float(rng.uniform(-5, 10)))
        uv = cam.project(true_points_fn(verts))
        iod = np.linalg.norm(uv[36] - uv[45])
        uv = uv + rng.normal(0, noise * iod, uv.shape)
        V.append(verts.astype(np.float32)), K.append(cam.K), R.append(cam.R)
        t.append(cam.t), P.append(uv)
    return lc.CalibrationSet(np.array(V), np.array(K), np.array(R), np.array(t), np.array(P),
                             np.arange(n))


def test_03_calibration_recovers_a_known_offset_embedding(model):
    faces = model.faces.numpy()
    tmpl = model.template.numpy().astype(np.float64)
    li = model.landmark_indices.numpy()
    truth = le.LandmarkEmbedding.from_vertices(li, faces)
    mask = lc.skin_faces(model)
    cent = tmpl[faces].mean(1)
    tri = tmpl[faces]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    frontal = nrm[:, 2] > 0.5 * np.linalg.norm(nrm, axis=1)  # visible from the front (+Z)
    rng = np.random.default_rng(5)
    chosen = (19, 30, 36, 45, 48, 57)
    for lmk in chosen:  # a visible skin triangle 4-10 mm from the landmark vertex
        d = np.linalg.norm(cent - tmpl[li[lmk]], axis=1)
        f = int(rng.choice(np.flatnonzero(mask & frontal & (d > 0.004) & (d < 0.010))))
        b = rng.dirichlet([3, 3, 3])
        truth.face_ids[lmk], truth.vertex_ids[lmk], truth.bary[lmk] = f, faces[f], b
    data = _fake_subjects(model, truth.points_np)
    emb, report = lc.calibrate(data, model, landmarks=chosen, radius=0.02, grid=4,
                               refine_grid=12, refine_top=6, progress=False)
    emb.validate(model.num_vertices, faces)
    got, want = emb.points_np(tmpl), truth.points_np(tmpl)
    err_mm = 1000 * np.linalg.norm(got - want, axis=1)[list(chosen)]
    moved_mm = 1000 * np.linalg.norm(want - tmpl[li], axis=1)[list(chosen)]
    assert err_mm.max() < 1.5, (err_mm, moved_mm)      # recovered within 1.5 mm
    assert np.all(moved_mm > 3.0)                       # of offsets of 3-10 mm
    assert emb.calibrated[list(chosen)].all() and emb.calibrated.sum() == len(chosen)
    for lmk in chosen:
        r = report["landmarks"][lmk]
        assert r["mean_dist_after"] < r["mean_dist_before"]
    ev = lc.evaluate(data, emb, li)
    assert np.median(ev["embedding"]) < np.median(ev["vertices"])


def test_04_shipped_file_loads_and_validates(model):
    assert le.DEFAULT_FILE.is_file(), "hack_render/data/landmark_embedding_dlib.npz is missing"
    emb = le.LandmarkEmbedding.load(le.DEFAULT_FILE, model)   # validates against the model
    assert emb.face_ids.shape == (68,) and emb.bary.shape == (68, 3)
    assert np.all(np.isfinite(emb.bary)) and np.all(emb.bary >= 0)
    assert np.allclose(emb.bary.sum(1), 1.0)
    assert 0 <= emb.face_ids.min() and emb.face_ids.max() < len(model.faces)
    np.testing.assert_array_equal(model.faces.numpy()[emb.face_ids], emb.vertex_ids)
    contours = [i for i in range(17) if i != 8]
    assert not emb.calibrated[contours].any()   # the jawline stays contour-matched
    assert emb.calibrated[17:].sum() >= 30
    assert emb.meta["provenance"].startswith("derived: calibrated on")
    assert "calibrate-landmarks" in emb.meta["command"]
    # points stay near the model's landmark vertices (within the search radius)
    d = np.linalg.norm(emb.points_np(model.template.numpy()) -
                       model.template.numpy()[model.landmark_indices.numpy()], axis=1)
    assert d.max() < emb.meta["radius_m"] + 0.005


def test_05_validation_refuses_broken_files(tmp_path, model):
    from hack_render.errors import HackError

    emb = le.LandmarkEmbedding.from_vertices(model.landmark_indices.numpy(), model.faces.numpy())
    bad = le.LandmarkEmbedding(emb.face_ids, emb.vertex_ids, emb.bary * 0.5, emb.calibrated)
    with pytest.raises(HackError, match="sum"):
        bad.validate()
    other = le.LandmarkEmbedding(emb.face_ids + 1, emb.vertex_ids, emb.bary, emb.calibrated)
    with pytest.raises(HackError, match="faces"):
        other.validate(model.num_vertices, model.faces.numpy())
    p = emb.save(tmp_path / "e.npz")
    assert np.array_equal(le.LandmarkEmbedding.load(p, model).vertex_ids, emb.vertex_ids)
    with pytest.warns(le.EmbeddingWarning, match="not found"):
        assert le.load_default(model, tmp_path / "missing.npz") is None


def test_06_fitter_uses_the_embedding_for_dlib_and_falls_back(tmp_path, model):
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import Photo
    from hack_render.vision.detection import Detection

    photo = Photo(np.full((64, 64, 3), 0.5, np.float32), "grey")
    pts = np.random.default_rng(0).uniform(10, 50, (68, 2))
    dets = {s: Detection(pts, (10, 10, 50, 50), 1, s) for s in ("dlib", "file", "truth")}

    def landmarks(source, **lm):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # silhouette off: nothing to segment on the grey photo (~10 s a fitter)
            f = Fitter([photo], [dets[source]],
                       load_config(None, {"landmarks": lm, "silhouette": {"mode": "off"}}),
                       model=model, appearance=None, progress=False)
        v = f.state.views[0]
        with torch.no_grad():
            verts = f.forward(v).vertices[0]
            return v.embedded, f.model_landmarks(v, verts, 1), verts

    emb = le.LandmarkEmbedding.load(le.DEFAULT_FILE, model)
    used, lm, verts = landmarks("dlib")
    assert used and torch.allclose(lm[17:], emb.points(verts)[17:])
    contours = [i for i in range(17) if i != 8]    # jaw: contour-matched vertices
    assert torch.equal(lm[contours], verts[model.landmark_indices[contours]])
    assert torch.allclose(lm[8], emb.points(verts)[8])  # the chin: no contour strip
    li = model.landmark_indices
    assert landmarks("file")[0] and not landmarks("file", files_follow="vertices")[0]
    assert not landmarks("truth")[0]
    used, lm, verts = landmarks("dlib", embedding="vertices")
    assert not used and torch.equal(lm[17:], verts[li[17:]])
    with pytest.warns(le.EmbeddingWarning):
        assert le.load_default(model, tmp_path / "none.npz") is None
    # a missing shipped file: the fitter falls back to the vertices (with a warning)
    import hack_render.fit.landmark_embedding as mod

    old = mod.DEFAULT_FILE
    try:
        mod.DEFAULT_FILE = tmp_path / "gone.npz"
        used, lm, verts = landmarks("dlib")
        assert not used and torch.equal(lm[17:], verts[li[17:]])
    finally:
        mod.DEFAULT_FILE = old


def test_07_detector_weights_are_inverse_variances(tmp_path, model, monkeypatch):
    """A point the fake detector scatters 3x more gets ~1/9 the weight of the others
    (clipped at 0.25 of the mean); the weights survive save/load, are validated, and the
    fitter applies them to embedded (dlib) views only."""
    from hack_render.errors import HackError
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import Photo
    from hack_render.vision.detection import Detection

    li = model.landmark_indices.numpy()
    emb = le.LandmarkEmbedding.from_vertices(li, model.faces.numpy())
    emb.calibrated[[8] + list(range(17, 68))] = True
    data = _fake_subjects(model, emb.points_np, n=24, noise=0.01, seed=4)
    rng = np.random.default_rng(9)
    for s in range(len(data.indices)):  # points 30 and 31 scatter 3x and 1.5x more
        iod = np.linalg.norm(data.points[s, 36] - data.points[s, 45])
        data.points[s, 30] += rng.normal(0, 0.02 * iod, 2)
        data.points[s, 31] += rng.normal(0, 0.0112 * iod, 2)
    w = lc.detector_weights(data, emb, li)
    cal = [8] + list(range(17, 68))
    assert np.allclose(w[[i for i in range(17) if i != 8]], 1.0)  # contours untouched
    assert w[cal].mean() == pytest.approx(1.0)
    others = np.median(np.delete(w, [30, 31] + list(range(17)))[: len(cal) - 3])
    assert w[30] < 0.35 * others and 0.2 < w[31] / others < 0.75
    emb.weights = w
    p = emb.save(tmp_path / "w.npz")
    np.testing.assert_allclose(le.LandmarkEmbedding.load(p, model).weights, w)
    with pytest.raises(HackError, match="weights"):
        le.LandmarkEmbedding(emb.face_ids, emb.vertex_ids, emb.bary, emb.calibrated,
                             weights=-w).validate()
    shipped = le.LandmarkEmbedding.load(le.DEFAULT_FILE, model)
    assert shipped.weights is not None and shipped.weights[cal].mean() == pytest.approx(1.0)
    assert shipped.weights[17:27].mean() < shipped.weights[36:48].mean()  # dlib: brows < eyes
    photo = Photo(np.full((64, 64, 3), 0.5, np.float32), "grey")
    pts = np.random.default_rng(0).uniform(10, 50, (68, 2))

    def weights(source, **lm):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = Fitter([photo], [Detection(pts, (10, 10, 50, 50), 1, source)],
                       load_config(None, {"landmarks": lm, "silhouette": {"mode": "off"}}),
                       model=model, appearance=None, progress=False)
        return f.view_landmark_weights(f.state.views[0]), f.state.lmk_w

    got, base = weights("dlib")
    torch.testing.assert_close(got, base * torch.as_tensor(shipped.weights, dtype=base.dtype))
    assert torch.equal(weights("truth")[0], weights("truth")[1])
    from hack_render.fit import terms

    monkeypatch.setattr(terms, "CALIBRATED_WEIGHTS", False)
    assert torch.equal(*weights("dlib"))
