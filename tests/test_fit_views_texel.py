"""Multi-view fitting (shared beta across views, own camera and pose per view) and the
per-texel albedo refinement (stage 5) on synthetic subjects with known truth."""

import warnings

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")


def _landmark_view(model, beta, yaw_deg):
    from synthetic import landmark_view

    return landmark_view(model, beta=beta, angles_deg=(5.0, yaw_deg, 0.0),
                         name=f"yaw{yaw_deg:+.0f}")


def test_01_two_views_recover_shared_shape_better_than_either_alone():
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.metrics import similarity_error
    from hack_render.geometry import load_default_model

    torch.set_num_threads(1)
    model = load_default_model()
    beta = torch.randn(1, 20, generator=torch.Generator().manual_seed(0))
    views = [_landmark_view(model, beta, 35.0), _landmark_view(model, beta, -35.0)]
    with torch.no_grad():
        truth = model(beta=beta).vertices[0][:9409].numpy()
    # noiseless landmarks: weaker priors than the defaults, which are set against dlib's
    # scatter (with those the prior, not the views, decides the shape)
    # silhouette off: the blank photos hold no person to segment (the fit is the same,
    # bit for bit, without the segmentation's ~10 s per fitter)
    cfg = load_config(None, {"camera": {"iterations": 80},
                             "shape": {"iterations": 100, "n_beta": 20, "w_beta": 0.02,
                                       "w_psi": 0.02, "psi_prior": "l2"},
                             "silhouette": {"mode": "off"}})

    def fit(vs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = Fitter([v[0] for v in vs], [v[1] for v in vs], cfg, model=model,
                       appearance=None, progress=False)
            f.fit_camera()
            f.fit_shape()
        with torch.no_grad():
            rest = model(beta=f.state.beta.detach()).vertices[0][:9409].numpy()
        return f, 1000 * similarity_error(rest, truth)  # identity (rest shape) error, mm

    _, err_a = fit(views[:1])
    _, err_b = fit(views[1:])
    both, err_ab = fit(views)
    # one beta for both photos, pinned down by two viewpoints: better than either alone
    assert err_ab < min(err_a, err_b), (err_a, err_b, err_ab)
    assert both.state.beta.shape == (1, 20) and len(both.state.views) == 2
    # each view keeps its own neck pose: per-joint angles recovered per view (the bench's
    # neck joint error: mean over the 8 joints and 3 Euler angles), opposite yaws
    from hack_render.geometry.rotations import axis_angle_to_euler
    from hack_render.geometry.skeleton import distribute_head_rotation

    for v, yaw in zip(both.state.views, (35.0, -35.0)):
        true = distribute_head_rotation(torch.deg2rad(torch.tensor([5.0, yaw, 0.0])))
        fit_ = both.theta(v).detach()[0]
        err = torch.rad2deg((axis_angle_to_euler(fit_) - axis_angle_to_euler(true)).abs()).mean()
        assert float(err) < 1.0, (yaw, float(err))
        assert float(fit_[:, 1].sum()) * yaw > 0
    # and both views' landmarks fit (normalised by the inter-ocular distance)
    for v in both.state.views:
        with torch.no_grad():
            pred = both.project(v, both.forward(v).landmarks[0]).numpy()
        tgt = v.detection.points
        nme = np.linalg.norm(pred - tgt, axis=1).mean() / np.linalg.norm(tgt[36] - tgt[45])
        assert nme < 0.03, (v.photo.name, nme)


def test_02_texel_refinement_lowers_photo_loss_and_obeys_regularisers(monkeypatch):
    import colour
    from synthetic import synthetic_target

    from hack_render.fit import photometric as ph
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import Photo
    from hack_render.fit.robust import charbonnier
    from hack_render.geometry import load_default_model
    from hack_render.vision.detection import Detection

    torch.set_num_threads(1)
    model = load_default_model()
    img, lm, _ = synthetic_target(model, res=96)
    srgb = np.clip(colour.cctf_encoding(np.clip(img, 0, 1), function="sRGB"), 0, 1)
    photo = Photo(srgb.astype(np.float32), "synthetic")
    det = Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth")
    cfg = load_config(None, {"camera": {"iterations": 40},
                             "shape": {"iterations": 40, "n_beta": 10},
                             "photometric": {"resolutions": [64], "iterations": [3], "spp": 4,
                                             "n_alpha": 4},
                             "texel": {"enabled": True, "iterations": 12, "lr": 0.005,
                                       "w_smooth": 20.0, "w_symmetry": 20.0}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = Fitter([photo], [det], cfg, model=model, progress=False)
        if f.state.appearance is None:
            pytest.skip("the appearance model is not available")
        f.fit_camera()
        f.fit_shape()
        f.photometric(texel=False)
    # photometric.PSI_LR_SCALE 0: the photometric stage refines the identity and pose but
    # leaves the expressions where the landmark stages put them
    f.cfg.photometric.iterations = [8]
    moved = {}
    for scale in (1.0, 0.0):
        monkeypatch.setattr(ph, "PSI_LR_SCALE", scale)
        before = [x.detach().clone() for x in (f.state.psi, f.state.beta, f.state.alpha)]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f.photometric(texel=False)
        moved[scale] = [float((x.detach() - b).abs().max())
                        for x, b in zip((f.state.psi, f.state.beta, f.state.alpha), before)]
    # the stage kept a later iterate both times (beta and alpha moved); psi only with 1
    assert min(moved[1.0]) > 0.0 and moved[0.0][0] == 0.0, moved
    assert moved[0.0][1] > 0.0 and moved[0.0][2] > 0.0, moved
    f.cfg.photometric.iterations = [3]
    v = f.state.views[0]
    # the texel stage renders the full atlas (the photometric stage a coarser mip): the
    # before/after losses below are both taken on the texel stage's scene
    ph.setup_level(f.state, f.cfg, v, int(cfg.photometric.resolutions[-1]), full_maps=True)

    def photo_loss():
        """Masked Charbonnier at 16 spp over two fixed sample patterns (not the stage's)."""
        with torch.no_grad():
            maps, verts = ph.level_maps(f.state, v), f.forward(v).vertices[0]
            m = v.level.mask
            out = 0.0
            for seed in (11, 12):
                im = v.renderer.render(seed=seed, spp=16, vertices=verts, albedo=maps["albedo"],
                                       specular=maps["specular"], roughness=maps["roughness"],
                                       normal=maps["normal"], env=v.lighting.env_map())[..., :3]
                d = charbonnier(im - v.level.target, ph.CHARBONNIER_EPS)
                out += float((d * m[..., None]).sum() / (3 * m.sum())) / 2
        return out

    pairs = ph.symmetry_pairs(model)
    frozen = [x.detach().clone() for x in (f.state.beta, f.state.psi, f.state.alpha, v.head_angles)]
    before = photo_loss()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f.photometric(texel=True)
    regularised = photo_loss()
    reg = {k: float(x) for k, x in ph.texel_regularisers(f.state.albedo_delta.detach(), pairs).items()}
    # the texel stage moves the albedo only: geometry, expression, PCA alpha, pose frozen
    for a, b in zip(frozen, (f.state.beta, f.state.psi, f.state.alpha, v.head_angles)):
        assert torch.equal(a, b.detach())
    assert float(f.state.albedo_delta.detach().abs().max()) > 0.0
    assert regularised < 0.9 * before, (before, regularised)

    # the same stage without the smoothness and symmetry terms: a rougher, less symmetric
    # delta, so the regularisers are what keeps it smooth and mirror-symmetric
    f.cfg.texel.w_smooth = f.cfg.texel.w_symmetry = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f.photometric(texel=True)
    free = {k: float(x) for k, x in ph.texel_regularisers(f.state.albedo_delta.detach(), pairs).items()}
    assert reg["smooth"] < 0.5 * free["smooth"], (reg, free)
    assert reg["symmetry"] < 0.5 * free["symmetry"], (reg, free)


def test_03_similarity_error_ignores_similarity_only():
    from hack_render.fit.metrics import similarity_error

    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))  # a rotation, not a reflection
    y = 1.7 * x @ q.T + np.array([0.1, -2.0, 3.0])
    assert similarity_error(x, y) < 1e-9
    bent = y.copy()
    bent[:, 2] += 0.05 * y[:, 0] ** 2  # a non-rigid change stays measurable
    assert similarity_error(x, bent) > 1e-3
    mirrored = x * np.array([-1.0, 1.0, 1.0])  # a reflection is not a similarity
    assert similarity_error(x, mirrored) > 0.1
