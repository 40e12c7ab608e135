"""The photometric stage's "sg" lighting: order-2 SH plus spherical-Gaussian lobes, and
their start from the photo (photometric.init_lobes)."""

import copy
import math
import warnings

import numpy as np
import pytest
import torch


def test_01_lobe_map_peak_sharpness_and_direction_gradient():
    from hack_render.fit.lighting import Lighting, candidate_directions, max_sharpness

    L = Lighting("sg", height=32, lobes=1)
    d = torch.tensor([-0.6, 0.3, 0.74])
    with torch.no_grad():
        L.lobe_dir[0] = d
        L.lobe_log_sharpness[0] = math.log(40.0)
        L.lobe_log_amplitude[0] = torch.log(torch.tensor([2.0, 3.0, 4.0]))
        L.coeffs.zero_()
    env = L.env_map()
    assert env.shape == (32, 64, 3) and bool((env >= 0).all())
    # the brightest texel looks along the lobe's direction (within a texel, pi / 32)
    i = int(env[..., 2].argmax())
    peak = L.dirs.reshape(-1, 3)[i]
    ang = math.acos(float(peak @ d / d.norm()))
    assert ang < math.pi / 32, math.degrees(ang)
    # its radiance: amplitude * exp(lambda (cos - 1)) over the SH's soft floor (zero SH:
    # softplus(0) / 20)
    rgb = env.reshape(-1, 3)[i].detach()
    want = torch.tensor([2.0, 3.0, 4.0]) * math.exp(40.0 * (math.cos(ang) - 1.0)) \
        + math.log(2.0) / 20.0
    assert torch.allclose(rgb, want, rtol=1e-4), (rgb, want)
    # sharpness is capped where the map can no longer resolve the lobe
    with torch.no_grad():
        L.lobe_log_sharpness[0] = math.log(1e6)
    assert float(L.sharpness()[0].detach()) == pytest.approx(max_sharpness(32))
    with torch.no_grad():
        L.lobe_log_sharpness[0] = math.log(40.0)
    # d(sum of w * env) / d(direction): autograd against central differences, in float64
    # (in float32 the differences of a sum over 6,144 texels carried rounding of 2 % on
    # one machine and not on another)
    L64 = copy.deepcopy(L).double()
    w = torch.rand(32, 64, 3, generator=torch.Generator().manual_seed(0)).double()
    f = (L64.env_map() * w).sum()
    (g,) = torch.autograd.grad(f, L64.lobe_dir)
    for k in range(3):
        h = 1e-4
        with torch.no_grad():
            L64.lobe_dir[0, k] += h
            fp = float((L64.env_map() * w).sum())
            L64.lobe_dir[0, k] -= 2 * h
            fm = float((L64.env_map() * w).sum())
            L64.lobe_dir[0, k] += h
        assert float(g[0, k]) == pytest.approx((fp - fm) / (2 * h), rel=1e-3, abs=1e-4)
    # the candidates cover the sphere: every direction within 30 degrees of one
    c = candidate_directions(32)
    assert np.allclose(np.linalg.norm(c, axis=1), 1.0)
    probe = np.random.default_rng(0).standard_normal((500, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    assert np.degrees(np.arccos((probe @ c.T).max(1).clip(-1, 1))).max() < 30.0


def _fitter(model, rig, res=80):
    import colour
    from synthetic import synthetic_target

    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import Photo
    from hack_render.vision.detection import Detection

    img, lm, _ = synthetic_target(model, res=res, rig=rig)
    srgb = np.clip(colour.cctf_encoding(np.clip(img, 0, 1), function="sRGB"), 0, 1)
    det = Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth")
    cfg = load_config(None, {"camera": {"iterations": 60},
                             "shape": {"iterations": 40, "n_beta": 10},
                             # the true landmarks place the head: no person segmentation
                             "silhouette": {"mode": "off"},
                             "photometric": {"lighting": "sg", "lobes": 1, "sg_height": 16,
                                             "spp": 4}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = Fitter([Photo(srgb.astype(np.float32), "synthetic")], [det], cfg, model=model,
                   progress=False)
        f.fit_camera()
        f.fit_shape()
    return f


def test_02_init_lobes_finds_the_window():
    pytest.importorskip("mitsuba")
    from hack_render.fit import photometric as ph
    from hack_render.geometry import load_default_model
    from scenes.lights import preset

    torch.set_num_threads(1)
    model = load_default_model()
    found = {}
    for name, rot in (("window", 30.0), ("light_stage", 0.0)):
        rig = preset(name, rotation_deg=rot)
        f = _fitter(model, rig)
        v = f.state.views[0]
        ph.setup_level(f.state, f.cfg, v, 48)
        rep = ph.init_lobes(f.state, f.cfg, v)
        assert len(rep) == 1
        found[name] = (rep[0], v.lighting.summary())
    # the window's centre as seen from the head, rotated with the rig about +Y
    light = preset("window", rotation_deg=30.0).area[0]
    a = math.radians(30.0)
    R = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    true_dir = R @ (np.asarray(light.position) - np.array([0.0, 0.0, 0.05]))
    true_dir /= np.linalg.norm(true_dir)
    rep, summ = found["window"]
    got = np.asarray(summ["lobe_direction"][0])
    assert np.degrees(math.acos(float(np.clip(got @ true_dir, -1, 1)))) < 35.0, (got, true_dir)
    # one lobe explains a large part of what a uniform light leaves in a window-lit
    # photo (0.58 of the residual is left since renders hide the lights from the camera
    # and use the multijitter sampler; 0.54 before)...
    assert rep["residual_after"] < 0.65 * rep["residual_before"], rep
    # ... and little of a uniformly lit one
    rep_ls = found["light_stage"][0]
    assert rep_ls["residual_after"] > 0.8 * rep_ls["residual_before"], rep_ls
