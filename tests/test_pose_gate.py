"""The pose correctives' gate (model format 3, issue 60): each joint's ``R - I`` block times
g = s^2 / (s^2 + c^4), s = 2 (1 - cos angle). Small rotations leave the skin to plain LBS,
large ones get the full corrective; format 2 files load ungated; the torch forward, the
plain reference and the NumPy posing path agree on a gated file. Format 4's chain weight
(``pose_gate_chain``) also opens the gate by the chain's net rotation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.geometry import HackModel
from hack_render.geometry import rotations as R
from hack_render.geometry.lbs import net_axial, pose_feature, pose_gate
from hack_render.geometry.model_file import (
    FORMAT_VERSION,
    load_model_file,
    save_model_file,
    without_correctives,
)
from hack_render.geometry.posing import PosingModel
from hack_render.geometry.reference import reference_forward
from tests.synthetic import synthetic_arrays

GATE = 8.0


def _rot(axis_angle) -> torch.Tensor:
    return R.axis_angle_to_matrix(torch.as_tensor(axis_angle, dtype=torch.float64))


def test_01_gate_values_and_gradient():
    c = math.radians(GATE)
    axis = torch.tensor([0.3, -0.8, 0.5], dtype=torch.float64)
    axis = axis / axis.norm()
    deg = torch.tensor([0.0, 2.0, 4.0, 8.0, 16.0, 40.0], dtype=torch.float64)
    g = pose_gate(_rot(torch.deg2rad(deg)[:, None] * axis), c)
    # about angle^4 / (angle^4 + c^4): 0 at rest, 1/2 at c, near 1 well above
    want = deg ** 4 / (deg ** 4 + GATE ** 4)
    torch.testing.assert_close(g, want, atol=5e-3, rtol=0)
    assert g[0] == 0 and abs(float(g[3]) - 0.5) < 5e-3 and g[-1] > 0.99
    assert torch.all(torch.diff(g) > 0)
    # smooth through the identity (no square root): finite-difference gradients hold there
    r = (1e-3 * torch.randn(2, 8, 3, dtype=torch.float64)).requires_grad_()
    torch.autograd.gradcheck(lambda t: pose_feature(R.axis_angle_to_matrix(t), c), (r,))
    r0 = torch.zeros(1, 8, 3, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda t: pose_feature(R.axis_angle_to_matrix(t), c), (r0,))
    # ungated is the plain SMPL feature
    rot = R.axis_angle_to_matrix(torch.randn(3, 8, 3, dtype=torch.float64))
    torch.testing.assert_close(pose_feature(rot), (rot - torch.eye(3, dtype=torch.float64)).flatten(1))


@pytest.fixture(scope="module")
def gated_arrays():
    a = synthetic_arrays(seed=2)
    a["pose_gate_deg"] = np.asarray(GATE, np.float32)
    return a


def test_02_small_rotations_are_plain_lbs_large_ones_corrected(gated_arrays):
    gated = HackModel(gated_arrays)
    plain = HackModel({k: v for k, v in gated_arrays.items() if k != "pose_gate_deg"})
    lbs = HackModel(without_correctives(gated_arrays))
    small = torch.zeros(1, 8, 3)
    small[0, :, 0] = torch.deg2rad(torch.tensor([2.0, -2.0] * 4))  # alternating 2 degrees
    big = torch.zeros(1, 8, 3)
    big[0, 3, 1] = math.radians(40.0)
    d = {}
    for name, m in (("gated", gated), ("plain", plain), ("lbs", lbs)):
        d[name] = [m(theta=t).vertices.double() for t in (small, big)]
    # at 2 degrees the gate is (2/8)^4 / (1 + (2/8)^4) = 0.0039 of the corrective
    off_small = (d["plain"][0] - d["lbs"][0]).abs().max()
    assert off_small > 0
    assert (d["gated"][0] - d["lbs"][0]).abs().max() <= 0.005 * off_small
    # at 40 degrees 0.9984 of it
    off_big = (d["plain"][1] - d["lbs"][1]).abs().max()
    assert (d["gated"][1] - d["plain"][1]).abs().max() <= 0.01 * off_big


@pytest.mark.parametrize("chain", [None, 1.0])
def test_03_fast_forward_reference_and_numpy_path_agree(gated_arrays, chain):
    arrays = gated_arrays if chain is None else dict(gated_arrays,
                                                     pose_gate_chain=np.float32(chain))
    tm, nm = HackModel(arrays), PosingModel(arrays)
    assert tm.pose_gate_chain == (chain or 0.0)
    g = np.random.default_rng(5)
    for _ in range(4):
        kw = {"beta": g.normal(size=nm.num_shape).astype(np.float32),
              "psi": g.uniform(0, 1, nm.num_expressions).astype(np.float32),
              "theta": g.normal(scale=0.2, size=(8, 3)).astype(np.float32)}
        t_kw = {k: torch.as_tensor(v)[None] for k, v in kw.items()}
        fast = tm(**t_kw).vertices[0].numpy()
        ref = reference_forward(tm, **t_kw).vertices[0].numpy()
        assert np.abs(fast - ref).max() < 2e-6
        assert np.abs(nm.vertices(**kw) - fast).max() < 2e-6
    pers = tm.personalize(torch.as_tensor(kw["beta"])[None])
    out = pers(psi=t_kw["psi"], theta=t_kw["theta"]).vertices[0].numpy()
    assert np.abs(out - fast).max() < 2e-6


def test_04_format_3_round_trip_and_older_files(gated_arrays, tmp_path):
    assert FORMAT_VERSION == 5
    save_model_file(tmp_path / "g.npz", gated_arrays, {})
    arrays, _ = load_model_file(tmp_path / "g.npz")
    assert float(arrays["pose_gate_deg"]) == GATE
    assert HackModel(arrays).pose_gate_rad == pytest.approx(math.radians(GATE))
    # a format-2 file (no gate) loads, ungated
    old = {k: v for k, v in gated_arrays.items() if k != "pose_gate_deg"}
    save_model_file(tmp_path / "old.npz", old, {})
    with np.load(tmp_path / "old.npz") as z:
        raw = {k: z[k] for k in z.files}
    raw["format_version"] = np.asarray(2)
    np.savez(tmp_path / "v2.npz", **raw)
    arrays, _ = load_model_file(tmp_path / "v2.npz")
    assert "pose_gate_deg" not in arrays and HackModel(arrays).pose_gate_rad is None
    # a gate that is no angle is refused, naming the key, on writing and on loading
    for bad in (0.0, -3.0, 120.0):
        with pytest.raises(HackError, match="pose_gate_deg"):
            save_model_file(tmp_path / "bad.npz", dict(gated_arrays, pose_gate_deg=np.float32(bad)), {})
        np.savez(tmp_path / "bad.npz", **dict(raw, format_version=np.asarray(3),
                                               pose_gate_deg=np.asarray(bad, np.float32)))
        with pytest.raises(HackError, match="pose_gate_deg"):
            load_model_file(tmp_path / "bad.npz")


def test_05_the_chain_term_opens_a_spread_nod_and_not_alternation():
    """lambda |n|^2 with n the sum of the joints' axial vectors: a 20-degree nod spread over
    the 8 joints (2.5 degrees each) is gated shut by each joint's own angle and opened by
    the chain's; rotations alternating about one axis cancel in n exactly, so their gate is
    the per-joint one; gradients stay finite-difference exact, at rest too."""
    c = math.radians(12.0)
    nod = torch.zeros(1, 8, 3, dtype=torch.float64)
    nod[0, :, 0] = math.radians(2.5)
    rot = R.axis_angle_to_matrix(nod)
    torch.testing.assert_close(net_axial(rot)[0], torch.tensor([8 * math.sin(math.radians(2.5)),
                                                                0.0, 0.0], dtype=torch.float64))
    assert pose_gate(rot, c).max() < 0.01
    assert pose_gate(rot, c, 1.0).min() > 0.8
    alt = torch.zeros(1, 8, 3, dtype=torch.float64)
    alt[0, :, 2] = torch.deg2rad(torch.tensor([5.0, -5.0] * 4, dtype=torch.float64))
    rot = R.axis_angle_to_matrix(alt)
    torch.testing.assert_close(pose_gate(rot, c, 1.0), pose_gate(rot, c), atol=1e-12, rtol=0)
    for r in (1e-2 * torch.randn(2, 8, 3, dtype=torch.float64),
              torch.zeros(1, 8, 3, dtype=torch.float64)):
        torch.autograd.gradcheck(lambda t: pose_feature(R.axis_angle_to_matrix(t), c, 0.7),
                                 (r.requires_grad_(),))


def test_06_format_4_chain_round_trip_and_refusals(gated_arrays, tmp_path):
    chained = dict(gated_arrays, pose_gate_chain=np.float32(0.5))
    save_model_file(tmp_path / "c.npz", chained, {})
    arrays, _ = load_model_file(tmp_path / "c.npz")
    assert float(arrays["pose_gate_chain"]) == 0.5 and HackModel(arrays).pose_gate_chain == 0.5
    # a chain weight without the gate it opens, or a negative one, is refused by name
    nogate = {k: v for k, v in chained.items() if k != "pose_gate_deg"}
    for bad in (nogate, dict(chained, pose_gate_chain=np.float32(-1.0))):
        with pytest.raises(HackError, match="pose_gate_chain"):
            save_model_file(tmp_path / "bad.npz", bad, {})
    # a format-3 file (gate, no chain) loads with the chain term off
    save_model_file(tmp_path / "g.npz", gated_arrays, {})
    with np.load(tmp_path / "g.npz") as z:
        raw = {k: z[k] for k in z.files}
    np.savez(tmp_path / "v3.npz", **dict(raw, format_version=np.asarray(3)))
    arrays, _ = load_model_file(tmp_path / "v3.npz")
    assert HackModel(arrays).pose_gate_chain == 0.0


def test_07_learn_pose_writes_the_chain_and_refuses_it_without_a_gate(tmp_path, capsys):
    """`learn pose --pose-gate C --pose-gate-chain L` writes a format-4 file that loads with
    both (one step here) and records them; a chain weight without a gate exits 2 with one
    line naming the option, before any learning."""
    from hack_render.cli import main

    out = tmp_path / "m.npz"
    main(["learn", "pose", "-o", str(out), "--iterations", "1", "--identities", "1",
          "--mine-poses", "2", "--hard-examples", "0", "--pose-gate", "12",
          "--pose-gate-chain", "0.5", "--corner-poses", "0.5", "--loss", "anchor=0.05",
          "--quiet"])
    arrays, meta = load_model_file(out)
    assert meta["learn"]["pose"]["corner_poses"] == 0.5
    assert meta["learn"]["pose"]["loss_weights"]["anchor"] == 0.05
    assert "anchor" in meta["learn"]["pose"]["history"][0]
    model = HackModel(arrays, meta)
    assert model.pose_gate_rad == pytest.approx(math.radians(12.0))
    assert model.pose_gate_chain == 0.5 and meta["learn"]["pose"]["gate_chain"] == 0.5
    with pytest.raises(SystemExit) as exc:
        main(["learn", "pose", "-o", str(tmp_path / "n.npz"), "--iterations", "1",
              "--pose-gate-chain", "1", "--quiet"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--pose-gate-chain" in err[-1] and not (tmp_path / "n.npz").exists()
