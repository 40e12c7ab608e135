"""The photo baked onto the parts that are not skin (hack_render/fit/part_bake.py,
``final.part_bake``): per-vertex colours of the eyes' fronts, whites and tear film (and
the teeth and gums where the mouth shows them), carried to ``render.png`` and to
``--textures`` (``parts.npz``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from synthetic import photo_of, texture_fitter

EYE_PARTS = ("iris", "sclera", "lacrimal")


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def _positions(head, part):
    return np.asarray(head.params[f"{part}.vertex_positions"], np.float64).reshape(-1, 3)


def test_01_the_eyes_colours_are_baked_from_the_photo(model, tmp_path):
    """A photo whose eyes' fronts, whites and tear film carry colours of their own (a
    smooth pattern over each part, far from the defaults): two passes of the bake bring
    the render over those parts' pixels to the photo (the squared error 10 times lower
    than before at least) and the colours of the vertices the camera sees to the truth;
    a vertex it does not see keeps its colour exactly; an occluder keeps the parts out
    except inside the person's eye and mouth openings. The
    colours go to ``parts.npz`` and come back through ``--textures``; an array of another
    length or an unknown part is a clear error."""
    from hack_render.errors import HackError
    from hack_render.fit import outputs, part_bake, texture
    from hack_render.render.materials import SkinMaps
    from hack_render.render.parts import REGIONS
    from hack_render.render.skin_maps import PARTS_FILE, read_texture_folder

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=15.0, res=256)
    st, v = f.state, f.state.views[0]
    head, _ = texture.photo_scene(st, cfg, v, true_maps, 1, cfg.final.max_side)
    truth = {}
    for k, part in enumerate(EYE_PARTS):
        # a pattern of about 25 mm: smooth over the few pixels an eye is wide here
        p = _positions(head, part) * 1e3 / 4.0
        truth[part] = np.clip(0.45 + 0.3 * np.stack(
            [np.sin(p[:, 0] + k), np.cos(p[:, 1] * 0.7 + k), np.sin(p[:, 0] + p[:, 1])], 1),
            0.03, 0.95).astype(np.float32)
    shot = texture.render_at_photo(st, cfg, v, maps=dataclasses.replace(
        true_maps, part_rgb=truth), spp=64)
    v.photo = photo_of(shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5)
    ids = [REGIONS.index(p) for p in EYE_PARTS]
    pixels = np.isin(shot.gbuffer["segmentation"], ids) & (shot.rgba[..., 3] > 0.999)
    assert pixels.sum() > 40

    def err(render):
        return float(((render.rgba[..., :3] - shot.rgba[..., :3])[pixels] ** 2).mean())

    maps = true_maps
    render = texture.render_at_photo(st, cfg, v, maps=maps, spp=64)
    before = err(render)
    start = part_bake.view_samples(st, cfg, v, maps, render)
    first = None
    for _ in range(2):
        rgb, report = part_bake.bake_parts(st, cfg, maps, [render])
        first = first or rgb
        maps = dataclasses.replace(maps, part_rgb=rgb)
        render = texture.render_at_photo(st, cfg, v, maps=maps, spp=64)
    assert err(render) < before / 10, (before, err(render))   # measured 17x
    assert set(EYE_PARTS) <= set(rgb) and report["iris"]["seen_vertices"] > 50
    samples = part_bake.view_samples(st, cfg, v, maps, render)
    for part in EYE_PARTS:
        cur0, _, _ = start[part]
        _, _, wgt = samples[part]
        seen = wgt > 0.5
        assert seen.sum() >= 10, part
        # the colours of the vertices seen move to the truth, as far as the pixels tell:
        # an eye is ~12 pixels wide here, ~3 of the iris's vertices to a pixel, so what
        # varies within a pixel stays as it was (the iris's pattern, its pupil); measured
        # median error iris 0.60 -> 0.14, whites 0.10 -> 0.04, tear film 0.12 -> 0.02
        e0 = np.median(np.abs(cur0[seen] - truth[part][seen]))
        e1 = np.median(np.abs(rgb[part][seen] - truth[part][seen]))
        assert e1 < 0.5 * e0 and e1 < 0.2, (part, e0, e1)
        # not seen (the same vertices in each pass: the geometry is the same): the colour
        # the part had (its material's, or the iris's pattern) is kept as it was
        unseen = wgt == 0
        assert unseen.any()
        np.testing.assert_array_equal(rgb[part][unseen], first[part][unseen])
        np.testing.assert_allclose(rgb[part][unseen], cur0[unseen], atol=1e-6)
    # an occluder over the whole photo keeps every part out of the bake; the person's
    # eye or mouth opening over it (the face mesh's: the segmentation calls the teeth and
    # a shaded eye "not skin") gives the parts inside it back
    full = np.ones(v.photo.uint8().shape[:2], bool)
    v.occluder, v.eye_opening, v.mouth_opening = full, None, None
    hidden = part_bake.view_samples(st, cfg, v, maps, render)
    assert all((w == 0).all() for _, _, w in hidden.values())
    for which in ("eye_opening", "mouth_opening"):
        setattr(v, which, full)
        back = part_bake.view_samples(st, cfg, v, maps, render)
        for part in EYE_PARTS:
            np.testing.assert_array_equal(back[part][2], samples[part][2])
        setattr(v, which, None)
    v.occluder = None
    # to --textures and back
    final = _final_stub(maps)
    written = outputs.write_textures(st, tmp_path / "tex", final, brows_baked=True)
    assert tmp_path / "tex" / PARTS_FILE in written
    assert read_texture_folder(tmp_path / "tex").brows_baked
    back = read_texture_folder(tmp_path / "tex").part_rgb
    assert set(back) == set(rgb)
    for part in rgb:
        np.testing.assert_array_equal(back[part], rgb[part])
    with pytest.raises(HackError, match="part colours 'iris': expected one per vertex"):
        texture.photo_scene(st, cfg, v, dataclasses.replace(
            maps, part_rgb={"iris": rgb["iris"][:-1]}), 1, None)
    with pytest.raises(HackError, match="expected parts among"):
        SkinMaps(maps.diffuse, maps.specular, maps.roughness, part_rgb={"nose": rgb["iris"]})
    np.savez(tmp_path / "tex" / PARTS_FILE, nose=rgb["iris"])
    with pytest.raises(HackError, match="expected arrays named among"):
        read_texture_folder(tmp_path / "tex")


def test_03_the_pupil_is_not_baked(model):
    """The iris's pupil keeps its colour (a hole: black) whatever the photo shows over
    it: baked, a photo's catchlight spread over the pupil's few vertices as a grey-blue
    pupil. On synthetic points about one eye's axis, then through a render: white painted
    over both irises of a photo leaves the pupils' vertices as they were and lightens the
    rest of the irises."""
    from hack_render.fit import part_bake, texture
    from hack_render.render.parts import PUPIL_RADIUS, REGIONS

    axes = [(np.zeros(3), np.array([0.0, 0.0, 1.0])),
            (np.array([0.06, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))]
    r = np.array([0.3, 0.8, 1.5, 1.69, 1.71, 2.5, 4.0, 6.5]) * 1e-3
    pos = np.r_[np.c_[r, np.zeros_like(r), np.full_like(r, 0.01)],
                np.c_[0.06 - r, np.zeros_like(r), np.full_like(r, 0.01)]]
    np.testing.assert_array_equal(part_bake.pupil(pos, axes), np.tile(r < PUPIL_RADIUS, 2))

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0, res=256)
    st, v = f.state, f.state.views[0]
    head, _ = texture.photo_scene(st, cfg, v, true_maps, 1, cfg.final.max_side)
    shot = texture.render_at_photo(st, cfg, v, maps=true_maps, spp=32)
    photo = shot.rgba[..., :3] + (1 - shot.rgba[..., 3:4]) * 0.5
    iris = shot.gbuffer["segmentation"] == REGIONS.index("iris")
    assert iris.sum() > 20
    photo[iris] = [0.95, 0.95, 1.0]
    v.photo = photo_of(photo)
    cur, _, wgt = part_bake.view_samples(st, cfg, v, true_maps, shot)["iris"]
    inside = part_bake.pupil(_positions(head, "iris"), head.eye_axes)
    assert inside.sum() >= 4 and (wgt[inside] == 0).all() and (wgt[~inside] > 0).sum() >= 10
    rgb, _ = part_bake.bake_parts(st, cfg, true_maps, [shot])
    np.testing.assert_allclose(rgb["iris"][inside], cur[inside], atol=1e-6)
    seen = wgt > 0
    assert (rgb["iris"][seen].mean(1) > cur[seen].mean(1)).mean() > 0.9


def _final_stub(maps):
    from types import SimpleNamespace

    from hack_render.fit.final import FinalRenders

    baked = SimpleNamespace(confidence=np.ones(maps.diffuse.shape[:2], np.float32))
    return FinalRenders(fitted=[], baked=baked, maps=maps, renders=[], iris={}, specular={})


def test_02_textures_that_hold_the_brows_get_no_brow_strands(tmp_path, cli_in_process):
    """A texture folder whose ``skin.json`` says the diffuse map holds the brows (a fit's
    bake with ``final.features``): ``render --textures --hair`` draws no brow strands
    over them and says so; without the file, or with brows_baked false, the style's brows
    are drawn; a malformed file is a clear error (exit 2)."""
    import json

    from hack_render.io.image import write_exr
    from hack_render.render import cli as render_cli
    from hack_render.render.materials import SkinMaps
    from hack_render.render.skin_maps import SKIN_FILE

    tex = tmp_path / "tex"
    tex.mkdir()
    c = SkinMaps.constant(32)
    write_exr(tex / "diffuse.exr", {k: c.diffuse[..., i] for i, k in enumerate("RGB")})
    write_exr(tex / "specular.exr", {"Y": c.specular[..., 0]})
    write_exr(tex / "roughness.exr", {"Y": c.roughness[..., 0]})
    brows = []
    real = render_cli.groom_of

    def groom_of(style, model):
        brows.append(style.brow_density)
        return real(style, model)

    args = ("render", "-o", tmp_path / "r.png", "--textures", tex, "--hair", "crew",
            "--resolution", "32", "--spp", "1")
    import unittest.mock

    with unittest.mock.patch.object(render_cli, "groom_of", groom_of):
        for doc, drawn in ((None, True), ({"brows_baked": False}, True),
                           ({"brows_baked": True}, False)):
            if doc is not None:
                (tex / SKIN_FILE).write_text(json.dumps(doc))
            r = cli_in_process(*args)
            assert r.returncode == 0, r.stderr[-1000:]
            assert (brows[-1] > 0) == drawn
            assert ("no brow strands" in r.stderr) == (not drawn)
        (tex / SKIN_FILE).write_text(json.dumps({"brows_baked": "yes"}))
        r = cli_in_process(*args)
        assert r.returncode == 2 and "expected a boolean brows_baked" in r.stderr


def test_04_the_veil_is_taken_off_before_the_ratio():
    """``final.part_veil``: the render is affine in a vertex's colour, ``colour * shading +
    veil`` (the veil: the cornea's reflection, what the render shows with the colours
    black). A dark iris under a bright reflection: the factor ``(photo - veil) / (render -
    veil)`` gives the true colour in one step; photo / render leaves it several times too
    light after the default two passes (the grey-blue irises), converging only slowly. A grey photo gives one
    factor for the three channels; where the part's own share is nearly nothing the
    plain ratio stands; a photo darker than the veil alone gives black, not a negative
    colour."""
    from hack_render.fit.part_bake import AFFINE_MIN, RATIO_RANGE, affine_ratio

    rng = np.random.default_rng(4)
    n = 200
    truth = rng.uniform(0.01, 0.08, (n, 3))          # a dark brown iris, linear
    shading = rng.uniform(0.3, 1.0, (n, 1))
    veil = rng.uniform(0.02, 0.06, (n, 3)) * np.array([0.8, 0.9, 1.0])  # a bluish sky
    cur = np.full((n, 3), 0.3)                       # the prior's light iris
    photo = truth * shading + veil                   # the same light on the cornea

    def render(c):
        return c * shading + veil

    got = cur * affine_ratio(photo, render(cur), veil)
    np.testing.assert_allclose(got, truth, rtol=1e-9)
    # photo / render, iterated: after the default two passes still too light
    c = cur.copy()
    for _ in range(2):
        c = np.clip(c * affine_ratio(photo, render(c), None), 0, 1)
    assert np.median(c / truth) > 1.3, np.median(c / truth)
    # grey: one factor, from luminance
    g = affine_ratio(photo, render(cur), veil, grey=True)
    assert np.all(g == g[:, :1])
    luma = np.array([0.2126, 0.7152, 0.0722])
    np.testing.assert_allclose(g[:, 0], ((photo - veil) @ luma) / ((render(cur) - veil) @ luma))
    # the part's own share too small: the plain ratio; the photo under the veil: 0
    r = render(cur)
    tiny = veil + AFFINE_MIN / 2
    np.testing.assert_allclose(affine_ratio(photo, tiny, veil),
                               np.clip(photo / tiny, *RATIO_RANGE))
    assert np.all(affine_ratio(veil * 0.5, r, veil) == 0.0)


def test_05_the_passes_before_the_last_render_the_parts_box(model):
    """``final.part_box``: the part bake's passes before the last (and the veil) render
    only the box of the parts' pixels (``part_bake.parts_box``, 12 px about them), their
    scene kept (``texture.PartRenders``). That box holds every eye and mouth pixel of the
    whole render; its render, pasted in the whole image, shows the same first hits inside
    it as the whole render and nothing outside it; new part colours set in the kept scene
    render as a scene built with them does. A render without the parts has no box; a
    box outside the image is an error."""
    from hack_render.fit import part_bake, texture
    from hack_render.fit.bake_weights import PhotoRender
    from hack_render.render.materials import VERTEX_COLOUR_PARTS
    from hack_render.render.parts import PART_SPECS, REGIONS

    f, cfg, true_maps, _, _ = texture_fitter(model, yaw=15.0, res=256)
    st, v = f.state, f.state.views[0]
    whole = texture.render_at_photo(st, cfg, v, maps=true_maps, spp=4)
    seg = np.asarray(whole.gbuffer["segmentation"])
    ids = [REGIONS.index(PART_SPECS[n][1]) for n in VERTEX_COLOUR_PARTS]
    box = part_bake.parts_box(whole)
    x0, y0, bw, bh = box
    parts = np.isin(seg, ids)
    assert parts.sum() > 40 and parts[y0:y0 + bh, x0:x0 + bw].sum() == parts.sum()
    assert bw * bh < 0.5 * np.count_nonzero(seg)   # the head's pixels: far fewer rendered
    head, _ = texture.photo_scene(st, cfg, v, true_maps, 1, cfg.final.max_side)
    rng = np.random.default_rng(6)
    colours = [{p: rng.uniform(0.05, 0.9, (len(_positions(head, p)), 3)).astype(np.float32)
                for p in EYE_PARTS} for _ in range(2)]
    kept = texture.PartRenders(st, cfg, v, box)
    first = kept(dataclasses.replace(true_maps, part_rgb=colours[0]))
    pseg = np.asarray(first.gbuffer["segmentation"])
    assert first.rgba.shape == whole.rgba.shape
    np.testing.assert_array_equal(pseg[y0:y0 + bh, x0:x0 + bw], seg[y0:y0 + bh, x0:x0 + bw])
    outside = np.ones(seg.shape, bool)
    outside[y0:y0 + bh, x0:x0 + bw] = False
    assert not pseg[outside].any() and not first.rgba[outside].any()
    second = kept(dataclasses.replace(true_maps, part_rgb=colours[1]))
    fresh = texture.PartRenders(st, cfg, v, box)(dataclasses.replace(true_maps,
                                                                     part_rgb=colours[1]))
    eyes = np.isin(pseg, [REGIONS.index(p) for p in EYE_PARTS])
    assert np.abs(second.rgba - first.rgba)[eyes].max() > 0.05   # the colours changed
    # (1.3e-6 measured: the Gaussian filter's splats summed in the threads' order)
    np.testing.assert_allclose(second.rgba, fresh.rgba, atol=1e-5)
    none = PhotoRender(whole.rgba, {"segmentation": np.where(parts, 1, seg)}, 4, 0.0)
    assert part_bake.parts_box(none) is None
    with pytest.raises(ValueError, match="outside"):
        texture.photo_scene(st, cfg, v, true_maps, 4, cfg.final.max_side, box=(10_000, 0, 5, 5))
