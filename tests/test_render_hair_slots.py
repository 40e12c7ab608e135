"""Hair slots (issue 65, datasets with hair): a scene built with ``hair_slots`` takes any
groom with lashes in place (``HeadScene.set_hair``) and renders, to the bit, what a scene
built around that groom renders; the empty slots' placeholder strands are never seen."""

from dataclasses import replace

import numpy as np
import pytest

from hack_render.render.engine import ensure_variant

ensure_variant()

import drjit as dr
import mitsuba as mi

from hack_render.errors import HackError
from hack_render.hair.groom import grow_cached
from hack_render.hair.style import HairStyle
from hack_render.render.hair_shapes import (
    PREFIX,
    control_points,
    hair_shapes,
    needed_segments,
    padding_points,
    segment_indices,
    slot_capacity,
    slot_content,
    slot_ids,
    slots_take,
    write_curves,
)
from hack_render.render.parts import REGIONS
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights

RES = 48


@pytest.fixture(scope="module")
def head_model(hair_head_model):
    return hair_head_model


@pytest.fixture(scope="module")
def grooms(head_model):
    """Two grooms of different layouts: short, one colour; long with a full beard and
    greying (a white bucket in the scalp and the beard), darker."""
    surf = head_model[2]
    a = grow_cached(surf, HairStyle.archetype_style("short", lod=0.1, variation=0.0, greying=0.0))
    b = grow_cached(surf, HairStyle.archetype_style("long", lod=0.1, greying=0.4, beard="full",
                                                    eumelanin=3.0))
    return a, b


def _scene(head_model, groom, vertices=None, **kw):
    topo, v, _ = head_model
    cam = cameras.orbit(RES, RES, 85.0, 35.0, 5.0)
    return HeadScene(topo, v if vertices is None else vertices, lights.preset("studio"), cam,
                     RenderSettings(RES, RES, 2, pixel_filter="box"), hair=groom, **kw)


def _labels(head):
    return head.label_pass(3, np.arange(len(REGIONS), dtype=np.uint32),
                           np.zeros((4, 8), np.uint32), num_labels=len(REGIONS))["coverage"]


def test_01_set_hair_renders_what_a_scene_built_around_the_groom_renders(head_model, grooms):
    a, b = grooms
    ids_b = {s.id for s in hair_shapes(b)}
    assert {"hair_beard_0", "hair_scalp_0"} <= ids_b  # b fills slots a leaves empty
    assert len(ids_b) > len(hair_shapes(a))
    cap = slot_capacity(b, 1.2, slot_capacity(a))
    head = _scene(head_model, a, hair_slots=cap)
    assert [s.id() for s in head.scene.shapes() if s.id().startswith(PREFIX)] == slot_ids()
    first = head.render()
    for groom in (b, a):  # a new layout, then back
        head.set_hair(groom)
        fresh = _scene(head_model, groom, hair_slots=cap)
        np.testing.assert_array_equal(head.render(), fresh.render())
        np.testing.assert_array_equal(_labels(head), _labels(fresh))
        assert head.scene.bbox() == fresh.scene.bbox()
        for sid, n in cap.items():  # every slot keeps its segment count
            assert dr.width(head.params[f"{sid}.segment_indices"]) == n
        # and against a scene without slots (earlier versions'): the padding's segments are
        # invalid (NaN), dropped by Embree, so the pixels are the same
        plain = _scene(head_model, groom)
        np.testing.assert_array_equal(_labels(head), _labels(plain))
        assert head.scene.bbox() == plain.scene.bbox()
        np.testing.assert_array_equal(head.render(), plain.render())
    np.testing.assert_array_equal(head.render(), first)
    assert np.abs(first - _scene(head_model, b).render()).mean() > 0.01  # a and b differ


def test_02_set_hair_then_set_vertices_poses_the_new_groom_once(head_model, grooms, monkeypatch):
    """The dataset's order: set_hair posed on the sample's vertices (or given them posed),
    then set_vertices to those vertices finds them posed; the pixels are those of a plain
    scene moved to the same vertices."""
    from hack_render.render import scene_hair as scene_mod  # where the scene poses

    a, b = grooms
    v2 = head_model[1] + np.array([0.01, -0.005, 0.0])
    cap = slot_capacity(b, 1.0, slot_capacity(a))
    head = _scene(head_model, a, hair_slots=cap)
    plain = _scene(head_model, b, hair_slots=cap)
    calls = []
    real = scene_mod.pose_groom
    monkeypatch.setattr(scene_mod, "pose_groom", lambda g, v: calls.append(1) or real(g, v))
    head.set_hair(b, vertices=v2, update=False)
    head.set_vertices(v2)
    assert len(calls) == 1
    plain.set_vertices(v2)
    np.testing.assert_array_equal(head.render(), plain.render())
    posed = real(a, v2)
    head.set_hair(a, vertices=v2, hair_posed=posed, update=False)
    head.set_vertices(v2)
    assert len(calls) == 2  # plain's own posing of v2; none for the given posed strands


def test_03_what_set_hair_refuses(head_model, grooms):
    a, b = grooms
    no_lashes = replace(a, groups=[g for g in a.groups if g.name != "lashes"])
    assert slots_take(a) and not slots_take(no_lashes)
    bald = _scene(head_model, None)
    assert bald.hair_slots == {} and not bald.takes_hair(a)
    with pytest.raises(HackError, match="hair_slots=True"):
        bald.set_hair(a)
    slotted = _scene(head_model, None, hair_slots=slot_capacity(a))
    assert "eyelashes" not in {s.id() for s in slotted.scene.shapes()}
    assert slotted.takes_hair(a) and not slotted.takes_hair(no_lashes)
    assert not slotted.takes_hair(None)
    assert not slotted.takes_hair(b)  # the long groom needs more segments than a's slots
    with pytest.raises(HackError, match="fits the slots"):
        slotted.set_hair(b)
    with pytest.raises(HackError, match="lashes"):
        slotted.set_hair(no_lashes)
    with pytest.raises(HackError, match="lashes"):
        _scene(head_model, no_lashes, hair_slots=True)


def test_04_empty_slots_are_never_seen(head_model):
    """A slotted scene without a groom: no pixel, sub-pixel ray or depth meets the
    placeholder strands (the hair label's coverage is 0 everywhere)."""
    head = _scene(head_model, None, hair_slots=True)
    cov = _labels(head)
    assert cov[..., REGIONS.index("hair")].max() == 0.0
    assert cov.sum() > 0.1 * RES * RES  # the head itself is there


def test_05_segment_indices_are_what_the_curve_file_loads(tmp_path):
    pts = np.cumsum(np.random.default_rng(1).normal(size=(3, 5, 3)), 1) * 1e-3
    cp = control_points(pts, np.full(5, 1e-4))
    path = tmp_path / "c.txt"
    write_curves(path, cp)
    shape = mi.load_dict({"type": "linearcurve", "filename": str(path)})
    params = mi.traverse(shape)
    np.testing.assert_array_equal(np.asarray(params["segment_indices"]),
                                  segment_indices(3, cp.shape[1]))
    # the file holds float32 to the bit: loading it equals writing the points
    np.testing.assert_array_equal(np.asarray(params["control_points"]), cp.ravel())


def test_06_slot_capacity_and_content(grooms):
    """Every slot of a group gets the same room (strands move between a group's melanin
    buckets), at least what was asked before; a slot's content is its strands then one
    padding strand, its segment count the capacity exactly."""
    _, b = grooms
    need = needed_segments(b)
    cap = slot_capacity(b, 1.5, {"hair_scalp_0": 10 ** 7})
    for g in ("scalp", "brows", "lashes", "beard"):
        ids = [k for k in cap if k.startswith(f"hair_{g}_")]
        assert len({cap[k] for k in ids}) == 1
        assert cap[ids[0]] >= max(1, 1.5 * max(need[k] for k in ids))
    assert cap["hair_scalp_2"] == 10 ** 7
    assert sum(need.values()) == sum(len(sh.strands) * (min(b.group(sh.group).points_per_strand,
                                     12) - 1) for sh in hair_shapes(b))
    cp = np.zeros((3, 4, 4), np.float32)
    cp[..., 3] = 1e-4
    points, index = slot_content(cp, 20, [0.0, 0.1, 0.0])
    assert len(index) == 20 and len(points) == 12 + 12  # 11 padding segments
    np.testing.assert_array_equal(index[:9], segment_indices(3, 4))
    np.testing.assert_array_equal(index[9:], np.arange(12, 23))
    pad = points[12:]  # one point at the centre, then NaN: segments Embree drops
    np.testing.assert_array_equal(pad[0, :3], np.float32([0.0, 0.1, 0.0]))
    assert np.isnan(pad[1:, :3]).all() and pad[:, 3].max() <= 1e-9
    valid = padding_points([0.0, 0.1, 0.0], 11, invalid=False)  # a curve file's
    assert np.abs(valid[:, :3] - [0.0, 0.1, 0.0]).max() <= 1.01e-6
    _, idx = slot_content(None, 5, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(idx, np.arange(5))
    with pytest.raises(ValueError, match="cannot hold"):
        slot_content(cp, 8, [0.0, 0.0, 0.0])


def test_07_labels_continue_rays_only_where_the_scene_has_lash_cards(head_model, grooms,
                                                                      monkeypatch):
    """A scene with hair strands has no lash cards (the see-through region): its label pass
    continues no ray past its first hit (one camera_hit where it traced two, the second
    masked off everywhere) and gives the same labels, coverage and G-buffer, to the bit,
    as the pass that continues the rays where a card is hit (none here)."""
    from hack_render.render import aov

    head = _scene(head_model, grooms[1])
    lashes = REGIONS.index("eyelashes")
    assert lashes not in {reg for reg, _, _ in head._shape_regions.values()}
    calls = []
    real = aov.camera_hit
    monkeypatch.setattr(aov, "camera_hit", lambda *a, **k: calls.append(1) or real(*a, **k))
    lean = head.label_pass(3, np.arange(len(REGIONS), dtype=np.uint32),
                           np.zeros((4, 8), np.uint32), num_labels=len(REGIONS))
    assert len(calls) == 1
    # the same pass as if the scene had a lash card (a shape id no ray meets)
    monkeypatch.setattr(head, "_shape_regions",
                        {**head._shape_regions, 2 ** 20: (lashes, 0.0, 1.0)})
    full = head.label_pass(3, np.arange(len(REGIONS), dtype=np.uint32),
                           np.zeros((4, 8), np.uint32), num_labels=len(REGIONS))
    assert len(calls) == 3
    assert lean.keys() == full.keys()
    for key in lean:
        np.testing.assert_array_equal(lean[key], full[key], err_msg=key)
    assert (lean["segmentation"] == REGIONS.index("hair")).sum() > 20
