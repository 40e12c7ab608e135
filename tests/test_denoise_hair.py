"""The denoiser's features on hair (issue 61): a hit on a strand gives OIDN the hair's
calibrated colour (``hair.style.slab_albedo``) and the direction to the camera as its
normal (``footprint.denoise_features``), so OIDN smooths the strands' noise instead of
keeping it as detail."""

from dataclasses import replace

import numpy as np
import pytest

from hack_render.hair.groom import grow_cached
from hack_render.hair.style import HairStyle, slab_albedo
from hack_render.render import denoise as dn
from hack_render.render import footprint
from hack_render.render.engine import ensure_variant
from hack_render.render.parts import REGIONS
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights

ensure_variant()

pytestmark = pytest.mark.skipif(not dn.available(), reason="pyoidn (the 'denoise' extra)")

RES = 64
HAIR = REGIONS.index("hair")
EU, PHEO = 1.3, 0.25  # a brown: its slab albedo is far from the BSDF's grey


@pytest.fixture(scope="module")
def head_model(hair_head_model):
    return hair_head_model


@pytest.fixture(scope="module")
def groom(head_model):
    """A short groom of one colour, no greying."""
    style = HairStyle.archetype_style("short", lod=0.3, variation=0.0, greying=0.0)
    g = grow_cached(head_model[2], style)
    groups = [replace(x, melanin=np.tile([EU, PHEO], (x.num_strands, 1)).astype(np.float64))
              for x in g.groups]
    return replace(g, groups=groups)


def _scene(head_model, groom, spp):
    """The back of the head from above (the scalp hair covers the skin), box filter as
    ``render --denoise`` uses."""
    topo, v, _ = head_model
    cam = cameras.orbit(RES, RES, 85.0, 180.0, 30.0)
    return HeadScene(topo, v, lights.preset("studio"), cam,
                     RenderSettings(RES, RES, spp, pixel_filter="box"), hair=groom)


def _covered(head):
    """Pixels whose footprint is all hair."""
    out = head.label_pass(4, np.arange(len(REGIONS), dtype=np.uint32),
                          np.zeros((4, 8), np.uint32), num_labels=len(REGIONS))
    return out["coverage"][..., HAIR] > 0.99


def _bsdf_features(head, k=4):
    """The features before issue 61's fix: the BSDF's diffuse reflectance and the curve's
    shading normal on the strands too."""
    import drjit as dr

    def values(layer):
        hit, ok, w = layer.hit, layer.ok, layer.weight
        a = dr.select(ok, hit.bsdf(layer.ray).eval_diffuse_reflectance(hit, ok) * w, 0.0)
        n = dr.select(ok, hit.sh_frame.n * w, 0.0)
        return [a[c] for c in range(3)] + [n[c] for c in range(3)]

    m = footprint.footprint_means(head, k, head.see_through_cards, values)
    return np.stack(m[:3], -1), np.stack(m[3:], -1)


def test_01_hair_hits_give_the_calibrated_colour_and_a_smooth_normal(head_model, groom):
    head = _scene(head_model, groom, 1)
    pairs = footprint.hair_albedos(head)
    assert len(pairs) == len(head.hair_shapes) > 0
    want = slab_albedo(EU, PHEO)
    for _, rgb in pairs:
        np.testing.assert_allclose(rgb, want, atol=1e-6)
    sel = _covered(head)
    assert sel.sum() > 200, sel.sum()
    albedo, normal = footprint.denoise_features(head, 4, head.see_through_cards)
    # the calibrated brown, not the BSDF's grey (0.09 in each channel)
    np.testing.assert_allclose(albedo[sel], np.broadcast_to(want, albedo[sel].shape),
                               atol=2e-3)
    # the normal: unit length, and the same from pixel to pixel across the strands
    # (the shading normal of the curves turns across every strand)
    assert np.abs(np.linalg.norm(normal[sel], axis=-1) - 1.0).max() < 1e-3
    both = sel[:, 1:] & sel[:, :-1]
    step = np.linalg.norm(normal[:, 1:] - normal[:, :-1], axis=-1)[both]
    _, old_normal = _bsdf_features(head)
    old_step = np.linalg.norm(old_normal[:, 1:] - old_normal[:, :-1], axis=-1)[both]
    assert step.max() < 0.05 < np.median(old_step), (step.max(), np.median(old_step))


def test_02_denoised_hair_is_nearer_the_reference_than_with_the_bsdf_features(
        head_model, groom):
    """4 spp + OIDN against a 128-spp render, PSNR over the pixels all covered by hair."""
    ref_head = _scene(head_model, groom, 128)
    ref = ref_head.render(seed=7, backdrop=False)[..., :3]
    head = _scene(head_model, groom, 4)
    sel = _covered(head)
    img = head.render(seed=1, backdrop=False)

    def psnr(x):
        return 10 * np.log10(1.0 / float(((x[..., :3] - ref) ** 2)[sel].mean()))

    new = psnr(head.denoise(img))
    old = psnr(dn.denoise(img[..., :3], *_bsdf_features(head)))
    noisy = psnr(img)
    print(f"hair PSNR: noisy {noisy:.2f}, OIDN with the BSDF's features {old:.2f}, "
          f"with the hair's {new:.2f} dB")
    assert new > noisy + 6.0, (noisy, old, new)
    assert new > old + 1.0, (noisy, old, new)  # measured: 31.0, 37.9, 40.2 dB
