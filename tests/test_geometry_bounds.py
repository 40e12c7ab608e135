"""Every parameter bounded (issue 21, part 3): the larynx's tau and eta ranges (penalty,
clamp, --limits), whole-head rotations beyond the neck's range, and the CLI's exit code."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import pytest
import torch

from hack_render.errors import HackError
from hack_render.geometry import load_default_model
from hack_render.geometry import rotations as R
from hack_render.geometry.larynx import (
    ETA_RANGE,
    TAU_RANGE_M,
    clamp_larynx,
    larynx_limit_penalty,
    larynx_outside_limits,
)
from hack_render.geometry.limits import enforce_limits
from hack_render.geometry.params import model_inputs
from hack_render.geometry.skeleton import head_rotation_range_deg, rotation_limits_deg


@pytest.fixture(scope="module")
def default():
    return load_default_model()


def test_larynx_penalty_zero_inside_exact_outside_and_differentiable():
    eta = torch.linspace(*ETA_RANGE, 7, dtype=torch.float64)
    tau = torch.linspace(*TAU_RANGE_M, 7, dtype=torch.float64)
    assert torch.all(larynx_limit_penalty(eta, tau) == 0)
    out = larynx_limit_penalty(torch.tensor([2.0, -0.3], dtype=torch.float64),
                               torch.tensor([0.0, -0.03], dtype=torch.float64))
    w_eta, w_tau = ETA_RANGE[1] - ETA_RANGE[0], TAU_RANGE_M[1] - TAU_RANGE_M[0]
    torch.testing.assert_close(out, torch.tensor([0.5 / w_eta, 0.3 / w_eta + 0.02 / w_tau],
                                                 dtype=torch.float64), atol=1e-12, rtol=0)
    x = (torch.tensor([2.0, -0.3, 0.7], dtype=torch.float64).requires_grad_(True),
         torch.tensor([0.05, -0.03, 0.001], dtype=torch.float64).requires_grad_(True))
    assert torch.autograd.gradcheck(larynx_limit_penalty, x)
    e, t = clamp_larynx(torch.tensor([-1.0, 0.5, 9.0]), torch.tensor([-0.05, 0.0, 0.05]))
    assert e.tolist() == [ETA_RANGE[0], 0.5, ETA_RANGE[1]]
    torch.testing.assert_close(t, torch.tensor([TAU_RANGE_M[0], 0.0, TAU_RANGE_M[1]]))
    bad = larynx_outside_limits(torch.tensor([2.0]), torch.tensor([-0.05]))
    assert [(b[0], b[1]) for b in bad] == [("eta", 2.0), ("tau", pytest.approx(-0.05))]


def test_larynx_ranges_hold_on_the_shipped_maps(default):
    """Across the tau range the mean identity's larynx stays whole on its maps (peak >= 95 %
    of the rest peak) and slides by tau; eta's range spans no prominence to ~10-12 mm at
    the median identity (ANATOMY.md: 5-10 mm in males, 1-3 mm in females)."""
    with torch.no_grad():
        def peak(eta, tau, beta=None):
            d = default.larynx_displacement(beta, torch.tensor([eta]), torch.tensor([tau]))[0]
            n = d.norm(dim=1)
            return float(n.max()), float(default.larynx_uv[n.argmax(), 1])

        h0, v0 = peak(1.0, 0.0)
        for tau in TAU_RANGE_M:
            h, v = peak(1.0, tau)
            assert h >= 0.95 * h0, (tau, h, h0)
            assert abs((v - v0) - tau) < 0.003, (tau, v - v0)  # the peak slides by tau
        assert peak(ETA_RANGE[0], 0.0)[0] == 0.0
        g = torch.Generator().manual_seed(3)
        beta = torch.randn(200, default.num_shape, generator=g)
        d = default.larynx_displacement(beta, torch.full((200,), ETA_RANGE[1]), torch.zeros(200))
        median_mm = 1e3 * float(d.norm(dim=-1).amax(1).median())
    assert 8.0 < median_mm < 12.5, median_mm


def test_head_turn_beyond_the_neck_is_an_error_or_a_named_clamp(default):
    """A 120 deg head turn: --limits error names the axis, value and range; warn and clamp
    clamp it to the neck's 77 deg and say so."""
    rng = head_rotation_range_deg()
    assert float(rng[1, 1]) == pytest.approx(float(rotation_limits_deg()[:, 1, 1].sum()))
    assert float(rng[1, 1]) == pytest.approx(77.0)
    kw = model_inputs(default, {"head_rotation_deg": [0.0, 120.0, 0.0]})
    with pytest.raises(HackError, match=r"head rotation axial rotation \(y\) 120\.0 deg "
                                        r"\(whole-neck range -77\.0\.\.77\.0 deg\)"):
        enforce_limits(kw, "error", [0.0, 120.0, 0.0])
    for policy in ("warn", "clamp"):
        out, msgs = enforce_limits(kw, policy, [0.0, 120.0, 0.0])
        assert len(msgs) == 1 and "120.0 deg" in msgs[0] and "clamped to 77.0 deg" in msgs[0]
        axial = torch.rad2deg(R.axis_angle_to_euler(out["theta"][0].double()))[:, 1].sum()
        assert float(axial) == pytest.approx(77.0, abs=1e-4)
    # inside the range: nothing to say, under any policy
    kw = model_inputs(default, {"head_rotation_deg": [10.0, 60.0, -20.0]})
    for policy in ("warn", "clamp", "error"):
        assert enforce_limits(kw, policy, [10.0, 60.0, -20.0])[1] == []


def test_larynx_and_joint_values_under_each_policy(default):
    kw = model_inputs(default, {"tau": -0.05, "eta": 2.0})
    with pytest.raises(HackError, match=r"larynx eta = 2 \(range 0\.\.1\.5\).*larynx tau = "
                                        r"-0\.05 m \(range -0\.01\.\.0\.02 m\)"):
        enforce_limits(kw, "error", None)
    out, msgs = enforce_limits(kw, "clamp", None)
    assert float(out["eta"][0]) == ETA_RANGE[1]
    assert float(out["tau"][0]) == pytest.approx(TAU_RANGE_M[0])
    assert any("clamped to -0.01 m" in m for m in msgs)
    out, msgs = enforce_limits(kw, "warn", None)
    assert float(out["tau"][0]) == pytest.approx(-0.05) and all("kept" in m for m in msgs)
    theta = torch.zeros(1, 8, 3)
    theta[0, 6] = R.euler_to_axis_angle(torch.tensor([0.0, 0.0, 0.2]))  # c1-c2 lateral 11.5 deg
    with pytest.raises(HackError, match=r"joint c1-c2 axis z = 11\.5 deg \(limits -5\.0\.\.5\.0"):
        enforce_limits({"theta": theta}, "error")
    with pytest.raises(HackError, match="--limits: expected one of"):
        enforce_limits({"theta": theta}, "ignore")


def test_forward_clamp_limits_clamps_eta_and_tau(default):
    with torch.no_grad():
        a = default(eta=torch.tensor([3.0]), tau=torch.tensor([0.1]), clamp_limits=True)
        b = default(eta=torch.tensor([ETA_RANGE[1]]), tau=torch.tensor([TAU_RANGE_M[1]]))
    assert torch.equal(a.vertices, b.vertices)


def test_fitter_projects_eta_and_tau_onto_their_ranges():
    """The fitter's projection after each step uses the anatomical ranges (the photometric
    stage also adds E_larynx = w_rot * larynx_limit_penalty to its objective)."""
    from hack_render.fit.state import FitState

    ns = SimpleNamespace(psi=torch.tensor([1.5]), views=[], eta=torch.tensor([2.5]),
                         tau=torch.tensor([-0.04]))
    FitState.clamp_(ns)
    assert float(ns.eta) == ETA_RANGE[1] and float(ns.tau) == pytest.approx(TAU_RANGE_M[0])


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hack_render.cli", *args], check=False,
                          capture_output=True, text=True)


def test_cli_head_turn_120_exits_2_under_limits_error_and_warns_otherwise(tmp_path,
                                                                          cli_in_process):
    _cli = cli_in_process
    res = _cli("mesh", "-o", str(tmp_path / "m.obj"), "--head-rotation", "0,120,0",
               "--limits", "error")
    assert res.returncode == 2, res.stderr
    assert "axial rotation (y) 120.0 deg" in res.stderr and "-77.0..77.0" in res.stderr
    assert not (tmp_path / "m.obj").exists()
    res = _cli("mesh", "-o", str(tmp_path / "m.obj"), "--head-rotation", "0,120,0",
               "--tau", "-0.05")
    assert res.returncode == 0, res.stderr
    assert "clamped to 77.0 deg" in res.stderr and "tau = -0.05 m" in res.stderr
