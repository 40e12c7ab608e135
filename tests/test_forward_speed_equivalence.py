"""The fast forward (issue 65: rigid pose and blended LBS as column multiply-adds, the
MLPs, joints and larynx on the given betas only, one finiteness check, chain transforms
by one offset product) against the plain :func:`reference_forward`, on the shipped model:
values at B = 1 with 20 and 100 shape components, dense and sparse (FACS) psi, joint
angles drawn within the limits, eta and tau; and gradients of every input (float64)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.geometry import load_default_model
from hack_render.geometry.deformation import sample_joint_poses
from hack_render.geometry.lbs import chain_parents, rigid_transforms
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import load_model_file
from hack_render.geometry.reference import reference_forward

FIELDS = ("vertices", "joints", "rest_joints", "landmarks", "rest_vertices")


@pytest.fixture(scope="module")
def model():
    return load_default_model()


@pytest.fixture(scope="module")
def model_dead_mp():
    """The shipped model with M_P's second hidden layer switched off (w1 = 0, b1 < 0): one
    constant output for every identity, as a file whose M_P died (the identity-independent
    path at w = b2)."""
    arrays, meta = load_model_file(load_default_model().source_path)
    arrays = dict(arrays)
    arrays["pose_mlp_w1"] = np.zeros_like(arrays["pose_mlp_w1"])
    arrays["pose_mlp_b1"] = np.full_like(arrays["pose_mlp_b1"], -1.0)
    return HackModel(arrays, meta)


@pytest.fixture(scope="module")
def model64():
    return load_default_model().double()


def _inputs(model, num_shape: int, facs: bool, seed: int, b: int = 1) -> dict:
    """Random inputs of the benchmark's kind: beta (b, num_shape), psi dense in [0, 1] or
    a FACS expression (5 of 53 weights nonzero), every joint's Euler angles uniform within
    its limits, a root rotation, a translation, eta in [0.5, 1.5], tau of a few mm."""
    g = torch.Generator().manual_seed(seed)
    dt = model.template.dtype
    psi = (model.expression_vector("mouthSmile_L=0.7, jawOpen=0.3, cheekSquint_R=0.5")
           .expand(b, -1).clone() if facs
           else torch.rand(b, model.num_expressions, generator=g, dtype=dt))
    return {"beta": torch.randn(b, num_shape, generator=g, dtype=dt), "psi": psi,
            "theta": sample_joint_poses(b, g, dt),
            "global_orient": 0.2 * torch.randn(b, 3, generator=g, dtype=dt),
            "transl": 0.05 * torch.randn(b, 3, generator=g, dtype=dt),
            "eta": 0.5 + torch.rand(b, generator=g, dtype=dt),
            "tau": 0.004 * torch.randn(b, generator=g, dtype=dt)}


def _relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp(min=1e-30))


@pytest.mark.parametrize("num_shape,facs", [(20, False), (20, True), (100, False), (100, True)])
def test_01_values_equal_reference_float32(model, num_shape, facs):
    """Every output equals the plain formulation to 1e-6 of its largest magnitude."""
    p = _inputs(model, num_shape, facs, seed=num_shape + facs)
    if facs:
        assert int(p["psi"].ne(0).sum()) < model.num_expressions // 4  # the sparse path
    with torch.no_grad():
        fast, ref = model(**p), reference_forward(model, **p)
    for f in FIELDS:
        err = _relative_error(getattr(fast, f), getattr(ref, f).expand_as(getattr(fast, f)))
        assert err < 1e-6, f"{f}: relative error {err:.2e} (S={num_shape}, facs={facs})"


@pytest.mark.parametrize("num_shape,facs", [(20, False), (100, True)])
def test_02_gradients_equal_reference_float64(model64, num_shape, facs):
    """The gradient of a random linear function of every output, with respect to every
    input (the fitter's backward), equals the reference's to 1e-9 relative; B = 2 with
    distinct identities, and psi's zero weights get their gradients too."""
    p = _inputs(model64, num_shape, facs, seed=7 + num_shape, b=2)
    gen = torch.Generator().manual_seed(3)
    weights = None
    grads = []
    for fn in (lambda **k: model64(**k), lambda **k: reference_forward(model64, **k)):
        leaves = {k: v.clone().requires_grad_(True) for k, v in p.items()}
        out = fn(**leaves)
        if weights is None:
            weights = {f: torch.randn(getattr(out, f).shape, generator=gen, dtype=torch.float64)
                       for f in FIELDS}
        loss = sum((getattr(out, f) * weights[f]).sum() for f in FIELDS)
        grads.append(dict(zip(leaves, torch.autograd.grad(loss, list(leaves.values())))))
    for k in p:
        err = _relative_error(grads[0][k], grads[1][k])
        assert err < 1e-9, f"d/d{k}: relative error {err:.2e}"
    if facs:
        assert grads[0]["psi"][:, p["psi"][0] == 0].abs().max() > 0  # zero weights are live


def test_03_gradcheck_tiny_float64(model64):
    """Finite differences agree with autograd through the whole forward (B = 1, three
    betas, two expressions, every joint) on a few output vertices of each kind."""
    p = _inputs(model64, 3, False, seed=5)
    idx = torch.cat([model64.landmark_indices[:4], model64.blended_vertices[:4],
                     model64.expr_personal.vertices[:2], model64.larynx_vertices[:2]])
    x0 = torch.cat([p["beta"][0], p["psi"][0, :2], p["theta"][0].reshape(-1), p["eta"], p["tau"]])

    def f(x):
        psi = torch.cat([x[3:5], p["psi"][0, 2:]])[None]
        out = model64(beta=x[None, :3], psi=psi, theta=x[5:29].view(1, 8, 3),
                      global_orient=p["global_orient"], eta=x[29:30], tau=x[30:31])
        return out.vertices[0, idx], out.joints[0]

    assert torch.autograd.gradcheck(f, (x0.clone().requires_grad_(True),), eps=1e-6, atol=1e-7,
                                    fast_mode=True)


def test_04_chain_offsets_and_finiteness_check(model):
    """The chain transforms' offset product gives each node's offset from its parent
    (posed joints at zero rotation are the rest joints), and one non-finite input is
    still named."""
    j = torch.randn(2, 9, 3, dtype=torch.float64)
    rot = torch.eye(3, dtype=torch.float64).expand(2, 9, 3, 3)
    posed, rel = rigid_transforms(rot, j, chain_parents(model.parents))
    torch.testing.assert_close(posed, j, atol=1e-14, rtol=0)
    torch.testing.assert_close(rel, torch.eye(4, dtype=torch.float64).expand(2, 9, 4, 4),
                               atol=1e-14, rtol=0)
    bad = torch.zeros(1, model.num_joints, 3)
    bad[0, 3, 1] = float("nan")
    with pytest.raises(HackError, match="theta"):
        model(beta=torch.zeros(1, 20), theta=bad)


# ------------------------------------------------------------------ issue 65 §2: the B = 1 path
@pytest.mark.parametrize("mp", ["live", "dead"])
@pytest.mark.parametrize("num_shape,b,facs", [(20, 1, False), (20, 1, True), (100, 1, False),
                                              (20, 64, False), (100, 64, True)])
def test_05_row_major_and_single_row_paths_equal_reference(model, model_dead_mp, num_shape, b,
                                                           facs, mp):
    """The personalised expressions contracted with psi first (M_E row-major, B = 1: the
    generic rows on the moved vertices and the folded personal mean in one product), M_P
    live (the shipped file's) and identity-independent (at w = b2) and the block rigid
    posing equal the plain forward to 1e-6 of each output's largest magnitude, at B = 1 and
    B = 64 distinct identities."""
    model = model if mp == "live" else model_dead_mp
    p = _inputs(model, num_shape, facs, seed=11 + num_shape + b + facs, b=b)
    assert model.pose_personal.mlp.weights(p["beta"])[1] == (mp == "dead")
    assert not model.expr_personal.mlp.weights(p["beta"])[1]
    with torch.no_grad():
        fast, ref = model(**p), reference_forward(model, **p)
    for f in FIELDS:
        err = _relative_error(getattr(fast, f), getattr(ref, f).expand_as(getattr(fast, f)))
        assert err < 1e-6, f"{f}: relative error {err:.2e} (S={num_shape}, B={b}, facs={facs})"


@pytest.mark.parametrize("num_shape,facs,psi_grad", [(20, False, True), (100, False, True),
                                                     (20, True, False), (20, True, True)])
def test_06_single_row_gradients_equal_reference_float64(model64, num_shape, facs, psi_grad):
    """B = 1 gradients of every output (float64) equal the reference's to 1e-9: the single
    row path (dense psi, or sparse psi without a gradient) and the general one (sparse psi
    with a gradient: its zero weights get theirs)."""
    p = _inputs(model64, num_shape, facs, seed=23 + num_shape + facs, b=1)
    gen = torch.Generator().manual_seed(4)
    weights, grads = None, []
    for fn in (lambda **k: model64(**k), lambda **k: reference_forward(model64, **k)):
        leaves = {k: v.clone().requires_grad_(k != "psi" or psi_grad) for k, v in p.items()}
        out = fn(**leaves)
        if weights is None:
            weights = {f: torch.randn(getattr(out, f).shape, generator=gen, dtype=torch.float64)
                       for f in FIELDS}
        loss = sum((getattr(out, f) * weights[f]).sum() for f in FIELDS)
        names = [k for k, v in leaves.items() if v.requires_grad]
        grads.append(dict(zip(names, torch.autograd.grad(loss, [leaves[k] for k in names]))))
    for k in grads[1]:
        err = _relative_error(grads[0][k], grads[1][k])
        assert err < 1e-9, f"d/d{k}: relative error {err:.2e}"
    if facs and psi_grad:
        assert grads[0]["psi"][:, p["psi"][0] == 0].abs().max() > 0


@pytest.mark.parametrize("b", [8, pytest.param(64, marks=pytest.mark.slow)])
def test_07_gradients_batch_float64(model64, b):
    """B distinct identities (the row-major M_E's outer-product form): gradients of beta,
    psi and theta equal the reference's to 1e-9 (B = 64: 50 s, in the slow run)."""
    p = _inputs(model64, 20, False, seed=31, b=b)
    gen = torch.Generator().manual_seed(6)
    grads, weights = [], None
    for fn in (lambda **k: model64(**k), lambda **k: reference_forward(model64, **k)):
        leaves = {k: v.clone().requires_grad_(k in ("beta", "psi", "theta")) for k, v in p.items()}
        out = fn(**leaves)
        if weights is None:
            weights = torch.randn(out.vertices.shape, generator=gen, dtype=torch.float64)
        loss = (out.vertices * weights).sum()
        grads.append(torch.autograd.grad(loss, [leaves[k] for k in ("beta", "psi", "theta")]))
    for name, a, r in zip(("beta", "psi", "theta"), *grads):
        assert _relative_error(a, r) < 1e-9, f"d/d{name}"


def test_08_live_and_dead_mlps_equal_reference(model):
    """The personalised bases at w = b2 are used exactly when an MLP's second hidden layer
    is zero: an M_P brought to life (its hidden biases raised) takes the general path, an
    M_E with a dead hidden layer the bias basis, and both equal the plain forward."""
    import copy
    m = copy.deepcopy(model)
    with torch.no_grad():
        m.pose_personal.mlp.b1 += 0.5
        m.expr_personal.mlp.b1 -= 1e4
        m._fold_pose_mean()
    for b in (1, 3):
        p = _inputs(m, 20, False, seed=41 + b, b=b)
        assert not m.pose_personal.mlp.weights(p["beta"])[1]
        assert m.expr_personal.mlp.weights(p["beta"])[1]
        with torch.no_grad():
            fast, ref = m(**p), reference_forward(m, **p)
        for f in FIELDS:
            err = _relative_error(getattr(fast, f), getattr(ref, f).expand_as(getattr(fast, f)))
            assert err < 1e-6, f"{f}: relative error {err:.2e} (B={b})"


def test_09_path_transforms_equal_rigid_transforms():
    """The prefix-scan chain of a path (the model's) equals the node-by-node one: posed
    nodes and the top three rows of every transform, float64, random rotations."""
    from hack_render.geometry.lbs import is_path, local_rotations, path_transforms
    g = torch.Generator().manual_seed(8)
    for k in (1, 2, 5, 9):
        parents = tuple(range(-1, k - 1))
        assert is_path(parents) and not is_path((-1, 0, 0)[:max(k, 3)])
        rot = local_rotations(torch.randn(3, k - 1, 3, generator=g, dtype=torch.float64),
                              torch.randn(3, 3, generator=g, dtype=torch.float64))
        j = torch.randn(3, k, 3, generator=g, dtype=torch.float64)
        posed, rel = rigid_transforms(rot, j, parents)
        posed_p, rel_p = path_transforms(rot, j)
        torch.testing.assert_close(posed_p, posed, atol=1e-13, rtol=0)
        torch.testing.assert_close(rel_p, rel[..., :3, :], atol=1e-13, rtol=0)
