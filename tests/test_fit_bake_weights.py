"""Which photo pixels the bake takes (hack_render/fit/bake_weights.py, through
texture.bake_diffuse): occluders and their margin, their shadow on the skin, the
segmentation's edges against the render's silhouette, hair strands across the skin, a
smile's dark mouth corners. Synthetic photos of the default model (tests/synthetic.py)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from synthetic import frontal_truth_photo, photo_of, texture_fitter


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


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


def test_14_the_segmentations_edges_are_not_eroded_the_renders_silhouette_is(model):
    """bake_weights.EDGE_PX drops the pixels next to the render's silhouette (the skin's edge
    there mixes in the background), not those next to the segmentation's occluders: a
    crease or a frame left out of the bake keeps the skin beside it, which is the
    photo's skin (eroding it as well had left a 2-pixel band of A(alpha) around every
    one of Grace Hopper's creases)."""
    from scipy.ndimage import binary_dilation, binary_erosion

    from hack_render.fit import bake_weights, texture

    f, cfg, _, _, _, _ = frontal_truth_photo(model)
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
