"""Geometry model G: exactness, gradients, LBS, personalisation, file IO, anatomy."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.geometry import HackModel, load_default_model
from hack_render.geometry import rotations as R
from hack_render.geometry.lbs import rigid_transforms, skin, skin_reference
from hack_render.geometry.model_file import load_model_file
from hack_render.geometry.products import personal_product, rows_product
from hack_render.geometry.reference import reference_forward
from hack_render.geometry.skeleton import (
    adjacent_similarity_penalty,
    clamp_to_limits,
    distribute_head_rotation,
    rotation_limit_penalty,
    rotation_limits,
)
from tests.synthetic import synthetic_arrays


@pytest.fixture(scope="module")
def synth64():
    return HackModel(synthetic_arrays()).double()


@pytest.fixture(scope="module")
def synth_rigid():
    """The synthetic model with the default model's structure: most vertices rigid with
    o-c1 and the generic pose rows on the personalised pose vertices (folded together)."""
    a = synthetic_arrays(seed=3)
    n = len(a["template_vertices"])
    w = a["skinning_weights"]
    rigid = np.arange(n) % 3 != 0
    w[rigid] = 0.0
    w[rigid, 8] = 1.0
    cols = a["pose_pca_vertices"]
    mask = np.zeros(n, bool)
    mask[cols] = True
    a["pose_basis"][:, ~mask] = 0.0
    m = HackModel(a).double()
    assert m.pose_folded and len(m.blended_vertices) < n
    return m


@pytest.fixture(scope="module")
def default():
    return load_default_model()


def _random_params(model, b, gen, scale=0.3):
    dt = model.template.dtype
    return {"beta": torch.randn(b, model.num_shape, generator=gen, dtype=dt),
            "psi": torch.rand(b, model.num_expressions, generator=gen, dtype=dt),
            "theta": scale * torch.randn(b, 8, 3, generator=gen, dtype=dt),
            "global_orient": 0.2 * torch.randn(b, 3, generator=gen, dtype=dt),
            "transl": 0.1 * torch.randn(b, 3, generator=gen, dtype=dt),
            "eta": torch.rand(b, generator=gen, dtype=dt) + 0.5,
            "tau": 0.01 * torch.randn(b, generator=gen, dtype=dt)}


def test_zero_parameters_give_template(default, synth64):
    """All zeros (eta = 0: no larynx) give the template; the defaults (eta = 1, the
    identity's own larynx, as on the CLI) add exactly L(0, 1, 0) at the larynx vertices."""
    out = default(eta=torch.zeros(1))
    assert out.vertices.shape == (1, default.num_vertices, 3)
    torch.testing.assert_close(out.vertices[0], default.template, atol=1e-7, rtol=0)
    assert torch.equal(out.rest_vertices[0], default.template)
    # float64: exact up to round-off of the kinematic chain
    out64 = synth64(eta=torch.zeros(1, dtype=torch.float64))
    assert (out64.vertices[0] - synth64.template).abs().max() < 1e-15
    with torch.no_grad():
        rest = default().rest_vertices[0]
    expect = default.template.index_add(0, default.larynx_vertices, default.larynx_displacement()[0])
    torch.testing.assert_close(rest, expect, atol=1e-7, rtol=0)
    assert (rest - default.template).norm(dim=1).max() > 0.003  # a real larynx, mm-sized


def test_eta_has_one_default_everywhere(default):
    """Python API, parameter files / CLI and larynx_displacement all default eta to 1."""
    from hack_render.geometry.larynx import ETA_DEFAULT
    from hack_render.geometry.params import model_inputs

    assert ETA_DEFAULT == 1.0
    kw = model_inputs(default, {})
    assert float(kw["eta"][0]) == ETA_DEFAULT
    with torch.no_grad():
        api = default().vertices
        cli = default(**kw).vertices
        one = default(eta=torch.ones(1)).vertices
    assert torch.equal(api, cli) and torch.equal(api, one)
    assert "missing: 1" in HackModel.forward.__doc__


def test_rotations_exact_near_zero_and_round_trips():
    r = torch.tensor([1e-9, -2e-9, 3e-9], dtype=torch.float64, requires_grad=True)
    m = R.axis_angle_to_matrix(r)
    assert torch.isfinite(m).all()
    assert torch.autograd.gradcheck(R.axis_angle_to_matrix, (r,))
    assert torch.autograd.gradcheck(R.axis_angle_to_matrix, (torch.zeros(3, dtype=torch.float64, requires_grad=True),))
    g = torch.Generator().manual_seed(1)
    rr = torch.randn(200, 3, generator=g, dtype=torch.float64)
    torch.testing.assert_close(R.matrix_to_axis_angle(R.axis_angle_to_matrix(rr)),
                               rr * torch.where(rr.norm(dim=-1, keepdim=True) > np.pi, np.nan, 1.0).nan_to_num(1.0),
                               atol=1e-10, rtol=0) if (rr.norm(dim=-1) < np.pi).all() else None
    e = (torch.rand(200, 3, generator=g, dtype=torch.float64) - 0.5) * 1.2
    torch.testing.assert_close(R.axis_angle_to_euler(R.euler_to_axis_angle(e)), e, atol=1e-12, rtol=0)
    # convention: Rx(flexion) @ Rz(lateral) @ Ry(axial)
    a, c, b = 0.3, -0.2, 0.1
    rx = R.axis_angle_to_matrix(torch.tensor([a, 0, 0], dtype=torch.float64))
    ry = R.axis_angle_to_matrix(torch.tensor([0, c, 0], dtype=torch.float64))
    rz = R.axis_angle_to_matrix(torch.tensor([0, 0, b], dtype=torch.float64))
    torch.testing.assert_close(R.axis_angle_to_matrix(R.euler_to_axis_angle(torch.tensor([a, c, b], dtype=torch.float64))),
                               rx @ rz @ ry, atol=1e-14, rtol=0)


@pytest.mark.parametrize("name", ["beta", "psi", "theta", "global_orient", "transl", "eta", "tau"])
def test_gradcheck_every_parameter(synth64, name):
    gen = torch.Generator().manual_seed(2)
    params = _random_params(synth64, 2, gen)
    x = params.pop(name).clone().requires_grad_(True)

    def f(val):
        out = synth64(**params, **{name: val})
        return out.vertices, out.joints

    assert torch.autograd.gradcheck(f, (x,), eps=1e-6, atol=1e-6)


def test_sparse_products_exact_with_gradients():
    """rows_product and personal_product read only the rows with a nonzero coefficient
    forward and every row backward: values equal the dense expressions, and gradients
    (zero coefficients included) equal finite differences, for distinct identities (w of
    B rows), one shared identity (w of one row) and all-nonzero coefficients."""
    gen = torch.Generator().manual_seed(5)
    dd = {"dtype": torch.float64, "generator": gen}
    B, C, D, K = 3, 4, 7, 10
    mean, comps = torch.randn(D, K, **dd), torch.randn(C, D, K, **dd)
    rows, bias = torch.randn(D, K, **dd), torch.randn(K, **dd)
    coeffs = torch.randn(B, D, **dd)
    for zero in ([], [1, 2, 5], [0, 1, 2, 3, 4, 5, 6]):
        c = coeffs.clone()
        c[:, zero] = 0.0
        torch.testing.assert_close(rows_product(c, rows, bias), bias + c @ rows, atol=1e-14, rtol=0)
        assert torch.autograd.gradcheck(lambda x, b: rows_product(x, rows, b),
                                        (c.clone().requires_grad_(True),
                                         bias[None].clone().requires_grad_(True)))
        for nw in (B, 1):
            w = torch.randn(nw, C, **dd)
            dense = torch.stack([c[b] @ (mean + torch.einsum("c,cdk->dk", w[b % nw], comps))
                                 for b in range(B)])
            with torch.no_grad():
                torch.testing.assert_close(personal_product(c, mean, w, comps), dense,
                                           atol=1e-13, rtol=0)
            assert torch.autograd.gradcheck(lambda x, ww: personal_product(x, mean, ww, comps),
                                            (c.clone().requires_grad_(True),
                                             w.clone().requires_grad_(True)))


def _grads(model, fn, params):
    leaves = {k: v.clone().requires_grad_(True) for k, v in params.items() if torch.is_tensor(v)}
    out = fn(model, **{**params, **leaves})
    gen = torch.Generator().manual_seed(11)
    loss = sum((getattr(out, f) * torch.randn(getattr(out, f).shape, generator=gen,
                                              dtype=torch.float64)).sum()
               for f in ("vertices", "joints", "rest_vertices"))
    names = list(leaves)
    return out, dict(zip(names, torch.autograd.grad(loss, [leaves[k] for k in names])))


@pytest.mark.parametrize("case", ["distinct", "one_identity", "equal_rows", "sparse_psi", "batch1"])
def test_fast_forward_equals_reference(synth64, synth_rigid, default, case):
    """The optimised forward (batched personalised bases, exact zeros skipped, one
    identity's work shared, rigid vertices posed by one product) equals the plain
    reference_forward: every output, and (float64 models) the gradient of every input."""
    gen = torch.Generator().manual_seed(40)
    for model, tol in ((synth64, 1e-12), (synth_rigid, 1e-12), (default, 2e-6)):
        p = _random_params(model, 1 if case == "batch1" else 3, gen)
        if case == "one_identity":
            p["beta"] = p["beta"][:1]
        if case == "equal_rows":
            p["beta"] = p["beta"][:1].repeat(3, 1)
        if case == "sparse_psi":
            p["psi"][:, 1::2] = 0.0
            p["psi"][0, 0] = 0.0
        if model is default:
            with torch.no_grad():
                fast, ref = model(**p), reference_forward(model, **p)
        else:
            fast, g_fast = _grads(model, lambda m, **k: m(**k), p)
            ref, g_ref = _grads(model, reference_forward, p)
            for k in g_ref:
                torch.testing.assert_close(g_fast[k], g_ref[k], atol=1e-10, rtol=1e-10, msg=k)
        for field in ("vertices", "joints", "rest_joints", "landmarks", "rest_vertices"):
            torch.testing.assert_close(getattr(fast, field), getattr(ref, field).expand_as(
                getattr(fast, field)), atol=tol, rtol=0, msg=f"{case} {field}")


def test_shared_identity_gradients_reach_each_row(synth64):
    """Equal beta rows that need gradients are not collapsed into one identity: each row
    gets its own gradient (as with distinct rows), and an expanded row gets the sum."""
    gen = torch.Generator().manual_seed(12)
    p = _random_params(synth64, 2, gen)
    beta = p.pop("beta")[:1].repeat(2, 1).requires_grad_(True)
    synth64(beta=beta, **p).vertices[0].sum().backward()
    assert beta.grad[0].abs().sum() > 0 and beta.grad[1].abs().max() == 0
    one = beta.detach()[:1].clone().requires_grad_(True)
    synth64(beta=one, **p).vertices.sum().backward()
    b2 = beta.detach().clone().requires_grad_(True)
    synth64(beta=b2, **p).vertices.sum().backward()
    torch.testing.assert_close(one.grad[0], b2.grad.sum(0), atol=1e-12, rtol=0)


def test_lbs_matches_slow_reference():
    gen = torch.Generator().manual_seed(3)
    b, k, n = 2, 9, 30
    rot = R.axis_angle_to_matrix(0.5 * torch.randn(b, k, 3, generator=gen, dtype=torch.float64))
    joints = torch.randn(b, k, 3, generator=gen, dtype=torch.float64)
    parents = (-1, 0, 1, 2, 3, 4, 5, 6, 7)
    _, rel = rigid_transforms(rot, joints, parents)
    w = torch.rand(n, k, generator=gen, dtype=torch.float64)
    w = w / w.sum(1, keepdim=True)
    verts = torch.randn(b, n, 3, generator=gen, dtype=torch.float64)
    torch.testing.assert_close(skin(verts, w, rel), skin_reference(verts, w, rel), atol=1e-12, rtol=0)
    # a vertex fully weighted to a node moves rigidly about that node's posed position
    posed, rel = rigid_transforms(rot, joints, parents)
    one = torch.zeros(1, k, dtype=torch.float64)
    one[0, 4] = 1
    moved = skin(joints[:, 4:5], one, rel)
    torch.testing.assert_close(moved[:, 0], posed[:, 4], atol=1e-12, rtol=0)


def test_personalized_equals_general(synth64, default):
    gen = torch.Generator().manual_seed(4)
    for model, tol in ((synth64, 1e-12), (default, 2e-6)):
        p = _random_params(model, 3, gen)
        beta = p.pop("beta")[:1]
        general = model(beta=beta, **p)
        fast = model.personalize(beta)(**p)
        for field in ("vertices", "joints", "rest_joints", "landmarks"):
            torch.testing.assert_close(getattr(fast, field), getattr(general, field), atol=tol, rtol=0)


def test_personal_components_are_live(synth64):
    """Personalised bases and larynx change the output when beta changes (not generic only)."""
    psi = torch.ones(1, synth64.num_expressions, dtype=torch.float64)
    b1 = torch.zeros(1, 5, dtype=torch.float64)
    b2 = b1.clone()
    b2[0, 0] = 1.0
    # expression deltas at two identities differ by more than the shape difference alone
    d1 = synth64(beta=b1, psi=psi).rest_vertices - synth64(beta=b1).rest_vertices
    d2 = synth64(beta=b2, psi=psi).rest_vertices - synth64(beta=b2).rest_vertices
    assert (d1 - d2).abs().max() > 1e-5
    # larynx: eta scales, tau moves
    base = synth64(beta=b2, eta=torch.zeros(1, dtype=torch.float64)).rest_vertices
    l1 = synth64(beta=b2, eta=torch.ones(1, dtype=torch.float64)).rest_vertices - base
    l2 = synth64(beta=b2, eta=2 * torch.ones(1, dtype=torch.float64)).rest_vertices - base
    torch.testing.assert_close(l2, 2 * l1, atol=1e-14, rtol=0)
    lt = synth64(beta=b2, eta=torch.ones(1, dtype=torch.float64), tau=torch.full((1,), 0.02, dtype=torch.float64)).rest_vertices - base
    assert (lt - l1).abs().max() > 1e-5 and l1.abs().max() > 1e-5


def test_bad_inputs_name_the_argument(default):
    with pytest.raises(HackError, match="theta: expected shape"):
        default(theta=torch.zeros(1, 7, 3))
    with pytest.raises(HackError, match="beta: contains NaN"):
        default(beta=torch.tensor([[float("nan")]]))
    with pytest.raises(HackError, match="batch size"):
        default(beta=torch.zeros(2, 3), psi=torch.zeros(3, 53))
    with pytest.raises(HackError, match="unknown action unit"):
        default.expression_vector("AU99=1")
    with pytest.raises(TypeError):
        default(betas=torch.zeros(1, 3))  # misspelt keyword is an error, not ignored


def test_facs_control(default):
    au = default.expression_vector({"AU12": 0.7})
    names = default.expression_names
    assert au[names.index("mouthSmile_L")] == pytest.approx(0.7)
    assert au[names.index("mouthSmile_R")] == pytest.approx(0.7)
    assert au.abs().sum() == pytest.approx(1.4)
    psi = default.expression_vector("AU12=0.7, jawOpen=0.4")
    assert psi[names.index("jawOpen")] == pytest.approx(0.4)
    out = default(psi="jawOpen=1.0")
    moved = (out.vertices[0] - default.template).norm(dim=-1)
    assert moved[default.landmark_indices[57]] > 0.005  # the lower lip drops by > 5 mm


def test_joints_inside_neck_for_random_identities(default):
    """200 identities: joints ordered bottom to top, plausibly spaced, inside the neck."""

    gen = torch.Generator().manual_seed(6)
    beta = torch.randn(200, default.num_shape, generator=gen)
    with torch.no_grad():
        out = default(beta=beta)
    j = out.rest_joints.numpy()
    dy = np.diff(j[:, :, 1], axis=1)
    assert (dy > 0.005).all() and (dy < 0.04).all(), (dy.min(), dy.max())
    column = j[:, -1, 1] - j[:, 0, 1]
    assert ((column > 0.09) & (column < 0.17)).all(), (column.min(), column.max())
    assert np.abs(j[:, :, 0]).max() < 0.012  # near the midline (ICT identities are not symmetric)
    skin_mask = (default.vertex_group <= 1).numpy()
    for b in range(0, 200, 4):
        skin = out.rest_vertices[b].numpy()[skin_mask]
        for k in range(8):
            # the skin's cross-section through the joint: a 2 cm x 3 cm sagittal strip
            strip = skin[(np.abs(skin[:, 1] - j[b, k, 1]) < 0.01) & (np.abs(skin[:, 0] - j[b, k, 0]) < 0.015)]
            fz, bz = strip[:, 2].max(), strip[:, 2].min()
            frac = (fz - j[b, k, 2]) / (fz - bz)
            assert 0.25 < frac < 0.9, (b, k, frac)  # inside, about 2 cm or more from the skin


def _skin_edges(model):
    skin_faces = model.faces[(model.vertex_group[model.faces] <= 1).all(1)]
    edges = torch.cat([skin_faces[:, [0, 1]], skin_faces[:, [1, 2]], skin_faces[:, [2, 0]]])
    return skin_faces, edges


def _deformation(model, theta):
    faces, edges = _skin_edges(model)
    with torch.no_grad():  # against the rest pose of the same (default) parameters
        v0 = model().vertices[0]
        v = model(theta=theta[None]).vertices[0]

    def normals(x):
        return torch.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]], dim=1)

    flips = int(((normals(v) * normals(v0)).sum(1) < 0).sum())
    l0 = (v0[edges[:, 0]] - v0[edges[:, 1]]).norm(dim=1)
    stretch = float(((v[edges[:, 0]] - v[edges[:, 1]]).norm(dim=1) / l0 - 1).abs().max())
    return flips, stretch


# With plain LBS (no pose blendshapes) c1-c2's 40 degree axial twist alone stretches the
# side of the short ICT neck by 52 % and o-c1's extension by 37 %; the shipped correctives
# (optimised over the whole joint space, tests/test_pose_space.py) bring them to 37 % and
# 31 %, and every other limit to <= 19 %, each below LBS. (The correctives shipped before,
# fitted to single-joint sweeps, held 26 % here but folded skin in combined poses.)


@pytest.fixture(scope="module")
def default_lbs(default):
    arrays, meta = load_model_file(default.source_path)
    return HackModel({k: v for k, v in arrays.items() if not k.startswith("pose_")}, meta)


@pytest.mark.parametrize("joint", range(8))
def test_joint_limits_flip_nothing_and_stretch_little(default, default_lbs, joint):
    assert default.has_pose_basis and default.pose_personal is not None
    lim = torch.deg2rad(default.rotation_limits_deg)
    for axis in range(3):
        for side in range(2):
            e = torch.zeros(8, 3)
            e[joint, axis] = lim[joint, axis, side]
            flips, stretch = _deformation(default, R.euler_to_axis_angle(e))
            _, lbs = _deformation(default_lbs, R.euler_to_axis_angle(e))
            assert flips == 0, (joint, axis, side)
            assert stretch <= 0.38, (joint, axis, side, stretch)
            assert stretch <= lbs + 1e-3, (joint, axis, side, stretch, lbs)


def test_face_is_rigid_with_the_skull(default):
    """All 68 facial landmarks (jawline and chin included) move only with o-c1."""
    w = default.skinning_weights[default.landmark_indices]
    assert torch.all(w[:, 8] == 1.0)
    w = default.skinning_weights
    assert torch.all(w >= 0) and torch.allclose(w.sum(1), torch.ones(len(w)), atol=1e-5)
    # chest (the template's lowest skin) stays with the root
    low = default.template[:, 1] < default.template[:, 1].min() + 0.007
    assert torch.all(w[low & (default.vertex_group <= 1), 0] == 1.0)


def test_limit_penalties_clamp_and_distribution():
    lim = rotation_limits(torch.float64)
    gen = torch.Generator().manual_seed(7)
    inside = lim[..., 0] + (lim[..., 1] - lim[..., 0]) * torch.rand(50, 8, 3, generator=gen, dtype=torch.float64)
    th_in = R.euler_to_axis_angle(0.98 * inside)
    assert torch.all(rotation_limit_penalty(th_in) < 1e-12)
    outside = inside.clone()
    outside[:, 3, 1] = lim[3, 1, 1] + 0.1
    th_out = R.euler_to_axis_angle(outside)
    torch.testing.assert_close(rotation_limit_penalty(th_out), torch.full((50,), 0.1, dtype=torch.float64), atol=1e-9, rtol=0)
    clamped = R.axis_angle_to_euler(clamp_to_limits(th_out))
    assert torch.all(clamped <= lim[..., 1] + 1e-9) and torch.all(clamped >= lim[..., 0] - 1e-9)
    assert adjacent_similarity_penalty(torch.zeros(8, 3, dtype=torch.float64)) == 0
    assert adjacent_similarity_penalty(th_out).min() > 0
    # a 30 degree head turn is shared in the in-vivo proportions (Ishii 2004), mostly c1-c2
    th = distribute_head_rotation(torch.deg2rad(torch.tensor([0.0, 30.0, 0.0], dtype=torch.float64)))
    ang = torch.rad2deg(R.axis_angle_to_euler(th))[:, 1]
    assert ang.sum() == pytest.approx(30.0, abs=1e-9)
    assert ang[6] == pytest.approx(30.0 * 36.2 / 56.3, abs=1e-9)
    assert rotation_limit_penalty(th) == 0
    # a request beyond the whole neck's range stops at the range
    th = distribute_head_rotation(torch.deg2rad(torch.tensor([0.0, 200.0, 0.0], dtype=torch.float64)))
    assert rotation_limit_penalty(th) < 1e-12


def test_penalties_differentiable():
    th = (0.3 * torch.randn(2, 8, 3, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: adjacent_similarity_penalty(t), (th,))
    (rotation_limit_penalty(th * 3).sum()).backward()
    assert torch.isfinite(th.grad).all() and th.grad.abs().sum() > 0


def test_float64_and_batch_any_size(default):
    m64 = copy.deepcopy(default).double()
    out = m64(beta=torch.zeros(5, 3, dtype=torch.float64))
    assert out.vertices.dtype == torch.float64 and out.vertices.shape[0] == 5


def test_load_default_model_returns_independent_modules():
    """One caller's .double() / attribute change does not reach another's model; the
    copies share the loaded tensors (no memory copied)."""
    a, b = load_default_model(), load_default_model()
    assert a is not b and a.expr_personal is not b.expr_personal
    assert a.template.data_ptr() == b.template.data_ptr()  # read-only storage shared
    a.double()
    a.has_larynx = False
    assert b.template.dtype == torch.float32 and b.expr_personal.components.dtype == torch.float32
    assert b.has_larynx and load_default_model().template.dtype == torch.float32
    with torch.no_grad():
        out = b(beta=torch.zeros(1, 3))
    assert out.vertices.dtype == torch.float32


def test_expressions_as_a_list_one_per_row(default):
    """psi may be a list of expression strings / dicts / weight vectors, one per row."""
    specs = ["AU12=0.7, jawOpen=0.4", {"AU1": 0.5}, torch.zeros(default.num_expressions)]
    with torch.no_grad():
        out = default(psi=specs, beta=torch.zeros(3, 2))
        for b, spec in enumerate(specs):
            one = default(psi=spec if not torch.is_tensor(spec) else spec[None])
            torch.testing.assert_close(out.vertices[b], one.vertices[0], atol=1e-6, rtol=0)
    assert not torch.equal(out.vertices[0], out.vertices[1])
    with pytest.raises(HackError, match="batch size 3 does not match"):
        default(psi=specs, beta=torch.zeros(2, 2))
