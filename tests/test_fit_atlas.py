"""Photo pixels into the skin atlas (hack_render/fit/atlas.py): the splat by footprint
band, the fallback map tone-matched to the bake, and the wide Gaussian they use. No
renders: arrays made here."""

from __future__ import annotations

import numpy as np


def test_09_fallback_skin_is_tone_matched_without_a_seam():
    """atlas.tone_matched_prior: A(alpha) where the photo does not see takes the baked
    skin's tone through a smooth gain field, so the face does not end in a seam; far from
    the face one gain (the seen texels' median) holds, on both UV tiles; the holes the
    seen texels enclose (eyes, mouth) keep A(alpha) unless asked."""
    from hack_render.fit.atlas import tone_matched_prior

    H = 128
    prior = np.broadcast_to(np.float64([0.50, 0.30, 0.30]), (H, 2 * H, 3)).copy()
    yy, xx = np.mgrid[0:H, 0:2 * H]
    r = np.hypot(yy - H / 2, xx - H / 2)
    seen = (r < 30) & ~(np.hypot(yy - H / 2, xx - H / 2 + 12) < 5)   # a face with an eye hole
    hole = np.hypot(yy - H / 2, xx - H / 2 + 12) < 4
    # the photo's skin: beige, a little darker on one side (its tone varies)
    photo = np.float64([0.60, 0.45, 0.33]) * np.where(xx < H / 2, 1.1, 0.9)[..., None]
    photo = np.where(seen[..., None], photo, 0.0)
    out = tone_matched_prior(prior, photo, seen.astype(float))
    ring = (r > 31) & (r < 34)      # just outside the face
    err_before = np.abs(np.log(prior[ring]) - np.log(photo[(r > 27) & (r < 29) & seen].mean(0)))
    err_after = np.abs(np.log(out[ring]) - np.log(photo[(r > 27) & (r < 29) & seen].mean(0)))
    assert err_after.mean() < 0.35 * err_before.mean(), (err_after.mean(), err_before.mean())
    # the seam's step in log colour across the face's edge: a fraction of the old one
    step = np.abs(np.diff(np.log(np.where(seen[..., None], photo, out)), axis=1))
    edge = seen[:, 1:] != seen[:, :-1]
    old = np.abs(np.diff(np.log(np.where(seen[..., None], photo, prior)), axis=1))
    assert np.median(step[edge]) < 0.35 * np.median(old[edge])
    # far away and on the other tile: one gain, the median's
    far = out[5:20, H + 20:2 * H - 20].reshape(-1, 3)
    assert np.ptp(far, axis=0).max() < 1e-6
    g0 = np.median(np.log(photo[seen]) - np.log(prior[seen]), axis=0)
    np.testing.assert_allclose(far[0], prior[0, 0] * np.exp(g0), rtol=1e-6)
    # the eye hole keeps A(alpha) ("outside"), or is tone-matched too ("all")
    np.testing.assert_array_equal(out[hole], prior[hole])
    inside = tone_matched_prior(prior, photo, seen.astype(float), inside=True)
    assert np.abs(np.log(inside[hole]) - np.log(photo[seen].mean(0))).mean() < 0.15
    # almost nothing seen: A(alpha) as it is
    few = np.zeros_like(seen)
    few[0, :8] = True
    assert tone_matched_prior(prior, photo, few.astype(float)) is prior


def test_unseen_skin_continues_the_face_colour_not_the_prior_tone():
    """A(alpha)'s neck is lighter than its face (1.4x on Grace Hopper's fit): the unseen
    skin far from the face takes the seen skin's median colour over the prior's own
    smooth tone there, so it continues the face's colour (before: 1.4x lighter), and
    keeps the prior's fine detail (a pattern of a few texels)."""
    from hack_render.fit.atlas import tone_matched_prior

    H = 128
    yy, xx = np.mgrid[0:H, 0:2 * H]
    detail = 1.0 + 0.1 * np.sign(np.sin(xx / 1.5) * np.sin(yy / 1.5))
    # the prior: its "face" (left tile) one tone, its "neck" (right tile) 1.4x lighter
    tone = np.where(xx < H, 1.0, 1.4)[..., None] * np.float64([0.30, 0.20, 0.15])
    prior = tone * detail[..., None]
    seen = np.hypot(yy - H / 2, xx - H / 2) < 30
    photo = np.where(seen[..., None], np.float64([0.40, 0.22, 0.12]), 0.0)
    out = tone_matched_prior(prior, photo, seen.astype(float))
    far = (xx > H + 30) & (xx < 2 * H - 30) & (yy > 30) & (yy < H - 30)
    # its smooth colour: the seen skin's (within 3 %), not 1.4x that
    ratio = np.exp(np.log(out[far]).mean(0)) / np.exp(np.log(photo[seen]).mean(0))
    np.testing.assert_allclose(ratio, 1.0, atol=0.03)
    # its detail: the prior's (a +-10 % pattern; the gain over it varies by 0.14 %)
    rel = out[far] / prior[far]
    assert np.ptp(rel, axis=0).max() < 0.01 * rel.mean()


def test_17_the_splat_filters_each_band_in_its_box_exactly(monkeypatch):
    """``atlas.splat`` filters each footprint band only in its samples' box grown by
    twice the kernel's reach: bit for bit what filtering the whole atlas gives, with
    samples at the atlas's corners and edges (where the filter reflects) and inside, and
    footprints over several bands (on obama_speech's bake 6.6 -> 1.5 s, measured)."""
    from hack_render.fit import atlas

    rng = np.random.default_rng(17)
    H, n = 64, 400
    xs = np.concatenate([rng.uniform(0, 3, 50), rng.uniform(2 * H - 3, 2 * H - 1, 50),
                         rng.uniform(40, 60, n - 100)])
    ys = np.concatenate([rng.uniform(0, 3, 50), rng.uniform(H - 3, H - 1, 50),
                         rng.uniform(20, 30, n - 100)])
    ws = rng.uniform(0.1, 1.0, n)
    obs = rng.uniform(0, 1, (n, 3))
    # the median footprint's band at the corners and inside (its box the whole atlas);
    # wider bands inside only (their boxes cropped)
    foot = np.ones(n)
    foot[100:] = np.where(rng.uniform(size=n - 100) < 0.4, rng.uniform(2.0, 7.0, n - 100), 1.0)
    foot[::37] = np.nan
    samples = [(xs, ys, ws, obs, foot), None]
    got = atlas.splat(samples, H)
    full = (slice(None), slice(None))
    monkeypatch.setattr(atlas, "_grown_box", lambda mask, grow: full)
    want = atlas.splat(samples, H)
    for g, w in zip(got[:2], want[:2]):
        np.testing.assert_array_equal(g, w)
    assert got[2] == want[2]
    assert (got[1] > 0).any() and (got[1][:4, :4] > 0).any() and (got[1][-4:, -4:] > 0).any()


def test_wide_gaussian_is_scipys_constant_mode_gaussian():
    """atlas.wide_gaussian (FFT, one axis at a time) equals scipy's gaussian_filter with
    mode="constant" (the tone match's blur before) to float64 rounding, at the atlas's
    edges and beyond the kernel's reach too, for narrow and wide kernels."""
    from scipy.ndimage import gaussian_filter

    from hack_render.fit.atlas import wide_gaussian

    rng = np.random.default_rng(7)
    x = rng.random((96, 192))
    x[:, 150:] = 0.0                      # far from any input: 0 (scipy) or ~1e-18
    x[0, 0] = x[-1, -1] = 3.0             # the corners
    for sigma in (0.7, 3.0, 11.3):
        got, want = wide_gaussian(x, sigma), gaussian_filter(x, sigma, mode="constant")
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    assert np.abs(wide_gaussian(x, 3.0)[:80, 170:]).max() < 1e-15   # (away from the corner)


def test_the_splat_sums_each_samples_four_corners(monkeypatch):
    """``atlas.splat``'s sums per texel (the filters made the identity): each sample's
    weight, area and observation go to its four bilinear corners, clamped at the atlas's
    edges, as an independent ``np.add.at`` over the corners gives them (several samples
    per texel, samples on the edges, NaN footprints)."""
    import scipy.ndimage

    from hack_render.fit import atlas

    monkeypatch.setattr(scipy.ndimage, "gaussian_filter", lambda a, sigma, **kw: a)
    rng = np.random.default_rng(5)
    H, n = 16, 300
    xs = np.concatenate([rng.uniform(-0.5, 2 * H - 0.5, n - 20), np.full(20, 2 * H - 0.6)])
    ys = np.concatenate([rng.uniform(-0.5, H - 0.5, n - 20), rng.uniform(0, 3, 20)])
    ws = rng.uniform(0.1, 1.0, n)
    obs = rng.uniform(0, 1, (n, 3))
    foot = rng.uniform(0.5, 6.0, n)
    foot[::17] = np.nan
    got_obs, got_dens, fp = atlas.splat([(xs, ys, ws, obs, foot)], H)
    assert fp == np.median(foot[np.isfinite(foot)])
    rel = np.clip(np.nan_to_num(foot, nan=fp) / fp, 1.0,
                  atlas.FOOTPRINT_STEP ** atlas.FOOTPRINT_BANDS)
    den = np.zeros((H, 2 * H))
    area = np.zeros((H, 2 * H))
    num = np.zeros((H, 2 * H, 3))
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for ox, oy, k in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                      (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        at = (np.clip(y0 + oy, 0, H - 1), np.clip(x0 + ox, 0, 2 * H - 1))
        np.add.at(den, at, ws * k)
        np.add.at(area, at, ws * k * rel * rel)
        np.add.at(num, at, (ws * k)[:, None] * obs)
    seen = den > 1e-8
    np.testing.assert_allclose(got_dens, area, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got_obs[seen], num[seen] / den[seen][:, None], rtol=1e-4,
                               atol=1e-5)
    assert (got_obs[~seen] == 0).all() and seen.sum() > 200
