"""Posing without torch (geometry/posing.py, np_rotations.py, anatomy.py): held equal to
the torch model and its rotation, limit and input code over the whole input space."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.geometry import HackModel, default_model_path, load_default_model
from hack_render.geometry import np_rotations as NR
from hack_render.geometry import rotations as R
from hack_render.geometry.anatomy import clamp_theta, outside_limits
from hack_render.geometry.anatomy import distribute_head_rotation as distribute_np
from hack_render.geometry.deformation import sample_pose_space
from hack_render.geometry.limits import LimitPolicy, apply_limit_policy
from hack_render.geometry.params import model_inputs
from hack_render.geometry.posing import PosingModel
from hack_render.geometry.skeleton import clamp_to_limits, distribute_head_rotation
from tests.synthetic import synthetic_arrays


@pytest.fixture(scope="module")
def models():
    return load_default_model(), PosingModel.from_file(default_model_path())


def _torch_vertices(model, kw):
    t = {k: torch.as_tensor(np.asarray(v))[None] for k, v in kw.items()}
    with torch.no_grad():
        return model(**t).vertices[0].numpy()


def test_01_rotations_equal_torch():
    """Rodrigues, Euler and quaternion conversions: the same values as the torch module's
    at random, tiny (series branch) and near-pi angles."""
    g = np.random.default_rng(0)
    r = np.concatenate([g.normal(size=(200, 3)), g.normal(size=(20, 3)) * 1e-5,
                        np.array([3.1, 0.0, 0.1]) + g.normal(scale=0.01, size=(20, 3))])
    rt = torch.tensor(r)
    assert np.allclose(NR.axis_angle_to_matrix(r), R.axis_angle_to_matrix(rt).numpy(), atol=1e-12)
    assert np.allclose(NR.axis_angle_to_euler(r), R.axis_angle_to_euler(rt).numpy(), atol=1e-9)
    e = g.uniform(-1.2, 1.2, size=(200, 3))
    assert np.allclose(NR.euler_to_axis_angle(e), R.euler_to_axis_angle(torch.tensor(e)).numpy(),
                       atol=1e-12)
    # against the elementary rotations composed Rx(e_x) Rz(e_z) Ry(e_y), independently
    c, s_ = np.cos(e), np.sin(e)
    o, i = np.zeros(len(e)), np.ones(len(e))
    rx = np.stack([i, o, o, o, c[:, 0], -s_[:, 0], o, s_[:, 0], c[:, 0]], -1).reshape(-1, 3, 3)
    ry = np.stack([c[:, 1], o, s_[:, 1], o, i, o, -s_[:, 1], o, c[:, 1]], -1).reshape(-1, 3, 3)
    rz = np.stack([c[:, 2], -s_[:, 2], o, s_[:, 2], c[:, 2], o, o, o, i], -1).reshape(-1, 3, 3)
    assert np.allclose(NR.axis_angle_to_matrix(NR.euler_to_axis_angle(e)), rx @ rz @ ry,
                       atol=1e-12)
    # the round trip away from gimbal lock (lateral, the middle axis, inside +-69 degrees)
    assert np.allclose(NR.axis_angle_to_euler(NR.euler_to_axis_angle(e)), e, atol=1e-9)


def test_02_limits_and_head_rotation_equal_torch():
    """Clamping, the whole-head share and the out-of-range report agree with the torch
    functions over the pose space's families and beyond the limits (x 1.6)."""
    fam = sample_pose_space(96, seed=4)
    theta = torch.cat(list(fam.values())) * 1.6
    clamped = clamp_theta(theta.numpy())
    assert np.allclose(clamped, clamp_to_limits(theta).numpy(), atol=1e-9)
    assert not outside_limits(clamped)
    assert outside_limits(theta) == outside_limits(theta.numpy())  # tensors or arrays
    assert len(outside_limits(theta)) > 50
    g = np.random.default_rng(1)
    for ang in np.deg2rad(g.uniform(-150, 150, size=(40, 3))):
        assert np.allclose(distribute_np(ang), distribute_head_rotation(torch.tensor(ang)).numpy(),
                           atol=1e-12)


def test_03_vertices_equal_the_torch_forward(models):
    """Posed vertices within 2e-6 m of HackModel.forward (float32 both) for random
    identities (some betas given), expression mixes, joint poses sampled over the whole
    pose space (combined axes at every joint, inside and 1.3x beyond the limits), global
    orientations, translations, eta in and beyond its range and tau sliding the larynx
    off its maps."""
    torch_model, np_model = models
    g = np.random.default_rng(2)
    fam = sample_pose_space(24, seed=5, dtype=torch.float32)
    poses = torch.cat(list(fam.values())).numpy()
    for i, theta in enumerate(poses):
        kw = {"beta": g.normal(size=g.integers(1, 101)).astype(np.float32),
              "psi": (g.uniform(0, 1, 53) * (g.uniform(size=53) < 0.25)).astype(np.float32),
              "theta": theta * (1.3 if i % 3 == 0 else 1.0),
              "global_orient": g.normal(scale=0.3, size=3).astype(np.float32),
              "transl": g.normal(scale=0.1, size=3).astype(np.float32),
              "eta": np.float32(g.uniform(0, 2.0)), "tau": np.float32(g.uniform(-0.03, 0.06))}
        err = np.abs(np_model.vertices(**kw) - _torch_vertices(torch_model, kw)).max()
        assert err < 2e-6, (i, err)
    # the defaults: the template's rest pose with the mean larynx
    assert np.abs(np_model.vertices() - _torch_vertices(torch_model, {})).max() < 1e-6


def test_04_other_model_structures():
    """A model whose generic pose rows are not on the personalised pose vertices, whose
    larynx maps are sampled at the atlas UVs, and without the optional groups: equal to
    the torch model too."""
    a = synthetic_arrays(seed=1)
    g = np.random.default_rng(3)
    lean = {k: v for k, v in a.items()
            if not k.startswith(("expr_", "pose_", "larynx_"))}
    for arrays in (a, lean):
        tm, nm = HackModel(arrays), PosingModel(arrays)
        for _ in range(4):
            kw = {"beta": g.normal(size=nm.num_shape).astype(np.float32),
                  "psi": g.uniform(0, 1, nm.num_expressions).astype(np.float32),
                  "theta": g.normal(scale=0.3, size=(8, 3)).astype(np.float32),
                  "tau": np.float32(g.uniform(-0.02, 0.03))}
            assert np.abs(nm.vertices(**kw) - _torch_vertices(tm, kw)).max() < 2e-6


def test_05_inputs_and_limit_policy_equal_torch(models, monkeypatch):
    """A parameter mapping (expression names and AUs, a head rotation beyond the neck's
    range, theta beyond a joint's limit, eta and tau beyond theirs, beta beyond +-5) gives
    the same inputs, warnings, clamped values and errors as the torch path."""
    torch_model, np_model = models
    p = {"beta": [6.0, -1.0], "expression": {"AU12": 0.7, "jawOpen": 0.3},
         "head_rotation_deg": [10.0, 95.0, -5.0], "theta": [[0.0, 0.0, 0.3]] + [[0.0] * 3] * 7,
         "eta": 1.8, "tau": 0.03, "transl": [0.0, 0.01, 0.0]}
    for policy in ("warn", "clamp"):
        out = {}
        for name, kw in (("np", np_model.inputs(p)), ("torch", model_inputs(torch_model, p))):
            msgs = []
            monkeypatch.setattr("typer.secho", lambda text, _m=msgs, **_: _m.append(text))
            out[name] = (apply_limit_policy(kw, LimitPolicy(policy), p["head_rotation_deg"]),
                         msgs)
        (a, ma), (b, mb) = out["np"], out["torch"]
        assert sorted(a) == sorted(b) and ma == mb and len(ma) == 1
        b = {k: np.asarray(v)[0] for k, v in b.items()}  # the torch inputs' batch of one
        for k in a:
            assert np.allclose(a[k], b[k], atol=1e-6), (policy, k)
        assert np.abs(np_model.vertices(**a) - _torch_vertices(torch_model, b)).max() < 2e-6
    errors = []
    for kw in (np_model.inputs(p), model_inputs(torch_model, p)):
        with pytest.raises(HackError, match="outside the plausible identities") as err:
            apply_limit_policy(kw, LimitPolicy("error"), p["head_rotation_deg"])
        errors.append(str(err.value))
        kw["beta"] = kw["beta"] * 0
        with pytest.raises(HackError, match="outside the anatomical limits: head rotation "
                           "axial rotation .*larynx tau") as err:
            apply_limit_policy(kw, LimitPolicy("error"), p["head_rotation_deg"])
        errors.append(str(err.value))
    assert errors[:2] == errors[2:]
    for bad, match in (({"expression": {"AU11": 1.0}}, "nasolabial"),
                       ({"expression": {"jawopen": 1.0}}, "Did you mean 'jawOpen'"),
                       ({"beta": [0.0] * 101}, "101 values given"),
                       ({"psi": [0.0] * 3}, "expected 53 values")):
        for fn in (np_model.inputs, lambda q: model_inputs(torch_model, q)):
            with pytest.raises(HackError, match=match):
                fn(bad)


def test_06_mesh_command_poses_without_torch(tmp_path, models):
    """`hack-render mesh` in a fresh process, caches off: no torch import, and the OBJ
    holds the torch model's vertices for the same flags."""
    from hack_render.geometry.obj_io import read_obj

    out = tmp_path / "m.obj"
    code = ("import sys\nfrom hack_render.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code\n"
            "print('torch' in sys.modules)")
    env = {**os.environ, "HACK_RENDER_NO_CACHE": "1"}
    flags = ["--expr", "AU12=0.8", "--head-rotation", "-20,35,10", "--beta", "1,-0.5",
             "--tau", "0.01"]
    res = subprocess.run([sys.executable, "-c", code, "mesh", "-o", str(out), *flags],
                         capture_output=True, text=True, env=env, check=True)
    assert res.stdout.strip().splitlines()[-1] == "False"
    torch_model = models[0]
    from hack_render.geometry.params import gather_params

    p = gather_params(None, "1,-0.5", "AU12=0.8", "-20,35,10", None, 0.01)
    kw = apply_limit_policy(model_inputs(torch_model, p), LimitPolicy("warn"),
                            p["head_rotation_deg"])
    ref = _torch_vertices(torch_model, {k: np.asarray(v)[0] for k, v in kw.items()})
    assert np.abs(read_obj(out).vertices - ref).max() < 2e-6
