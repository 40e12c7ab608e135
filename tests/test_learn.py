"""Learners of issue 6: larynx, deformation transfer, personalised spaces, pose trainer,
joint regressor, model report. Fast unless marked slow."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from synthetic import synthetic_arrays

from hack_render.errors import HackError

PARENTS = (-1, 0, 1, 2, 3, 4, 5, 6)


def grid(nx=15, ny=15, size=0.06):
    """A flat square grid in the z = 0 plane (metres), triangulated."""
    xs, ys = np.meshgrid(np.linspace(-size / 2, size / 2, nx), np.linspace(-size / 2, size / 2, ny))
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(nx * ny)], 1)
    f = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            f += [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]]
    return v, np.array(f)


# ------------------------------------------------------------------ 1 deformation transfer
def test_01_deformation_transfer_onto_itself_is_exact():
    from hack_render.motion.deformation_transfer import TargetSolver, source_gradients

    v, f = grid()
    rng = np.random.default_rng(0)
    free = np.linalg.norm(v[:, :2], axis=1) < 0.02
    deformed = v.copy()
    deformed[free] += 0.003 * rng.standard_normal((free.sum(), 3))
    g = source_gradients(v, deformed, f)
    out = TargetSolver(v, f, free).transfer(g[None])[0]
    np.testing.assert_allclose(out, deformed, atol=1e-12)


def test_02_deformation_transfer_follows_the_target_scale():
    """A bump transferred onto a target scaled by 2 comes out with twice the height."""
    from hack_render.motion.deformation_transfer import TargetSolver, source_gradients

    v, f = grid(21, 21)
    r = np.linalg.norm(v[:, :2], axis=1)
    free = r < 0.025
    bumped = v.copy()
    bumped[:, 2] = 0.004 * np.exp(-(r / 0.008) ** 2) * free
    g = source_gradients(v, bumped, f)
    out = TargetSolver(2 * v, f, free).transfer(g[None])[0]
    assert abs(out[:, 2].max() - 2 * bumped[:, 2].max()) < 0.05 * 2 * bumped[:, 2].max()


# ---------------------------------------------------------------------------- 2 larynx
def test_03_larynx_removal_recovers_a_bump_and_is_zero_outside():
    from hack_render.learn.larynx_learn import Remover
    from hack_render.learn.mesh_ops import vertex_normals

    v, f = grid(25, 25)
    r = np.linalg.norm(v[:, :2], axis=1)
    patch = r < 0.022
    bump = 0.005 * np.exp(-(r / 0.006) ** 2)
    x = v.copy()
    x[:, 2] += bump
    gamma = Remover(x, f, patch).gamma(x, vertex_normals(v, f))
    assert np.abs(gamma[~patch]).max() == 0
    assert np.abs(gamma[:, 2] - bump).max() < 0.1 * bump.max()
    # A smooth (quadratic) surface has nothing to remove.
    y = v.copy()
    y[:, 2] = 2.0 * v[:, 0] ** 2
    assert np.abs(Remover(y, f, patch).gamma(y, vertex_normals(y, f))).max() < 2e-4


def test_04_uv_raster_interpolates_linear_functions_exactly():
    from hack_render.learn.larynx_learn import uv_raster_matrix

    v, f = grid(9, 9, size=1.0)
    uv = v[:, :2] + 0.5
    m = uv_raster_matrix(uv, f, np.array([0.0, 0.0, 1.0, 1.0]), 32)
    vals = 3 * uv[:, 0] - 2 * uv[:, 1]
    img = (m @ vals).reshape(32, 32)
    jj, ii = np.meshgrid(np.arange(32), np.arange(32))
    want = 3 * (jj + 0.5) / 32 - 2 * (1 - (ii + 0.5) / 32)
    inside = np.asarray(m.sum(1)).ravel().reshape(32, 32) > 0.5
    assert inside.mean() > 0.9
    np.testing.assert_allclose(img[inside], want[inside], atol=1e-9)


# --------------------------------------------------------------- 3 PCA and mapping MLP
def test_05_pca_reconstructs_training_data_and_is_compact():
    from hack_render.learn.pca import compactness, fit_pca

    rng = np.random.default_rng(1)
    x = rng.standard_normal((30, 5)) @ rng.standard_normal((5, 200)) + 1.0
    pca = fit_pca(x)
    assert len(pca.components) == 5
    np.testing.assert_allclose(pca.reconstruct(pca.project(x)), x, atol=1e-4)
    c = compactness(pca)
    assert np.all(np.diff(c) >= -1e-12) and abs(c[-1] - 1) < 1e-9
    with pytest.raises(HackError):
        fit_pca(x[:1])


def test_06_mapping_mlp_beats_the_mean_on_held_out_identities():
    from hack_render.learn.personal import mlp_forward, train_mapping

    rng = np.random.default_rng(2)
    b = rng.standard_normal((220, 6))
    w = np.tanh(b @ rng.standard_normal((6, 4)))
    mlp, _train, val = train_mapping(b[:200], w[:200], b[200:], w[200:], lr=1e-3, epochs=150,
                                     progress=False)
    baseline = ((w[200:] - w[:200].mean(0)) ** 2).sum(1).mean()
    assert val < 0.3 * baseline
    np.testing.assert_allclose(((mlp_forward(mlp, b[200:]) - w[200:]) ** 2).sum(1).mean(), val, rtol=1e-3)


# -------------------------------------------------------------------------- 4 pose
def _pose_setup(seed=1):
    from hack_render.learn.pose_learn import weight_support

    a = synthetic_arrays(0, nx=8, ny=14)
    v = a["template_vertices"].astype(float)
    j = a["joint_regressor"].astype(float) @ v
    rng = np.random.default_rng(seed)
    w0 = a["skinning_weights"].astype(float)
    ws = w0 * np.exp(0.3 * rng.standard_normal(w0.shape)) * weight_support(w0, PARENTS)
    ws /= ws.sum(1, keepdims=True)
    p = np.stack([0.01 * np.outer(np.sin(3 * v[:, 1] + k), rng.standard_normal(3)) for k in range(72)])
    return a, v, j, w0, ws, p, rng


def _random_sequences(trainer, p, w, rng, n=4, frames=30):
    from hack_render.geometry.rotations import euler_to_axis_angle
    from hack_render.geometry.skeleton import rotation_limits
    from hack_render.learn.pose_learn import Sequence

    lim = rotation_limits(torch.float64)
    out = []
    for _ in range(n):
        e = lim[..., 0] + (lim[..., 1] - lim[..., 0]) * torch.as_tensor(rng.random((frames, 8, 3)))
        th = euler_to_axis_angle(e)
        with torch.no_grad():
            tg, _ = trainer.predict(0, th, torch.as_tensor(p), torch.as_tensor(w))
        out.append(Sequence(0, tg.numpy(), th.numpy()))
    return out


@pytest.mark.slow
def test_07_pose_recovery_known_weights_recovers_the_corrective_on_held_out_poses():
    """Sequences from a known W*, P*: with W = W* known, the fitted P reproduces P*'s
    correctives on held-out poses within 10 % (P itself is identifiable only along the pose
    features the data excites)."""
    from hack_render.learn.pose_learn import PoseTrainer

    a, v, j, _w0, ws, p, rng = _pose_setup()
    tr = PoseTrainer(v[None], j[None], a["faces"], ws, PARENTS, weights={"ski": 0.0, "smo": 0.0})
    fit = tr.fit(_random_sequences(tr, p, ws, rng), iterations=500, lr=0.03, learn_weights=False,
                 progress=False)
    held = _random_sequences(tr, p, ws, rng, n=2)
    num = den = 0.0
    with torch.no_grad():
        for s in held:
            th = torch.as_tensor(s.theta)
            got = tr.predict(0, th, torch.as_tensor(fit.pose_blendshapes[0]), torch.as_tensor(ws))[0].numpy()
            nop = tr.predict(0, th, torch.zeros(72, len(v), 3, dtype=torch.float64), torch.as_tensor(ws))[0].numpy()
            num += ((got - s.targets) ** 2).sum()
            den += ((nop - s.targets) ** 2).sum()
    assert np.sqrt(num / den) < 0.10


@pytest.mark.slow
def test_08_pose_recovery_known_pose_blendshapes_moves_weights_towards_the_truth():
    from hack_render.learn.pose_learn import PoseTrainer

    a, v, j, w0, ws, p, rng = _pose_setup()
    tr = PoseTrainer(v[None], j[None], a["faces"], w0, PARENTS, weights={"ski": 0.0, "smo": 0.0})
    zero = np.zeros_like(p)
    fit = tr.fit(_random_sequences(tr, zero, ws, rng), iterations=800, lr=0.03, learn_pose=False,
                 progress=False)
    assert np.abs(fit.weights - ws).mean() < 0.5 * np.abs(w0 - ws).mean()
    np.testing.assert_allclose(fit.weights.sum(1), 1, atol=1e-9)
    assert (fit.weights >= 0).all()


def test_09_temporal_penalty_tolerates_slow_motion_and_punishes_jumps():
    from hack_render.learn.pose_learn import TEMPORAL, temporal_penalty

    ramp = torch.linspace(0, 1, 20)[:, None] * 0.1 * 19 / 20  # slope 0.1 < eps 0.15
    assert float(temporal_penalty(ramp, *TEMPORAL["theta"])) < 1e-9
    jump = ramp.clone()
    jump[10:] += 0.5
    assert float(temporal_penalty(jump, *TEMPORAL["theta"])) > 100


def test_10_dqs_keeps_neck_area_under_twist_where_lbs_loses_it():
    from hack_render.learn.pose_data import twist_area_ratio

    a = synthetic_arrays(0, nx=16, ny=12)
    v = torch.as_tensor(a["template_vertices"], dtype=torch.float64)
    j = torch.as_tensor(a["joint_regressor"], dtype=torch.float64) @ v
    # Smooth weights along the neck: each vertex between its two nearest joints.
    y = v[:, 1].numpy()
    jy = j[:, 1].numpy()
    w = np.zeros((len(y), 9))
    for n, yy in enumerate(y):
        k = int(np.clip(np.searchsorted(jy, yy) - 1, 0, 6))
        t = float(np.clip((yy - jy[k]) / (jy[k + 1] - jy[k]), 0, 1))
        w[n, k + 1], w[n, k + 2] = 1 - t, t
    ring = np.flatnonzero(np.abs(y - y[np.argmin(np.abs(y - jy[6]))]) < 1e-6)
    r = twist_area_ratio(v, j, torch.as_tensor(w), PARENTS, ring, degrees=75.0)
    assert abs(r["dqs"] - 1) < 0.02
    assert r["lbs"] < r["dqs"] - 0.02


def _cylinder_twist(degrees=40.0):
    """A synthetic neck tube with a sharp skinning band at one joint and a twist there."""
    from hack_render.learn.pose_data import pose_sequence

    a = synthetic_arrays(0, nx=16, ny=14)
    v = torch.as_tensor(a["template_vertices"], dtype=torch.float64)
    j = torch.as_tensor(a["joint_regressor"], dtype=torch.float64) @ v
    y = v[:, 1].numpy()
    t = np.clip((y - j[5, 1].item()) / 0.012 + 0.5, 0, 1)  # a 12 mm blend band at joint 5
    w = np.zeros((len(y), 9))
    w[:, 0], w[:, 8] = 1 - t, t
    w = torch.as_tensor(w)
    theta = torch.zeros(2, 8, 3, dtype=torch.float64)
    theta[1, 5, 1] = np.deg2rad(degrees)
    fixed = (y < y.min() + 0.02) | (y > y.max() - 0.02)
    return a, v, j, w, theta, fixed, pose_sequence


def _max_stretch(p, v, faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    l0 = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    return np.abs(np.linalg.norm(p[:, e[:, 0]] - p[:, e[:, 1]], axis=-1) / l0 - 1).max(1)


def test_10b_arap_spreads_a_twist_keeps_fixed_vertices_and_rest():
    from hack_render.learn.pose_data import ArapNeck

    a, v, j, w, theta, fixed, pose_sequence = _cylinder_twist()
    # Only the band is skinned to both nodes; fix the tube's ends to the skeleton.
    arap = ArapNeck(v.numpy(), a["faces"], fixed)
    lbs = pose_sequence(v, j, w, PARENTS, theta, "lbs").numpy()
    dqs = pose_sequence(v, j, w, PARENTS, theta, "dqs").numpy()
    out = pose_sequence(v, j, w, PARENTS, theta, "arap", arap).numpy()
    np.testing.assert_allclose(out[0], v.numpy(), atol=1e-12)  # rest pose: rest mesh
    np.testing.assert_array_equal(out[1][fixed], dqs[1][fixed])  # fixed where DQS put them
    s_lbs, s_arap = _max_stretch(lbs, v.numpy(), a["faces"])[1], _max_stretch(out, v.numpy(), a["faces"])[1]
    assert s_arap < 0.5 * s_lbs, (s_lbs, s_arap)
    with pytest.raises(HackError):
        ArapNeck(v.numpy(), a["faces"], np.ones(len(v), bool))
    with pytest.raises(HackError):
        pose_sequence(v, j, w, PARENTS, theta, "arap")


def test_10c_closed_form_pose_blendshapes_reproduce_known_correctives():
    """Sequences from known P* with W known: the unposed least-squares start alone
    reproduces P*'s correctives on held-out poses (its error comes only from LBS's
    non-rigid blended rotations)."""
    from hack_render.learn.pose_learn import PoseTrainer

    a, v, j, _w0, ws, p, rng = _pose_setup()
    tr = PoseTrainer(v[None], j[None], a["faces"], ws, PARENTS)
    fit = tr.unposed_least_squares(_random_sequences(tr, p, ws, rng, n=6))
    held = _random_sequences(tr, p, ws, rng, n=2)
    num = den = 0.0
    with torch.no_grad():
        for s in held:
            th = torch.as_tensor(s.theta)
            got = tr.predict(0, th, torch.as_tensor(fit[0]), torch.as_tensor(ws))[0].numpy()
            nop = tr.predict(0, th, torch.zeros(72, len(v), 3, dtype=torch.float64), torch.as_tensor(ws))[0].numpy()
            num += ((got - s.targets) ** 2).sum()
            den += ((nop - s.targets) ** 2).sum()
    assert np.sqrt(num / den) < 0.01  # measured 1.5e-4


# -------------------------------------------------------------------- 5 joint regressor
def test_11_joint_regressor_recovers_joints_of_held_out_meshes():
    from hack_render.learn.joint_regressor import joint_errors, train_joint_regressor

    a = synthetic_arrays(0, nx=10, ny=16)
    v = a["template_vertices"].astype(float)
    rng = np.random.default_rng(3)
    meshes = v[None] * (1 + 0.1 * rng.standard_normal((40, 1, 3))) + 0.01 * rng.standard_normal((40, 1, 3))
    truth = np.zeros((8, len(v)))
    for k, yk in enumerate(np.linspace(-0.13, -0.01, 8)):
        ring = np.argsort(np.abs(v[:, 1] - yk))[:10]
        truth[k, ring] = rng.random(10) + 0.1
    truth /= truth.sum(1, keepdims=True)
    joints = np.einsum("kn,pnc->pkc", truth, meshes)
    reg = train_joint_regressor(meshes[:30], joints[:30], slab=0.012)
    np.testing.assert_allclose(reg.sum(1), 1, atol=1e-9)
    assert (reg >= 0).all()
    assert joint_errors(reg, meshes[30:], joints[30:]).max() < 5e-4
    with pytest.raises(HackError):
        train_joint_regressor(meshes[:3], joints[:2])


# ------------------------------------------------------------------ 6 model file format
def test_12_format_1_files_still_load_and_larynx_chart_is_used(tmp_path):
    from hack_render.geometry.model import HackModel
    from hack_render.geometry.model_file import load_model_file, save_model_file

    arrays = synthetic_arrays(0)
    save_model_file(tmp_path / "v.npz", arrays, {})
    with np.load(tmp_path / "v.npz") as z:
        raw = dict(z)
    raw["format_version"] = np.asarray(1)
    np.savez(tmp_path / "v1.npz", **raw)
    loaded, _ = load_model_file(tmp_path / "v1.npz")
    assert "larynx_vertex_uv" not in loaded
    chart = dict(arrays, larynx_vertex_uv=arrays["vertex_uv"][arrays["larynx_vertices"]] * 0.5)
    kw = {"beta": torch.ones(1, 5), "eta": torch.ones(1)}
    with torch.no_grad():
        a0 = HackModel(loaded)(**kw).rest_vertices
        a1 = HackModel(chart)(**kw).rest_vertices
    assert (a0 - a1).abs().max() > 1e-5
    bad = dict(arrays)
    for k in [k for k in bad if k.startswith("larynx_")]:
        bad.pop(k)
    bad["larynx_vertex_uv"] = chart["larynx_vertex_uv"]
    with pytest.raises(HackError, match="larynx"):
        save_model_file(tmp_path / "bad.npz", bad, {})


# ---------------------------------------------------------------- 7 the shipped model
@pytest.fixture(scope="module")
def shipped():
    from hack_render.geometry import load_default_model

    m = load_default_model()
    if not m.has_larynx:
        pytest.fail("the shipped model has no larynx; rebuild it with `hack-render model build-v2`")
    return m


def _larynx_peak(m, eta, tau):
    with torch.no_grad():
        base = m(eta=torch.zeros(1)).rest_vertices[0].numpy()
        d = m(eta=torch.tensor([eta]), tau=torch.tensor([tau])).rest_vertices[0].numpy() - base
    mag = np.linalg.norm(d, axis=1)
    w = np.clip(mag - 0.5 * mag.max(), 0, None)
    return (w[:, None] * base).sum(0) / w.sum(), mag.max()


def test_13_shipped_larynx_slides_vertically_by_tau(shipped):
    c0, _ = _larynx_peak(shipped, 1.0, 0.0)
    for tau in (0.01, -0.01):
        c, _ = _larynx_peak(shipped, 1.0, tau)
        assert abs((c[1] - c0[1]) - tau) < 0.002, (tau, c - c0)
        assert abs(c[0] - c0[0]) < 0.001


def test_14_shipped_larynx_eta_scales_protrusion_and_zero_gives_template(shipped):
    _, h1 = _larynx_peak(shipped, 1.0, 0.0)
    _, h2 = _larynx_peak(shipped, 2.0, 0.0)
    assert 0.001 < h1 < 0.012
    assert abs(h2 - 2 * h1) < 1e-6
    with torch.no_grad():  # eta = 0: no larynx (the default, 1, is the identity's own)
        out = shipped(eta=torch.zeros(1)).vertices[0]
    torch.testing.assert_close(out, shipped.template, atol=1e-7, rtol=0)


def test_15_shipped_model_has_provenance_and_report(shipped, tmp_path):
    from hack_render.learn.report import write_report

    prov = shipped.meta["provenance"]
    for key, label in (("larynx", "simulated"), ("personalised_expressions", "derived"),
                       ("pose_blendshapes", "optimised")):
        assert label in prov[key]
    assert shipped.expr_personal is not None and shipped.pose_personal is not None
    js, png = write_report(shipped.meta, tmp_path)
    import json

    summary = json.loads(js.read_text())["summary"]
    assert set(summary) == {"shape", "larynx", "expression", "pose"}
    assert png.stat().st_size > 10_000
    abl = shipped.meta["learn"]["expressions"]["ablation_mm"]
    assert abl["personalised_subset"] < abl["generic_subset"]


def test_16_larynx_displacement_is_the_forward_passes_larynx_term(shipped):
    """``larynx_displacement(beta, eta, tau)`` is exactly what the forward adds at the larynx
    vertices (defaults: beta 0, eta 1, tau 0), and a model without a larynx says so."""
    import copy

    from hack_render.errors import HackError

    g = torch.Generator().manual_seed(7)
    beta = torch.randn(2, 12, generator=g)
    eta, tau = torch.tensor([0.7, 1.6]), torch.tensor([0.004, -0.009])
    idx = shipped.larynx_vertices
    with torch.no_grad():
        with_l = shipped(beta=beta, eta=eta, tau=tau).rest_vertices[:, idx]
        without = shipped(beta=beta, eta=torch.zeros(2), tau=tau).rest_vertices[:, idx]
        d = shipped.larynx_displacement(beta, eta, tau)
        d0 = shipped.larynx_displacement()
        ref0 = shipped(eta=torch.ones(1)).rest_vertices[:, idx] - shipped.template[idx]
    torch.testing.assert_close(d, with_l - without, atol=1e-6, rtol=0)
    torch.testing.assert_close(d0, ref0, atol=1e-6, rtol=0)
    assert d.abs().max() > 1e-3  # a real larynx, not zeros
    flat = copy.copy(shipped)
    flat.has_larynx = False
    with pytest.raises(HackError, match="no larynx"):
        flat.larynx_displacement()
