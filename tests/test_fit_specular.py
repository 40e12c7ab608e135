"""The skin's specular intensity from the photo's highlights (hack_render/fit/specular_bake.py):
the dichromatic split per pixel, and a known specular map recovered where the photo's
highlights identify it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest


def _pixels(k_true: float, diffuse_rgb, seed: int = 0):
    """A 64 x 64 patch: a shaded diffuse skin, a white highlight in the middle (its
    contribution at the fitted map ``g``), the photo with the highlight ``k_true`` times it
    and the skin 10 % brighter than fitted, 0.2 % noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:64, 0:64]
    shade = 0.6 + 0.4 * np.cos((xx - 32) / 40.0)
    rgb0 = shade[..., None] * np.asarray(diffuse_rgb)[None, None]
    blob = np.exp(-((xx - 32) ** 2 + (yy - 32) ** 2) / (2 * 6.0 ** 2))
    g = 0.08 * blob[..., None] * np.ones(3)
    photo = 1.1 * rgb0 + k_true * g + rng.normal(0, 0.002, rgb0.shape)
    return photo, rgb0 + g, rgb0, blob


def test_01_gain_is_recovered_where_the_highlight_is_and_unweighted_elsewhere():
    from hack_render.fit.specular_bake import gain_observations

    for k_true in (0.5, 2.0):
        photo, rgb, rgb0, blob = _pixels(k_true, (0.45, 0.25, 0.15))
        k, w = gain_observations(photo, rgb, rgb0, np.ones(blob.shape), 16.0)
        core = blob > 0.6
        # (the pull towards 1 holds at most a tenth of the way)
        assert np.abs(np.median(k[core]) - k_true) < 0.1, (k_true, np.median(k[core]))
        assert w[core].min() > 0.3
        assert w[blob < 0.01].max() < 0.02        # no highlight: nothing to say
    # a white skin: the highlight has its colour, the split is not identified
    photo, rgb, rgb0, blob = _pixels(2.0, (0.5, 0.5, 0.5))
    _, w = gain_observations(photo, rgb, rgb0, np.ones(blob.shape), 16.0)
    assert w.max() < 1e-3
    # pixels the bake does not take count 0
    photo, rgb, rgb0, blob = _pixels(2.0, (0.45, 0.25, 0.15))
    _, w = gain_observations(photo, rgb, rgb0, np.zeros(blob.shape), 16.0)
    assert w.max() == 0.0


def test_02_a_known_specular_map_is_recovered_where_the_photo_identifies_it(tmp_path):
    pytest.importorskip("mitsuba")
    import torch
    from synthetic import photo_of, texture_fitter

    from hack_render.fit import texture
    from hack_render.fit.bake_weights import pixel_weights
    from hack_render.fit.specular_bake import bake_specular
    from hack_render.geometry import load_default_model

    model = load_default_model()
    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=20.0)
    v = f.state.views[0]
    # a dim environment and a bright lobe from above the camera: highlights on the face
    d = torch.tensor([0.0, 0.35, 1.0])
    d = d / d.norm()
    with torch.no_grad():
        lobe = torch.exp(12.0 * ((v.lighting.dirs * d).sum(-1) - 1.0))
        v.lighting.log_texels.copy_(torch.log(0.25 + 6.0 * lobe)[..., None].expand(-1, -1, 3))
    fitted = texture._skin_maps(f.state, cfg.final.atlas_height)
    truth = np.clip(fitted.specular * 2.0, 0, 1).astype(np.float32)   # twice as glossy
    shot = texture.render_at_photo(f.state, cfg, v,
                                   maps=dataclasses.replace(true_maps, specular=truth))
    v.photo = photo_of(shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5)
    pr = texture.render_at_photo(f.state, cfg, v, maps=dataclasses.replace(
        true_maps, specular=fitted.specular))
    m0 = dataclasses.replace(true_maps, specular=np.zeros_like(fitted.specular))
    pr0 = texture.render_at_photo(f.state, cfg, v, maps=m0)
    wgt, _ = pixel_weights(v, pr, cfg)
    spec, conf, rep = bake_specular(f.state, cfg, [pr], [pr0], [wgt], fitted.specular)
    assert spec.shape == fitted.specular.shape and conf.shape == spec.shape[:2]
    sure = conf > 0.5
    # the gains, per region of the face (a 16-row atlas), are known on most of it (83 %)
    assert sure.sum() > 5000 and rep["identified_fraction"] > 0.5, (sure.sum(), rep)
    err_fitted = np.abs(fitted.specular - truth)[sure].mean()
    err_baked = np.abs(spec - truth)[sure].mean()
    # there the map's error is 0.81 of the fitted map's (0.288 against 0.358): the skin's
    # colour absorbs part of the sheen, which is everywhere (the module's docstring)
    assert err_baked < 0.9 * err_fitted, (err_baked, err_fitted)
    # where the photo says nothing the fitted map stays
    none = conf == 0
    assert none.any()
    np.testing.assert_allclose(spec[none], fitted.specular[none], atol=1e-6)
    # (measured 1.11; the truth is twice the fitted map clipped at 1: 1.5 in the median
    # over the highlights' pixels, the true over the fitted specular contribution)
    assert 1.05 < rep["median_gain"] < 2.0, rep
    # the fit's final stage with final.specular: the map, its confidence, the report
    from hack_render.fit import final as final_stage
    from hack_render.fit import outputs

    cfg.final.specular = True
    final = final_stage.run(f.state, f.cfg)
    rep = final.report["specular"]
    assert rep["identified_fraction"] > 0.5 and rep["median_gain"] > 1.0, rep
    sure = final.specular_confidence > 0.5
    assert np.abs(final.maps.specular - fitted.specular)[sure].mean() > 0.02
    written = outputs.write_textures(f.state, tmp_path / "textures", final)
    assert tmp_path / "textures" / "specular_confidence.exr" in written
    # final.specular off (the default): the fitted map, no confidence; asserted on the
    # final stage that tests/test_fit_eyes.py test_01 runs anyway (a second final stage
    # here was a quarter of this test's time)
