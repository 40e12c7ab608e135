"""Subsurface scattering (hack_render.render.sss): the profile, the screen-space
diffusion's invariants (a uniformly lit patch unchanged, light conserved, red spread
furthest, nothing across a depth gap or onto other materials) and the two-pass render."""

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.render import sss


def flat(h=48, w=64, depth=1.0):
    """A flat skin patch facing the camera: albedo 0.5, every pixel on skin."""
    a = np.full((h, w, 3), 0.5, np.float32)
    return a, a.copy(), np.ones((h, w), np.float32), np.full((h, w), depth, np.float32)


def test_01_profile_is_normalised_and_red_travels_furthest():
    w = np.asarray(sss.SKIN.weights)
    np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-9)
    r = sss.SKIN.mean_radius_mm()
    assert r[0] > 2 * r[1] > 2 * r[2] > 0
    # d'Eon & Luebke's fit: red about 1.1 mm on average, green and blue under 0.3 mm
    assert 0.9 < r[0] < 1.3 and r[1] < 0.3 and r[2] < 0.2


def test_02_uniform_light_stays_and_a_shadow_edge_turns_red():
    albedo, skin_albedo, skin, depth = flat()
    f = 4000.0  # 1 m away: 0.25 mm per pixel
    lit = np.float32(0.8) * albedo
    out = sss.scatter(lit, albedo, skin_albedo, skin, depth, f)
    np.testing.assert_allclose(out, lit, rtol=1e-5)
    # a shadow edge at column 32: light crosses into the shadow, red furthest; none is
    # created or lost away from the patch's border
    irr = np.zeros_like(albedo)
    irr[:, :32] = 1.0
    out = sss.scatter(irr * albedo, albedo, skin_albedo, skin, depth, f)
    shadow = out[8:-8, 32:] / 0.5
    assert shadow[..., 0].sum() > 3 * shadow[..., 1].sum() > 3 * shadow[..., 2].sum() > 0
    np.testing.assert_allclose(out[8:-8].sum((0, 1)) / 0.5, irr[8:-8].sum((0, 1)), rtol=1e-3)
    # the red light's reach in the shadow: its mean distance from the edge (pixels of
    # 0.25 mm) is of the profile's order, not of the image's
    row = shadow[20, :, 0]
    reach = (row * (np.arange(row.size) + 0.5)).sum() / row.sum() * 0.25
    assert 0.2 < reach < 2.0


def test_03_light_does_not_cross_a_depth_gap_or_reach_other_materials():
    albedo, skin_albedo, skin, depth = flat()
    depth[:, 32:] = 1.05  # a surface 5 cm behind (the neck under the chin)
    irr = np.zeros_like(albedo)
    irr[:, :32] = 1.0
    out = sss.scatter(irr * albedo, albedo, skin_albedo, skin, depth, 4000.0)
    assert out[:, 32:].max() < 1e-6
    # pixels of another material (skin fraction 0) neither send nor receive; the skin
    # beyond a strip of it does (light travels under the strip, as under an eyelid)
    skin2 = skin.copy()
    skin2[:, 30:34] = 0.0
    sa = skin_albedo * skin2[..., None]
    out = sss.scatter(irr * albedo, albedo, sa, skin2, flat()[3], 4000.0)
    assert out[:, 30:34].max() == 0.0 and out[:, 34:36, 0].min() > 0


def test_04_scale_zero_and_the_combination_of_passes():
    albedo, skin_albedo, skin, depth = flat()
    rng = np.random.default_rng(0)
    diffuse = (rng.uniform(0.2, 1.0, albedo.shape) * albedo).astype(np.float32)
    out = sss.scatter(diffuse, albedo, skin_albedo, skin, depth, 4000.0, scale=0.0)
    np.testing.assert_allclose(out, diffuse, rtol=1e-5)
    # combine: skin pixels = scattered diffuse + specular; off-skin pixels = the diffuse
    # pass (which holds what the skin's diffuse light adds to other materials)
    skin[:, :8] = 0.0
    skin_albedo[:, :8] = 0.0
    specular = np.full_like(diffuse, 0.1)
    feats = {"albedo": albedo, "skin_albedo": skin_albedo, "skin": skin, "depth": depth}
    rgb = sss.combine(diffuse, specular, feats, 4000.0, scale=0.0)
    np.testing.assert_allclose(rgb[:, 8:], diffuse[:, 8:] + 0.1, rtol=1e-5)
    np.testing.assert_allclose(rgb[:, :8], diffuse[:, :8], rtol=1e-6)


def test_05_bad_shapes_are_clear_errors():
    albedo, skin_albedo, skin, depth = flat()
    with pytest.raises(HackError, match="depth"):
        sss.scatter(albedo, albedo, skin_albedo, skin, depth[:4], 4000.0)
    with pytest.raises(HackError, match="focal"):
        sss.scatter(albedo, albedo, skin_albedo, skin, depth, 0.0)


# --- the two-pass render ----------------------------------------------------------------
@pytest.fixture(scope="module")
def head():
    import torch

    from hack_render.render.engine import ensure_variant, is_jit

    ensure_variant()
    if not is_jit():
        pytest.skip("subsurface scattering needs a JIT variant")
    from hack_render.geometry import load_default_model
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes import cameras, lights

    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    # a close-up of the cheek and nose, 1 m away through a 300 mm lens: ~0.6 mm per
    # pixel, where the red light's spread (~1 mm) spans pixels (at a whole-head framing
    # of 96 px it would not)
    tip = v[np.argmax(v[:, 2])]
    target = tip + np.array([0.025, -0.01, -0.03])
    R, t = cameras.look_at(target + np.array([0.5, 0.0, 0.85]), target)
    cam = cameras.Camera(cameras.intrinsics(96, 96, 300.0), R, t, 96, 96, "cheek")
    topo = Topology.from_model(model)
    return {name: HeadScene(topo, v, lights.preset("window"), cam,
                            RenderSettings(96, 96, 16, integrator=name))
            for name in ("hack_path", "volpath")}


def _roughness(img, skin, c):  # mean difference between neighbouring skin pixels
    return np.abs(np.diff(img[..., c], axis=1))[skin[:, 1:] & skin[:, :-1]].mean()


def _assert_red_smoothed(scattered, plain, skin):
    """Scattering smooths the skin's red, which travels furthest, and hardly its blue
    (measured: red 0.93-0.94x, green and blue 0.999x the plain render's roughness)."""
    r = [_roughness(scattered, skin, c) / _roughness(plain, skin, c) for c in range(3)]
    assert r[0] < 0.96 and r[0] < r[2] - 0.03, r


def test_06_one_pass_splits_the_skin_light(head):
    """hack_path's skin split: the image of the split render is the plain render's,
    sample for sample; its AOVs (the light whose first event is the skin's diffuse,
    specular lobe) are non-negative, add up to no more than the image, and agree with
    the two lobe-weighted renders on skin pixels (measured within 1 % diffuse; the
    specular AOV also holds the light that bounces on to the other lobe, which the
    specular-only render drops); render(sss=True) is combine_split of that one pass,
    keeps the light (within 1 %) and smooths the skin's red."""
    from hack_render.render.footprint import sss_features

    h = head["hack_path"]
    one = h.render(seed=1, backdrop=False)
    img = h.render_passes(1, False, integrator=sss.split_integrator(h))
    assert img.shape == one.shape[:2] + (10,)
    np.testing.assert_allclose(img[..., :4], one, rtol=1e-5, atol=1e-7)
    d, s = img[..., 4:7], img[..., 7:10]
    assert d.min() >= 0 and s.min() >= 0
    assert np.all(d + s <= img[..., :3] + 1e-5)
    f = sss_features(h, h.skin_bsdf, h.see_through_cards)
    skin = f["skin"] > 0.99
    assert skin.sum() > 4000
    dd, ss = sss.lobe_passes(h, seed=1)
    np.testing.assert_allclose(d[skin].mean(0), dd[..., :3][skin].mean(0), rtol=0.02)
    np.testing.assert_allclose(s[skin].mean(0), ss[..., :3][skin].mean(0), rtol=0.25)
    scattered = h.render(seed=1, backdrop=False, sss=True)
    focal = float(h.camera.K[0, 0])
    np.testing.assert_allclose(scattered[..., :3],
                               sss.combine_split(img[..., :3], d, f, focal),
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(scattered[..., 3], one[..., 3], atol=1e-6)
    np.testing.assert_allclose(scattered[..., :3].sum((0, 1)), one[..., :3].sum((0, 1)),
                               rtol=0.01)
    unscattered = sss.combine_split(img[..., :3], d, f, focal, scale=0.0)
    np.testing.assert_allclose(unscattered, img[..., :3], rtol=1e-5, atol=1e-6)
    _assert_red_smoothed(scattered, one, skin)


def test_06b_two_passes_add_up_to_the_render(head):  # the other integrators
    """The skin's diffuse and specular passes (lobe weights (1, 0), (0, 1)), combined
    without scattering, match a one-pass render; render(sss=True) is those passes
    combined with scattering, which keeps the light (within 1 %) and smooths the skin's red;
    the lobe weights are restored."""
    from hack_render.render.footprint import sss_features

    head = head["volpath"]
    one = head.render(seed=1, backdrop=False)
    d, s = sss.lobe_passes(head, seed=2)
    f = sss_features(head, head.skin_bsdf, head.see_through_cards)
    focal = float(head.camera.K[0, 0])
    plain = sss.combine(d[..., :3], s[..., :3], f, focal, scale=0.0)
    skin = f["skin"] > 0.99
    assert skin.sum() > 4000
    np.testing.assert_allclose(plain[skin].mean(0), one[..., :3][skin].mean(0), rtol=0.03)
    scattered = head.render(seed=2, backdrop=False, sss=True)
    np.testing.assert_allclose(scattered[..., :3], sss.combine(d[..., :3], s[..., :3], f, focal),
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(scattered[..., 3], d[..., 3], rtol=1e-5, atol=1e-7)
    assert [float(w[0]) for w in head.skin_bsdf.lobe_weights] == [1.0, 1.0]
    np.testing.assert_allclose(scattered[..., :3].sum((0, 1)), plain.sum((0, 1)), rtol=0.01)

    _assert_red_smoothed(scattered, plain, skin)
