"""The flexion block (model format 5, geometry/flex_block.py): every path that evaluates the
model (the fast forward, the plain reference, the personalised module, NumPy posing, the
glTF rig) gives the same mesh with a block; the block vanishes at rest and outside its
knots, has finite gradients there, and matches finite differences in a nod; the file
format checks it and still reads format 4."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.export import rig as R
from hack_render.geometry.flex_block import flex_weights_np
from hack_render.geometry.lbs import flex_weights, local_rotations
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import (
    default_model_path,
    load_model_file,
    save_model_file,
    validate_arrays,
    without_correctives,
)
from hack_render.geometry.posing import PosingModel
from hack_render.geometry.reference import reference_forward
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.learn.flex_learn import knots_deg

KNOTS = knots_deg(-80, 80)


@pytest.fixture(scope="module")
def arrays():
    """The default model's arrays with a random block (4 mm scale) on 400 neck vertices
    (the shipped block replaced, where there is one)."""
    a = {k: v for k, v in load_model_file(default_model_path())[0].items()
         if not k.startswith("flex_")}
    rng = np.random.default_rng(0)
    verts = np.sort(rng.choice(np.asarray(a["pose_pca_vertices"]), 400, replace=False))
    a.update({"flex_vertices": verts.astype(np.int32),
              "flex_basis": (4e-3 * rng.standard_normal((len(KNOTS), 21, 400, 3))).astype(np.float32),
              "flex_knots_deg": KNOTS.astype(np.float32), "flex_width_deg": np.float32(10.0),
              "flex_purity_deg": np.float32(20.0), "flex_coherence": np.float32(4.0)})
    validate_arrays(a)
    return a


@pytest.fixture(scope="module")
def model(arrays):
    return HackModel(arrays)


def poses(n: int, seed: int = 0) -> torch.Tensor:
    """n poses: rest, nods over the knots' whole range, and random combined rotations."""
    g = torch.Generator().manual_seed(seed)
    nod = torch.deg2rad(torch.linspace(-85, 85, n // 2, dtype=torch.float64))
    head = torch.stack([nod, 0.2 * torch.randn(n // 2, generator=g, dtype=torch.float64),
                        0.1 * torch.randn(n // 2, generator=g, dtype=torch.float64)], -1)
    rnd = 0.12 * torch.randn(n - n // 2, 8, 3, generator=g, dtype=torch.float64)
    out = torch.cat([distribute_head_rotation(head), rnd]).float()
    out[-1] = 0
    return out


def test_01_every_path_gives_the_same_mesh(model, arrays):
    """Fast forward, reference, personalised module and NumPy posing agree with a block
    (to float32 rounding), and the block moves the mesh by millimetres."""
    theta = poses(8)
    g = torch.Generator().manual_seed(1)
    beta = torch.randn(len(theta), 20, generator=g)
    with torch.no_grad():
        fast = model(beta=beta, theta=theta).vertices
        ref = reference_forward(model, beta=beta, theta=theta).vertices
        plain = HackModel(without_correctives(arrays))(beta=beta, theta=theta).vertices
        bare = HackModel({k: v for k, v in arrays.items() if not k.startswith("flex_")})(
            beta=beta, theta=theta).vertices
    assert (fast - ref).abs().max() < 2e-6
    moved = (fast - bare).norm(dim=-1).amax(1)
    assert moved[:3].min() > 1e-3, moved  # nods within the knots: the block acts
    assert moved[-1] == 0                   # rest: it vanishes
    assert (bare - plain).abs().max() > 0   # and the other correctives are still there
    posing = PosingModel(arrays)
    for b in (1, 5):
        with torch.no_grad():
            one = model.personalize(beta[b:b + 1])(theta=theta[b:b + 1]).vertices[0]
        assert (one - fast[b]).abs().max() < 2e-6
        np_v = posing.vertices(beta=beta[b].numpy(), theta=theta[b].numpy())
        assert np.abs(np_v - fast[b].numpy()).max() < 2e-6


def test_02_weights_hats_purity_and_their_numpy_twin():
    """At most two hats act, they sum to 1 between the knots of a pure nod, purity fades a
    combined rotation, nothing acts past the outer knots' reach, and NumPy equals torch."""
    theta = poses(40).double()
    rot = local_rotations(theta, torch.zeros(len(theta), 3, dtype=torch.float64))[:, 1:]
    w = flex_weights(rot, torch.deg2rad(torch.as_tensor(KNOTS)), math.radians(10), math.radians(20),
                     4.0)
    assert ((w > 0).sum(1) <= 2).all()
    w_np = flex_weights_np(theta.numpy(), KNOTS, 10.0, 20.0, 4.0)
    assert np.abs(w_np - w.numpy()).max() < 1e-9
    # coherence: a nod (every joint the same way) keeps its weights, the same net flexion
    # with the joints bending against each other loses most of them
    same = np.zeros((2, 8, 3))
    same[0, :, 0] = np.deg2rad(30.0) / 8
    same[1, :, 0] = np.deg2rad([12, -6, 12, -6, 12, -6, 12, 0])  # net 30 degrees too
    wc = flex_weights_np(same, KNOTS, 10.0, 20.0, 4.0)
    w0 = flex_weights_np(same, KNOTS, 10.0, 20.0, 0.0)
    assert np.allclose(wc[0], w0[0], atol=1e-7) and w0[1].sum() == pytest.approx(1.0, abs=1e-6)
    assert wc[1].sum() < 0.2 * w0[1].sum()
    nod = np.zeros((4, 8, 3))  # pure flexion shared by the 8 joints: the net angle is the sum
    nod[:, :, 0] = np.deg2rad([[-55.0], [33.0], [95.0], [4.0]]) / 8
    wn = flex_weights_np(nod, KNOTS, 10.0, 20.0)
    assert wn[0].sum() == pytest.approx(1.0, abs=1e-6) and wn[1].sum() == pytest.approx(1.0, abs=1e-6)
    assert wn[2].sum() == 0                      # past 80 + 10 degrees
    assert wn[3].sum() == pytest.approx(0.4, abs=1e-6)   # between rest and the first knot
    turned = distribute_head_rotation(torch.deg2rad(torch.tensor([[-55.0, 20.0, 0.0]],
                                                                 dtype=torch.float64)))
    assert flex_weights_np(turned.numpy(), KNOTS, 10.0, 20.0).sum() < 0.5


def test_03_gradients_finite_at_rest_and_equal_to_finite_differences(model):
    m = model.double()
    beta = torch.randn(1, 20, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    vid = m.flex.vertices[:5]
    rest = torch.zeros(1, 8, 3, dtype=torch.float64, requires_grad=True)
    m(beta=beta, theta=rest).vertices[0, vid].sum().backward()
    assert torch.isfinite(rest.grad).all()
    nod = distribute_head_rotation(torch.deg2rad(torch.tensor([[-43.0, 6.0, -3.0]],
                                                              dtype=torch.float64)))
    th = nod.clone().requires_grad_()
    f = lambda t: m(beta=beta, theta=t).vertices[0, vid].sum()
    f(th).backward()
    eps = 1e-6
    for j, a in ((7, 0), (3, 0), (5, 1)):
        d = torch.zeros_like(nod)
        d[0, j, a] = eps
        fd = (f(nod + d) - f(nod - d)) / (2 * eps)
        assert float(th.grad[0, j, a]) == pytest.approx(float(fd), rel=1e-5, abs=1e-9)


def test_04_file_format_round_trip_checks_and_format_4(arrays, tmp_path):
    path = tmp_path / "m.npz"
    save_model_file(path, arrays, {"note": "test"})
    back, _ = load_model_file(path)
    assert np.abs(back["flex_basis"] - arrays["flex_basis"]).max() < 4e-3 * 6 / 32767
    assert np.array_equal(back["flex_vertices"], arrays["flex_vertices"])
    for key, value, words in (("flex_knots_deg", np.r_[KNOTS[:8], 0.0, KNOTS[9:]], "without 0"),
                              ("flex_width_deg", np.float32(0), "flex_width_deg"),
                              ("flex_coherence", np.float32(-1), "flex_coherence"),
                              ("flex_basis", np.zeros((len(KNOTS), len(arrays["shape_std"]) + 2,
                                                       400, 3)), "terms per hat")):
        with pytest.raises(HackError, match=words):
            validate_arrays(dict(arrays, **{key: np.asarray(value, np.float32)}))
    with pytest.raises(HackError, match="incomplete"):
        validate_arrays({k: v for k, v in arrays.items() if k != "flex_purity_deg"})
    with np.load(path) as z:
        raw = {k: z[k] for k in z.files if not k.startswith("flex_")}
    np.savez(tmp_path / "v4.npz", **dict(raw, format_version=np.asarray(4)))
    assert HackModel(*load_model_file(tmp_path / "v4.npz")).flex is None


def test_05_the_rig_carries_the_block(model, arrays):
    """The glTF rig's flex targets are the identity's hats; its frame weights are the
    model's, and its rest mesh plus the weighted targets skinned equal the forward."""
    beta = torch.tensor([[0.8, -1.2, 0.5]])
    rig = R.build_rig(model, beta, 1.0)
    s = rig.slots["flex"]
    assert s.stop - s.start == len(KNOTS) and rig.target_names[s.start] == "flex_-80deg"
    theta = poses(6, seed=3).double().numpy()
    wts = R.frame_weights(rig, None, theta, None)
    assert np.abs(wts[:, s] - flex_weights_np(theta, KNOTS, 10.0, 20.0, 4.0)).max() < 1e-12
    assert wts.min() >= 0 and wts.max() <= 1
    with torch.no_grad():
        want = model(beta=beta.expand(len(theta), -1), theta=torch.as_tensor(theta).float(),
                     eta=torch.ones(len(theta))).rest_vertices.double().numpy()
    got = rig.base[None] + np.einsum("tk,knc->tnc", wts, rig.targets.astype(np.float64))
    assert np.abs(got - want).max() < 2e-5
