"""`hack-render track`'s larynx stage (``track/larynx.py``): the slid meshes against full
forwards, the robust shading fit, the least-cost slide path and the skin albedo over the
larynx chart."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hack_render.geometry import load_default_model
from hack_render.geometry.skeleton import distribute_head_rotation


@pytest.fixture(scope="module")
def model():
    return load_default_model()


def test_09_slid_meshes_equal_full_forwards(model):
    """The photometric tau's meshes (one forward, the other slides' larynx displacements
    posed by the joints' blended rotations) equal full forwards at each slide, for a
    turned, tilted head with a torso turn, a translation and an expression."""
    from hack_render.track.larynx import slid_meshes
    from hack_render.track.solve import FrameParams

    g = torch.Generator().manual_seed(5)
    beta = torch.randn(1, 20, generator=g)
    h = np.array([[0.3, -0.6, 0.2]])
    params = FrameParams(h, np.array([[0.05, 0.1, -0.03]]), np.array([[0.01, -0.02, 0.03]]),
                         np.clip(torch.rand(1, 53, generator=g).numpy() - 0.7, 0, 1))
    theta = distribute_head_rotation(torch.as_tensor(h), clamp=False).float()
    taus = torch.tensor([-0.01, 0.0, 0.007, 0.02])
    d_tau = model.larynx_displacement(beta.expand(4, -1), torch.full((4,), 1.2), taus)
    V = slid_meshes(model, model.personalize(beta), params, theta, 0, 1.2, taus, d_tau)
    with torch.no_grad():
        want = model(beta=beta.expand(4, -1), psi=torch.as_tensor(params.psi).float().expand(4, -1),
                     theta=theta.expand(4, -1, -1),
                     global_orient=torch.as_tensor(params.g).float().expand(4, -1),
                     transl=torch.as_tensor(params.t).float().expand(4, -1),
                     eta=torch.full((4,), 1.2), tau=taus).vertices
    assert float((want[3] - want[0]).abs().max()) > 3e-3  # the slide moves the skin
    assert float((V - want).abs().max()) < 1e-6


def test_10_robust_shading_fit_ignores_shadows():
    """Luminance made by the shading model from random normals, with a fifth of the
    pixels darkened as by a cast shadow: the robust fit's residual is ~0 on the rest
    (a plain least-squares fit is not)."""
    from hack_render.track.larynx import robust_shading_fit, shading_basis

    rng = np.random.default_rng(0)
    n = rng.normal(size=(3000, 3)) + [0, 0, 2.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    view = np.tile([0.0, 0.0, 1.0], (3000, 1))
    A = shading_basis(n, view)
    assert A.shape == (3000, 17)
    b = A @ rng.normal(size=17) * 0.05 + 0.5
    shadow = rng.random(3000) < 0.2
    b_obs = np.where(shadow, 0.3 * b, b)
    r, _ = robust_shading_fit(A, b_obs, 6)
    assert np.abs(r[~shadow]).max() < 1e-3, np.abs(r[~shadow]).max()
    r_ls, _ = robust_shading_fit(A, b_obs, 1)  # one round: plain least squares
    assert np.abs(r_ls[~shadow]).max() > 0.02


def test_11_smooth_path_follows_the_curves_without_lag():
    """Cost curves whose minima trace a known swallow, with noise and frames whose curve
    is flat (no cue) or missing: the least-cost path follows the truth within 1.5 mm and
    is best aligned at zero shift (no lag)."""
    from hack_render.track.larynx import LarynxTrackConfig, smooth_path

    cfg = LarynxTrackConfig()
    grid = np.linspace(-0.01, 0.02, 13)
    T, fps = 48, 24.0
    t = np.arange(T)
    truth = 0.016 * np.exp(-0.5 * ((t - 24) / 5.0) ** 2)
    rng = np.random.default_rng(1)
    cost = 40 * (grid[None] - truth[:, None]) ** 2 / 0.01 + 0.02 * rng.random((T, 13))
    cost[10:14] = 0.01 * rng.random((4, 13))   # flat: the light tells nothing there
    cost[30] = np.nan                          # a lost frame
    path = smooth_path(cost, grid, fps, cfg)
    assert np.abs(path - truth).max() < 0.0015, np.abs(path - truth).max()
    err = [np.abs(np.roll(path, k) - truth)[5:-5].mean() for k in (-2, -1, 0, 1, 2)]
    assert int(np.argmin(err)) == 2, err


def test_12_skin_albedo_is_the_robust_ratio_over_the_chart(model):
    """The albedo map over the larynx chart gives back a mole's darkening from ratios of
    luminance over shading, ignores points of zero weight, and is 1 (relative) elsewhere."""
    from hack_render.track.larynx import SkinAlbedo, _Region

    region = _Region(model)
    alb = SkinAlbedo(region)
    rng = np.random.default_rng(2)
    chart = region.chart[region.larynx_vertices]
    lo, hi = chart.min(0), chart.max(0)
    pts = lo + rng.random((20000, 2)) * (hi - lo)
    mole = np.linalg.norm(pts - (lo + hi) / 2, axis=1) < 0.003
    ratio = np.where(mole, 0.6, 1.0) * (1 + 0.02 * rng.normal(size=len(pts)))
    w = np.ones(len(pts))
    w[:500] = 0.0
    ratio[:500] = 50.0  # a shadow's outliers, weighted out
    alb.add(pts, ratio, w)
    got = alb(pts[500:])
    far = np.linalg.norm(pts[500:] - (lo + hi) / 2, axis=1) > 0.006
    assert abs(np.median(got[far]) - 1.0) < 0.03
    near = np.linalg.norm(pts[500:] - (lo + hi) / 2, axis=1) < 0.002
    assert abs(np.median(got[near]) - 0.6) < 0.04
