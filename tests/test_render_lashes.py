"""The lash cards: their UV layout, the procedural strand opacity texture, a close-up
render of the eye, and the label passes' agreement with the renderer's opacity."""

import numpy as np
import pytest

from hack_render.render.engine import ensure_variant

ensure_variant()

import drjit as dr
import mitsuba as mi

from hack_render.render import materials
from hack_render.render.aov import card_opacity
from hack_render.render.footprint import camera_hit
from hack_render.render.parts import REGIONS, Part, lash_cards, split_parts
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights


@pytest.fixture(scope="module")
def cards(head_model):
    topo, v = head_model
    parts, axes = split_parts(topo, v)
    lashes = next(p for p in parts if p.name == "eyelashes")
    return lash_cards(lashes, v, axes)


def eye_closeup(res: int) -> cameras.Camera:
    """A close-up of the left eye (model +x), from a little above: ~40 mm across."""
    R, t = cameras.look_at([0.036, 0.040, 0.200], [0.034, 0.033, 0.092])
    return cameras.Camera(cameras.intrinsics(res, res, 90.0), R, t, res, res, "eye")


def card_rows(card, size):
    """Texel rows of a card and their position t from root (0) to tip (1)."""
    _, _, v_root, v_tip = card
    centre = (np.arange(size) + 0.5) / size
    t = (centre - v_root) / (v_tip - v_root)
    return t


def test_01_lash_cards_from_the_model_uvs(head_model, cards):
    """ICT's lashes are 12 cards (3 layers x upper / lower lid x 2 eyes), each a UV
    rectangle; the root (lid margin) is at the lower Mitsuba v, found from the geometry."""
    assert cards.shape == (12, 4)
    u0, u1, root, tip = cards.T
    assert np.all(u1 - u0 > 0.4) and np.all(tip - root > 0.1)  # root below tip in v
    assert sorted(np.round(u0, 2)) == [0.01] * 6 + [0.51] * 6  # one eye per half of u
    # the rectangles do not overlap: every card has its own strands
    for i in range(12):
        for j in range(i):
            a, b = cards[i], cards[j]
            assert a[1] <= b[0] or b[1] <= a[0] or a[3] <= b[2] or b[3] <= a[2]


def test_02_degenerate_uvs_give_no_cards(head_model, cards):
    """Cards whose UVs collapse (no root-to-tip direction) give none: the scene then
    falls back to the uniform EYELASH_OPACITY."""
    topo, v = head_model
    parts, axes = split_parts(topo, v)
    lashes = next(p for p in parts if p.name == "eyelashes")
    flat = Part(lashes.name, lashes.region, lashes.gather, lashes.faces,
                np.full_like(lashes.texcoords, 0.5), lashes.model_uv)
    assert lash_cards(flat, v, axes).shape == (0, 4)
    # without eye axes the root is ICT's lower v: the same cards
    np.testing.assert_array_equal(lash_cards(lashes, v, []), cards)


def test_03_strand_texture(cards):
    """The texture is deterministic, in [0, 1], opaque at the roots, clear at the tips,
    between the strands and outside the cards; a card whose root is its upper v is drawn
    from that end."""
    size = materials.LASH_MAP_SIZE
    a = materials.lash_opacity_map(cards, size)
    assert a.shape == (size, size) and a.dtype == np.float32
    np.testing.assert_array_equal(a, materials.lash_opacity_map(cards, size))
    assert not np.array_equal(a, materials.lash_opacity_map(cards, size, seed=1))
    assert a.min() >= 0.0 and a.max() <= 1.0
    inside = np.zeros_like(a, bool)
    centre = (np.arange(size) + 0.5) / size
    for card in cards:
        u0, u1, _, _ = card
        t = card_rows(card, size)
        cols = (centre + 0.5 / size > u0) & (centre - 0.5 / size < u1)  # texels on the card
        inside[np.ix_((t >= 0) & (t <= 1), cols)] = True
        root = a[np.ix_((t >= 0) & (t < 0.1), cols)]
        assert root.max() == pytest.approx(1.0, abs=1e-6)  # opaque strands at the root
        assert 0.15 < (root > 0.5).mean() < 0.9
        assert (root < 1e-3).mean() > 0.15  # gaps between the roots
        mid = a[np.ix_((t > 0.3) & (t < 0.5), cols)]
        assert (mid < 1e-3).mean() > 0.5  # clear between the strands
        assert a[np.ix_((t > 0.97) & (t <= 1), cols)].max() < 1e-3  # faded at the tips
        # opacity falls from root to tip
        prof = [a[np.ix_((t >= lo) & (t < lo + 0.2), cols)].mean() for lo in (0, 0.2, 0.4, 0.6)]
        assert prof == sorted(prof, reverse=True)
    assert a[~inside].max() == 0.0
    flipped = cards[0, [0, 1, 3, 2]]  # root at the upper v
    f = materials.lash_opacity_map(flipped[None], size)
    t = card_rows(flipped, size)
    assert f[(t >= 0) & (t < 0.1)].max() == pytest.approx(1.0, abs=1e-6)
    assert f[(t > 0.97) & (t <= 1)].max() < 1e-3


def lash_band_darkness(img, band, skin):
    """Share of the lash band's pixels darker than half the median skin luminance."""
    lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    return float((lum[band] < 0.5 * np.median(lum[skin & ~band])).mean())


def test_04_closeup_lashes_are_strands_not_a_band(head_model):
    """In a close-up of the eye the lash cards' footprint is mostly skin and eye seen
    between strands: few of its pixels are dark (8 % here; uniform 50 % cards, three
    layers deep, made 88 % of them dark, a grey band around the eye), yet some are (the
    strands). 64 spp, volpath: shadow rays pass between the strands."""
    topo, v = head_model
    cam = eye_closeup(96)
    dark = {}
    for strands in (True, False):
        head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(96, 96, 64),
                         lash_strands=strands)
        assert (head.lash_opacity is not None) == strands
        hits = head.region_hits()
        band = hits["region"] == REGIONS.index("eyelashes")
        skin = hits["region"] == REGIONS.index("face")
        assert band.sum() > 500
        dark[strands] = lash_band_darkness(head.render(), band, skin)
    assert 0.02 < dark[True] < 0.4 and dark[False] > 0.7, dark


def test_05_label_passes_follow_the_render_opacity(head_model):
    """The label and AOV passes weight a lash hit by the opacity the renderer's mask BSDF
    gives it there (1 - its null transmission), not by a constant."""
    topo, v = head_model
    cam = eye_closeup(48)
    head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(48, 48, 4))
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = head.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5))
    si = camera_hit(head, ray)
    bsdf, _ = head.see_through_cards[0]
    on = si.is_valid() & (dr.reinterpret_array(mi.UInt32, si.bsdf())
                          == dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf)))
    ours = np.asarray(card_opacity(head, si, on))
    mask = 1.0 - np.asarray(bsdf.eval_null_transmission(si, on))[0]  # RGB, all equal
    lash = np.asarray(on)
    assert lash.sum() > 100
    np.testing.assert_allclose(ours[lash], mask[lash], atol=1e-6)
    assert np.all(ours[~lash] == 1.0)
    # region_hits reports the same opacity, which varies along and across the strands
    hits = head.region_hits()
    front = hits["region"].ravel() == REGIONS.index("eyelashes")
    np.testing.assert_allclose(hits["opacity"].ravel()[front], ours[front], atol=1e-6)
    assert hits["opacity"].ravel()[front].min() < 0.01
    assert hits["opacity"].ravel()[front].max() > 0.5
    # the label pass at the pixel centres (k = 1): the lash label's coverage is that opacity
    # where the surface behind is not another lash card (then it is all lashes)
    out = head.label_pass(1, np.arange(len(REGIONS), dtype=np.uint32),
                          np.zeros((4, 8), np.uint32), num_labels=len(REGIONS))
    cov = out["coverage"][..., REGIONS.index("eyelashes")].ravel()
    single = front & (hits["region_behind"].ravel() != REGIONS.index("eyelashes"))
    assert single.sum() > 20
    np.testing.assert_allclose(cov[single], ours[single], atol=1e-6)
    np.testing.assert_allclose(cov[front & ~single], 1.0, atol=1e-6)
    np.testing.assert_allclose(out["coverage"].sum(-1), 1.0, atol=1e-6)


def test_06_denoiser_features_look_through_the_cards(head_model):
    """The denoiser's albedo and normal follow a footprint ray through the lash cards as
    the film does (each card by its opacity, what lies behind by the rest): every ray's
    weights add up to 1 (a ray crosses up to 7 cards here), those on surfaces to no more
    than the first hits' coverage; the lash band's albedo is the skin and eye seen
    between strands, not a dark ring (measured: 2 % of its pixels dark, against 96 %
    when the features stop at the first card); and OIDN given these features lands
    closer to a 1,024-spp reference over the band (measured 0.64x the squared error)."""
    pytest.importorskip("pyoidn")
    from hack_render.render import denoise as dn
    from hack_render.render.footprint import denoise_features, footprint_means

    topo, v = head_model
    cam = eye_closeup(48)
    head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(48, 48, 16))
    see = head.see_through_cards
    hits = head.region_hits()
    band = hits["region"] == REGIONS.index("eyelashes")
    skin = hits["region"] == REGIONS.index("face")
    assert band.sum() > 200

    def weight(layer):  # every hit's weight, and those on a surface (not the background)
        return [layer.weight + 0.0, dr.select(layer.ok, layer.weight, 0.0)]

    _, coverage = footprint_means(head, 4, (), weight)
    total, through = footprint_means(head, 4, see, weight)
    np.testing.assert_allclose(total, 1.0, atol=1e-5)
    assert np.all(through <= coverage + 1e-6)
    assert np.abs(through - coverage)[skin].max() < 1e-6  # skin in front: nothing passed

    lum = np.array([0.2126, 0.7152, 0.0722])
    dark = {}
    feats = {}
    for name, cards in (("through", see), ("first hit", ())):
        feats[name] = denoise_features(head, 4, cards)
        a = feats[name][0] @ lum
        dark[name] = float((a[band] < 0.5 * np.median(a[skin & ~band])).mean())
    assert dark["through"] < 0.05 and dark["first hit"] > 0.5, dark

    ref = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(48, 48, 1024))
    reference = ref.render(seed=5, backdrop=False)[..., :3]
    bare = head.render(seed=1, backdrop=False)
    err = {name: float(np.mean((dn.denoise(bare[..., :3], *f) - reference)[band] ** 2))
           for name, f in feats.items()}
    assert err["through"] < 0.8 * err["first hit"], err


def test_07_gbuffer_sees_through_the_cards(head_model):
    """``gbuffer(see_through=("eyelashes",))``: off the lash cards every AOV is the first
    hit's; on them (``through``: exactly the first hits on a card) it is the surface
    behind all the layered cards, the skin or the eye, deeper than the card, and
    ``card_opacity`` is the first card's opacity there (``region_hits``')."""
    from hack_render.render.aov import gbuffer

    topo, v = head_model
    cam = eye_closeup(48)
    head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(48, 48, 4))
    first = gbuffer(head)
    seen = gbuffer(head, ("eyelashes",))
    lash = first["segmentation"] == REGIONS.index("eyelashes")
    assert lash.sum() > 100 and "through" not in first
    np.testing.assert_array_equal(seen["through"], lash)
    for key in ("depth", "normal", "albedo", "uv", "segmentation"):
        np.testing.assert_array_equal(seen[key][~lash], first[key][~lash])
    behind = seen["segmentation"][lash]
    assert not np.any(behind == REGIONS.index("eyelashes"))
    ids = [REGIONS.index(r) for r in ("face", "sclera", "iris", "lacrimal")]
    assert np.isin(behind, ids).mean() > 0.95 and (behind == ids[0]).mean() > 0.5
    assert np.all(seen["depth"][lash] > first["depth"][lash])
    hits = head.region_hits()
    np.testing.assert_allclose(seen["card_opacity"][lash], hits["opacity"][lash], atol=1e-6)
    assert np.all(seen["card_opacity"][~lash] == 0.0)
