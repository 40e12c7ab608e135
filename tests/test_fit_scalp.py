"""The fitted hair layer in render.png: the scalp under it shaded towards the hair's colour
(fit/scalp.py), and its strands rendered with their own scattering (final.hair_composite)."""

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.fit import final, scalp
from hack_render.fit.bake_weights import PhotoRender
from hack_render.fit.config import load_config
from hack_render.geometry import load_default_model
from hack_render.hair.groom import grow_cached
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import HairStyle
from hack_render.render.parts import REGIONS


@pytest.fixture(scope="module")
def crew():
    m = load_default_model()
    groom = grow_cached(HeadSurface.from_model(m), HairStyle.archetype_style("crew", lod=0.3))
    return m, groom, scalp.root_density(m, groom, 256)


def _uv_texels(m, faces, H):
    """The atlas texels (rows, cols) of ``faces``' UV centroids."""
    uv = m.uvs.numpy()[m.uv_faces.numpy()[faces]].mean(1)
    return (np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1),
            np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1))


def test_01_the_roots_cover_the_crown_and_never_the_face(crew):
    m, _, dens = crew
    assert dens.shape == (256, 512) and dens.dtype == np.float32
    assert 0.0 <= dens.min() and dens.max() <= 1.0
    v, f = m.template.numpy(), m.faces.numpy()
    names = list(m.material_names)
    fm = m.face_material.numpy()
    c = v[f].mean(1)
    lm = v[m.landmark_indices.numpy()]
    # the face between the eyes' outer corners, below the brows (sideburns are beside it)
    face = np.flatnonzero((fm == names.index("M_Face")) & (c[:, 1] < lm[19, 1] - 0.01)
                          & (np.abs(c[:, 0]) < np.abs(lm[36, 0] - lm[45, 0]) / 2))
    cy = c[:, 1]
    top = np.flatnonzero(cy > v[:, 1].max() - 0.02)
    assert len(face) > 500 and len(top) > 50
    assert dens[_uv_texels(m, face, 256)].max() < 0.01     # no strand roots below the brows
    assert np.median(dens[_uv_texels(m, top, 256)]) > 0.5  # a crew cut covers the crown


def test_02_only_unseen_texels_under_roots_take_the_hairs_colour():
    rng = np.random.default_rng(0)
    diffuse = rng.uniform(0.2, 0.6, (8, 16, 3)).astype(np.float32)
    conf = np.zeros((8, 16), np.float32)
    conf[:, :4] = 1.0      # seen by the photo
    conf[:, 4:6] = 0.5
    dens = np.zeros((8, 16), np.float32)
    dens[:, :12] = 1.0     # rooted
    dens[:, 6:8] = 0.25
    hair = (0.02, 0.015, 0.01)
    out, share = scalp.shade_scalp(diffuse, conf, dens, hair, 0.8)
    assert out.dtype == diffuse.dtype
    np.testing.assert_array_equal(out[:, :4], diffuse[:, :4])      # seen: the bake's
    np.testing.assert_array_equal(out[:, 12:], diffuse[:, 12:])    # no roots: unchanged
    np.testing.assert_allclose(out[:, 8:12], 0.2 * diffuse[:, 8:12] + 0.8 * np.array(hair),
                               rtol=1e-6)
    np.testing.assert_allclose(out[:, 4:6], 0.6 * diffuse[:, 4:6] + 0.4 * np.array(hair),
                               rtol=1e-6)
    np.testing.assert_allclose(out[:, 6:8], 0.8 * diffuse[:, 6:8] + 0.2 * np.array(hair),
                               rtol=1e-6)
    assert share == pytest.approx(8 / 16)
    same, none = scalp.shade_scalp(diffuse, conf, dens, hair, 0.0)
    np.testing.assert_array_equal(same, diffuse)
    assert none == 0.0


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "0.5"])
def test_03_the_shade_is_a_share(bad):
    with pytest.raises(HackError, match="final.scalp_shade"):
        load_config(None, {"final": {"scalp_shade": bad}})


def test_04_the_hair_pixels_come_from_the_deep_render_the_skin_from_the_shallow():
    h, w = 12, 16
    seg = np.full((h, w), REGIONS.index("face"), np.int32)
    seg[3:9, 4:10] = REGIONS.index("hair")
    shallow = PhotoRender(np.full((h, w, 4), 0.2, np.float32), {"segmentation": seg}, 16, 1.0)
    deep = PhotoRender(np.full((h, w, 4), 0.6, np.float32), {"segmentation": seg.copy()},
                       16, 2.0)
    out = final.hair_composite(shallow, deep)
    assert out.rgba.dtype == np.float32 and out.seconds == 3.0
    assert out.gbuffer is shallow.gbuffer
    np.testing.assert_allclose(out.rgba[4:8, 5:9], 0.6, rtol=1e-6)   # inside the hair
    np.testing.assert_allclose(out.rgba[:, 11:], 0.2, rtol=1e-6)     # skin away from it
    np.testing.assert_allclose(out.rgba[:2], 0.2, rtol=1e-6)
    edge = out.rgba[2, 3, 0]     # a skin pixel diagonal to the hair's corner: 1/9 hair
    assert edge == pytest.approx(0.2 + 0.4 / 9, rel=1e-5)


@pytest.mark.parametrize("bad", [1, 65, True, 2.5, "8"])
def test_05_the_hair_depth_is_a_path_depth(bad):
    with pytest.raises(HackError, match="final.hair_depth"):
        load_config(None, {"final": {"hair_depth": bad}})


def test_06_the_colour_step_reads_hair_where_both_show_it():
    from types import SimpleNamespace

    from hack_render.fit import final

    h, w = 40, 40
    photo = np.full((h, w, 3), 0.5, np.float32)
    photo[:20] = (0.12, 0.08, 0.02)                     # the photo's hair: the top half
    view = SimpleNamespace(photo=SimpleNamespace(linear=lambda: photo))
    hair_px = np.zeros((h, w), bool)
    hair_px[:20] = True
    seg = np.full((h, w), REGIONS.index("face"), np.int32)
    seg[5:30] = REGIONS.index("hair")                   # the render's strands overlap it
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = 0.3
    rgba[5:30, :, :3] = (0.24, 0.16, 0.04)              # twice the photo's hair
    pr = PhotoRender(rgba, {"segmentation": seg}, 16, 1.0)
    ph, rd = final._hair_pixels(view, pr, hair_px)      # rows 5..19: 600 pixels
    np.testing.assert_allclose(ph, (0.12, 0.08, 0.02), rtol=1e-6)
    np.testing.assert_allclose(rd, (0.24, 0.16, 0.04), rtol=1e-6)
    seg[8:30] = REGIONS.index("face")                   # 3 rows x 40: too few
    assert final._hair_pixels(view, pr, hair_px) == (None, None)


@pytest.mark.parametrize("bad", [-1, 5, True, 1.5])
def test_07_the_colour_steps_are_a_count(bad):
    with pytest.raises(HackError, match="final.hair_colour_steps"):
        load_config(None, {"final": {"hair_colour_steps": bad}})
