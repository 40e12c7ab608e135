"""Hair in the renderer (issue 61): a groom's strands as curves with the hair BSDF in
``HeadScene(hair=...)``, labelled ``hair`` by the AOV passes, re-posed by ``set_vertices``;
the bald scene unchanged; ``--hair`` / ``--hair-color`` of the commands."""

from dataclasses import replace

import numpy as np
import pytest

from hack_render.render.engine import ensure_variant

ensure_variant()

import mitsuba as mi

from hack_render.cli import main
from hack_render.hair.groom import Groom, grow_cached
from hack_render.hair.style import HairStyle
from hack_render.render.hair_options import hair_style
from hack_render.render.hair_shapes import (
    HAIR_RR,
    HAIR_RR_DEPTH,
    MAX_CONTROL_POINTS,
    MELANIN_BUCKETS,
    MIN_SEGMENT,
    buckets,
    control_points,
)
from hack_render.render.parts import REGIONS
from hack_render.render.scene import HeadScene, RenderSettings
from hack_render.render.sss import split_integrator
from scenes import cameras, lights

RES = 64
HAIR = REGIONS.index("hair")


@pytest.fixture(scope="module")
def head_model(hair_head_model):
    return hair_head_model


@pytest.fixture(scope="module")
def groom(head_model):
    """A sparse short groom (brows and lashes too), one colour, no greying."""
    style = HairStyle.archetype_style("short", lod=0.15, variation=0.0, greying=0.0)
    return grow_cached(head_model[2], style)


def _coloured(groom: Groom, eu: float, pheo: float = 0.0) -> Groom:
    groups = [replace(g, melanin=np.tile([eu, pheo], (g.num_strands, 1)).astype(np.float64))
              for g in groom.groups]
    return replace(groom, groups=groups)


def _scene(head_model, groom, res=RES, spp=4, yaw=0.0, pitch=5.0, **kw):
    topo, v, _ = head_model
    cam = cameras.orbit(res, res, 85.0, yaw, pitch)
    return HeadScene(topo, v, lights.preset("studio"), cam,
                     RenderSettings(res, res, spp, pixel_filter="box"), hair=groom, **kw)


def test_01_region_ids_kept_and_hair_appended():
    assert REGIONS[:10] == ("background", "face", "back_head", "mouth", "teeth", "sclera",
                            "iris", "lacrimal", "eyelashes", "bust")
    assert REGIONS[-1] == "hair"


def test_02_curve_control_points_keep_root_and_tip():
    """Linear curves through the strand's points: root and tip kept, long strands resampled
    to MAX_CONTROL_POINTS, no zero-length segment (a cut strand's gathered tail); the
    melanin buckets split a group by quantile and keep white strands apart."""
    pts = np.cumsum(np.random.default_rng(0).normal(size=(3, 20, 3)), 1)
    pts[0, -3:] = pts[0, -4]  # a gathered tail
    cp = control_points(pts, np.linspace(2e-4, 1e-4, 20))
    assert cp.shape == (3, MAX_CONTROL_POINTS, 4)
    np.testing.assert_allclose(cp[:, 0, :3], pts[:, 0], atol=1e-5)
    np.testing.assert_allclose(cp[1:, -1, :3], pts[1:, -1], atol=1e-5)
    seg = np.linalg.norm(np.diff(cp[..., :3].astype(np.float64), axis=1), axis=-1)
    assert seg.min() > 0.9 * MIN_SEGMENT
    assert cp[0, 0, 3] == pytest.approx(2e-4) and cp[0, -1, 3] == pytest.approx(1e-4)
    mel = np.c_[np.r_[np.linspace(1, 2, 40), [0.02] * 10], np.zeros(50)]
    b = buckets(mel, 4)
    assert len(b) == 5 and sorted(b[0]) == list(range(40, 50))
    assert sorted(np.concatenate(b)) == list(range(50))


def test_03_bald_scene_has_no_curves_and_hair_scene_replaces_the_lash_cards(head_model, groom):
    bald = _scene(head_model, None)
    ids = {s.id() for s in bald.scene.shapes()}
    assert not any(i.startswith("hair_") for i in ids) and "eyelashes" in ids
    assert bald.hair_shapes == [] and bald.see_through_cards
    hairy = _scene(head_model, groom)
    ids = {s.id() for s in hairy.scene.shapes()}
    assert "eyelashes" not in ids and not hairy.see_through_cards
    assert {s.group for s in hairy.hair_shapes} == {"scalp", "brows", "lashes"}
    assert {s.id for s in hairy.hair_shapes} <= ids
    groups = [s.group for s in hairy.hair_shapes]  # one BSDF for each small group
    assert groups.count("scalp") == MELANIN_BUCKETS and groups.count("brows") == 1 == \
        groups.count("lashes")
    # the bald path: no kwarg and hair=None build the same scene and render the same pixels
    topo, v, _ = head_model
    cam = cameras.orbit(32, 32, 85.0, 0.0, 5.0)
    # (the box filter: the Gaussian one adds samples into neighbouring pixels from several
    # threads in no fixed order, and once in CI 98 of 4,096 values differed by 1.2e-7)
    rs = RenderSettings(32, 32, 2, pixel_filter="box")
    a = HeadScene(topo, v, lights.preset("studio"), cam, rs).render()
    b = HeadScene(topo, v, lights.preset("studio"), cam, rs, hair=None).render()
    np.testing.assert_array_equal(a, b)


def _hair_pixels(head, k=3):
    out = head.label_pass(k, np.arange(len(REGIONS), dtype=np.uint32), np.zeros((4, 8), np.uint32),
                          num_labels=len(REGIONS))
    return out


def test_04_melanin_0_renders_near_white_and_8_near_black(head_model, groom):
    """Mean colour over pixels wholly covered by hair, seen from behind (the back of the
    head, where the scalp hair covers the skin)."""
    means = {}
    for eu in (0.0, 8.0):
        head = _scene(head_model, _coloured(groom, eu), yaw=180.0, pitch=30.0, spp=8)
        img = head.render(backdrop=False)
        cov = _hair_pixels(head)["coverage"][..., HAIR]
        sel = cov > 0.95
        assert sel.sum() > 60, sel.sum()
        means[eu] = img[sel, :3].mean(0)
    # measured: 0.160, 0.140, 0.132 and 0.016-0.019, 0.015-0.017, 0.014-0.016 (8 spp; the
    # roulette on hair, HAIR_RR, leaves black hair's mean but not its noise as it was)
    white, black = means[0.0], means[8.0]
    assert white.min() > 5 * black.max(), means
    assert white.max() / white.min() < 1.25, white  # grey to white, not tinted
    assert black.max() < 0.05, black


def test_05_segmentation_hair_class_matches_strand_coverage(head_model, groom):
    """With the head's meshes moved out of sight the film's alpha is the strands' coverage
    alone; the label pass's hair coverage (and its pixel-centre segmentation) matches it."""
    head = _scene(head_model, groom, yaw=30.0, spp=16)
    for part in head.parts:
        key = f"{part.name}.vertex_positions"
        p = np.asarray(head.params[key]).reshape(-1, 3) + np.array([0.0, 0.0, -50.0])
        head.params[key] = mi.Float(p.ravel().astype(np.float32))
    head.params.update()
    alpha = head.render(backdrop=False)[..., 3]
    out = _hair_pixels(head, k=4)
    cov = out["coverage"][..., HAIR]
    assert cov.sum() > 200
    # strands are thinner than a pixel: compare soft masks (measured: soft IoU 0.80,
    # correlation 0.96, coverage sums within 1 %; at 64 spp and 8 x 8 rays 0.99 correlation)
    iou = np.minimum(alpha, cov).sum() / np.maximum(alpha, cov).sum()
    assert iou > 0.72, iou
    assert np.corrcoef(alpha.ravel(), cov.ravel())[0, 1] > 0.92
    assert cov.sum() == pytest.approx(alpha.sum(), rel=0.05)
    seg = out["segmentation"]
    assert set(np.unique(seg)) <= {0, HAIR}
    depth = out["depth"][seg == HAIR]
    assert (depth > 0.7).all() and (depth < 1.3).all()  # the camera is ~1 m away


def test_06_set_vertices_moves_the_strands(head_model, groom):
    head = _scene(head_model, groom)
    sh = head.hair_shapes[0]
    before = np.asarray(head.params[f"{sh.id}.control_points"]).reshape(-1, 4)
    # Mitsuba keeps the control points in the file's order
    expect = control_points(head._pose_hair(head._vertices)[sh.group][sh.strands],
                            groom.group(sh.group).radius).reshape(-1, 4)
    np.testing.assert_allclose(before, expect, atol=1e-6)
    seg0 = head.aovs()["segmentation"]
    shift = np.array([0.03, 0.0, 0.0])
    head.set_vertices(head_model[1] + shift)
    after = np.asarray(head.params[f"{sh.id}.control_points"]).reshape(-1, 4)
    np.testing.assert_allclose(after[:, :3] - before[:, :3], np.broadcast_to(shift, before[:, :3].shape),
                               atol=2e-4)
    seg1 = head.aovs()["segmentation"]
    x0 = np.nonzero(seg0 == HAIR)[1].mean()
    x1 = np.nonzero(seg1 == HAIR)[1].mean()
    assert x1 - x0 > 1.0  # +x of the model is the image's right from the front


def run(args):
    try:
        main(args)
    except SystemExit as exit_:
        return exit_.code
    return 0


def test_07_cli_hair_options(tmp_path, capsys):
    out = str(tmp_path / "h.png")
    assert run(["render", "-o", out, "--hair", "mohawk"]) == 2
    assert "--hair: expected a style name" in capsys.readouterr().err
    assert run(["render", "-o", out, "--hair", "short", "--hair-color", "green"]) == 2
    assert "--hair-color" in capsys.readouterr().err
    assert run(["render", "-o", out, "--hair-color", "red"]) == 2
    assert "no hair to colour" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"archetype": "long", "lenght": 0.2}')
    assert run(["turntable", "-o", str(tmp_path / "tt"), "--hair", str(bad)]) == 2
    assert "unknown key(s) lenght" in capsys.readouterr().err
    params = tmp_path / "p.yaml"
    params.write_text("hair:\n  archetype: crew\n  lod: 0.05\n  beard: none\n")
    assert run(["render", "-o", out, "--params", str(params), "--hair-color", "black",
                "--resolution", "32", "--spp", "2", "--denoise", "off", "--no-sss",
                "--quiet"]) == 0
    assert (tmp_path / "h.png").is_file()


def test_08_hair_style_resolution(tmp_path):
    assert hair_style(None, None) is None
    assert hair_style("none", None, {"archetype": "long"}) is None  # the flag wins
    assert hair_style(None, None, {"archetype": "long"}).archetype == "long"
    assert hair_style(None, None, None, default="short").archetype == "short"
    s = hair_style("bald", "1.5,0.2")
    assert s.bald and (s.eumelanin, s.pheomelanin) == (1.5, 0.2)
    f = tmp_path / "h.yaml"
    f.write_text("hair: {archetype: afro, color: red}\nbeta: [0.5]\n")
    s = hair_style(str(f), None)
    assert s.archetype == "afro" and (s.eumelanin, s.pheomelanin) == (0.5, 1.6)


def test_09_any_hit_shadows_without_cards_render_the_same_image(head_model, groom):
    """With strand lashes there are no null surfaces: hack_path's shadow rays become
    any-hit tests (``null_surfaces`` false), which must see what the closest-hit loop
    through null surfaces sees."""
    head = _scene(head_model, groom, res=48, spp=4, yaw=30.0)
    assert head.scene.integrator().null_surfaces is False
    split = split_integrator(head)  # render(sss=True)'s: the same settings
    assert split.null_surfaces is False and split.rr_depth == HAIR_RR_DEPTH
    loop = mi.load_dict({"type": "hack_path", "max_depth": head.settings.max_depth,
                         "hide_emitters": True, "rr_depth": HAIR_RR_DEPTH,
                         "hair_rr": HAIR_RR})
    a = head.render_passes(3, False)
    b = head.render_passes(3, False, integrator=loop)
    assert np.abs(a - b).max() < 1e-3, np.abs(a - b).max()
    assert _scene(head_model, None, res=16, spp=1).scene.integrator().null_surfaces is True


def _hack_path(head, **kw):
    return mi.load_dict({"type": "hack_path", "max_depth": head.settings.max_depth,
                         "hide_emitters": True, **head.integrator_extra, **kw})


def test_10_hair_roulette_and_budget_leave_a_hair_free_scene_unchanged(head_model, groom):
    """hack_path's hair handling keys on the hair BSDF's glossy transmission: in a
    HeadScene the hair shapes' BSDFs have it and no other; so a scene without hair renders
    bit for bit the same with the roulette on hair and a budget of one hair event."""
    head = _scene(head_model, groom, res=16, spp=1)
    for sh in head.scene.shapes():
        hair = sh.id().startswith("hair_")
        assert mi.has_flag(sh.bsdf().flags(), mi.BSDFFlags.GlossyTransmission) == hair, sh.id()
    assert head.integrator_extra["hair_rr"] is HAIR_RR is True
    bald = _scene(head_model, None, res=32, spp=4)
    assert not any(mi.has_flag(sh.bsdf().flags(), mi.BSDFFlags.GlossyTransmission)
                   for sh in bald.scene.shapes())
    a = bald.render_passes(5, False, integrator=_hack_path(bald))
    b = bald.render_passes(5, False, integrator=_hack_path(bald, hair_rr=True, hair_depth=1))
    assert a[..., 3].sum() > 100 and np.array_equal(a, b)


def test_11_hair_roulette_is_unbiased_and_the_budget_cuts_paths_on_hair(head_model, groom):
    """On light hair (eumelanin 0.3: most of its light is scattered between strands), the
    roulette from the first hair event changes the samples but not their mean over the
    hair; a budget of one hair event drops the light of longer paths in the hair (darker
    there: a path ends at its first strand)."""
    head = _scene(head_model, _coloured(groom, 0.3), res=40, spp=256)
    seg = head.aovs()["segmentation"]
    hair = seg == HAIR
    assert hair.sum() > 50
    base = head.render_passes(7, False, integrator=_hack_path(head, hair_rr=False))
    rr = head.render_passes(7, False, integrator=_hack_path(head, hair_rr=True))
    cut = head.render_passes(7, False, integrator=_hack_path(head, hair_rr=False, hair_depth=1))
    mean = {k: float(im[..., :3][hair].mean()) for k, im in
            (("base", base), ("rr", rr), ("cut", cut))}
    assert not np.array_equal(base, rr)
    assert abs(mean["rr"] / mean["base"] - 1.0) < 0.12, mean
    assert mean["cut"] < 0.6 * mean["base"], mean
