"""Dataset hair (issue 61): each person's HairStyle sampled from its own stream, written to
sample.json and params.json; the ``hair`` class, its soft mask and its depth."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from hack_render.dataset import labels as lab
from hack_render.dataset.config import load_config
from hack_render.dataset.runner import Job, run
from hack_render.dataset.sampling import pool_entries, sample_spec
from hack_render.errors import HackError
from hack_render.hair.style import ARCHETYPES, BEARDS, COLOUR_FIELDS, HairStyle

#: 40 px, few strands: the hair's paths, not its looks; 3 x 3 mask rays (odd: the pixel
#: centre, where the label is taken, is one of them)
TINY = {"render": {"resolution": 40, "spp": 2, "soft_mask_samples": 3},
        "appearance": {"height": 32}, "lighting": {"presets": ["studio", "window"]},
        "hair": {"style": "sampled", "lod": 0.05}}


@pytest.fixture(scope="module")
def au_names():
    from hack_render.geometry import load_default_model

    return load_default_model().au_names


def tree(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


# --- sampling -------------------------------------------------------------------------
def test_hair_is_a_pure_function_of_seed_and_index(au_names):
    cfg = load_config()
    a = [sample_spec(cfg, 4, i, au_names)["hair"] for i in (3, 8)]
    b = [sample_spec(cfg, 4, i, au_names)["hair"] for i in (8, 3)][::-1]
    assert a == b and a[0] != a[1]
    assert a[0] != sample_spec(cfg, 5, 3, au_names)["hair"]
    # a full style, read back as it was written, at the config's level of detail
    style = HairStyle.from_dict(a[0])
    assert style.to_dict() == a[0] and style.lod == cfg["hair"]["lod"]


def test_hair_has_its_own_stream(au_names):
    """Changing the hair config changes no other draw; changing another section leaves the
    hair as it was."""
    base = sample_spec(load_config(), 2, 6, au_names)
    for hair in ("none", "afro", {"style": {"archetype": "bob", "color": "red"}},
                 {"lod": 0.6}):
        other = sample_spec(load_config(overrides={"hair": hair}), 2, 6, au_names)
        assert {k: v for k, v in other.items() if k != "hair"} == \
            {k: v for k, v in base.items() if k != "hair"}
    moved = sample_spec(load_config(overrides={"camera": {"yaw_deg": [1, 2]}}), 2, 6, au_names)
    assert moved["hair"] == base["hair"]


def test_hair_options(au_names):
    def hair(override, i=0):
        return sample_spec(load_config(overrides={"hair": override}), 1, i, au_names)["hair"]

    assert hair("none") is None and hair(None) is None and hair({"style": "none"}) is None
    drawn = hair("sampled")
    # an archetype: everyone has it, with its defaults; colour, brows, beard still drawn
    afro = hair("afro")
    assert afro["archetype"] == "afro" and afro["curl"] == 0.95
    for k in ("eumelanin", "brow_arch", "beard", "seed", "hairline"):
        assert afro[k] == drawn[k], k
    # a mapping: one style for everyone, each with their own strands (seed)
    fixed = [hair({"style": {"archetype": "long", "color": "blonde"}, "lod": 0.2}, i)
             for i in (0, 1)]
    assert all(f["archetype"] == "long" and f["eumelanin"] == 0.3 and f["lod"] == 0.2
               for f in fixed)
    assert fixed[0]["seed"] != fixed[1]["seed"]
    assert hair({"style": {"archetype": "bun", "seed": 9, "lod": 0.7}})["seed"] == 9
    assert hair({"style": {"archetype": "bun", "seed": 9, "lod": 0.7}})["lod"] == 0.7
    # the sampler reaches every archetype and beard
    cfg = load_config()
    styles = [sample_spec(cfg, 0, i, au_names)["hair"] for i in range(300)]
    assert set(Counter(s["archetype"] for s in styles)) == set(ARCHETYPES)
    assert len({s["beard"] for s in styles}) == 4


def test_pooled_grooms_keep_each_persons_archetype_beard_and_colour(au_names):
    """``hair.pool``: everyone keeps the archetype, beard and colour of their own draw
    (``pool: 0``'s); their strands are one of ``pool_entries`` draws for that pair, so a
    dataset has at most their sum of grooms, shared by people of different colours."""
    own = load_config(overrides={"hair": {"pool": 0}})
    pooled = load_config(overrides={"hair": {"pool": 8}})
    shapes: dict = {}
    own_shapes = set()
    for i in range(150):
        a = HairStyle.from_dict(sample_spec(own, 3, i, au_names)["hair"])
        b = HairStyle.from_dict(sample_spec(pooled, 3, i, au_names)["hair"])
        for k in ("archetype", "beard", "lod", *COLOUR_FIELDS):
            assert getattr(a, k) == getattr(b, k), (i, k)
        shapes.setdefault((b.archetype, b.beard), {}).setdefault(b.uncoloured(), []).append(b)
        own_shapes.add(a.uncoloured())
    assert len(own_shapes) == 150  # pool 0: everyone's own strands
    assert all(len(v) <= pool_entries(8, *k) for k, v in shapes.items())
    assert sum(len(v) for v in shapes.values()) <= sum(
        pool_entries(8, a, b) for a in ARCHETYPES for b in BEARDS) < 60
    shared = [people for v in shapes.values() for people in v.values() if len(people) > 1]
    assert len(shared) > 10
    assert all(len({p.eumelanin for p in people}) == len(people) for people in shared)
    assert pool_entries(32, "short", "none") == 4 and pool_entries(32, "afro", "goatee") == 1


def test_the_run_says_what_hair_it_draws():
    """The dataset's first line names the hair and the pool (issue 65: what runs is said)."""
    from hack_render.dataset.runner import hair_summary

    assert hair_summary(load_config()) == \
        "; hair sampled at lod 0.5, strands from at most 47 pooled grooms (hair.pool 32)"
    assert hair_summary(load_config(overrides={"hair": {"pool": 0, "lod": 0.3}})) == \
        "; hair sampled at lod 0.3, everyone's own strands (hair.pool 0)"
    assert hair_summary(load_config(overrides={"hair": "none"})) == "; no hair"


@pytest.mark.parametrize("override,match", [
    ("mohawk", "hair.style"),
    ({"style": {"archetype": "mohawk"}}, "hair.style"),
    ({"style": {"curl": 3}}, "hair.style"),
    ({"style": 3}, "hair.style"),
    ({"lod": 0}, "hair.lod"),
    ({"lod": "high"}, "hair.lod"),
    ({"archetype": "long"}, "hair.archetype"),
    ({"pool": -1}, "hair.pool"),
    ({"pool": 2.5}, "hair.pool"),
])
def test_bad_hair_config_names_the_key(override, match):
    with pytest.raises(HackError, match=match.replace(".", r"\.")):
        load_config(overrides={"hair": override})


def test_hair_shorthand_in_a_config_file(tmp_path):
    f = tmp_path / "d.yaml"
    f.write_text("hair: none\n")
    assert load_config(f)["hair"] == {"style": "none", "lod": 0.5, "pool": 32}
    f.write_text("hair: {style: crew, lod: 0.3}\n")
    assert load_config(f)["hair"] == {"style": "crew", "lod": 0.3, "pool": 32}


# --- rendering ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def hair_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("dsh") / "hair"
    cfg = load_config(overrides=TINY)
    run(Job(out, 3, 3, cfg), progress=False)
    return out, cfg


def _view(out, i):
    import imageio.v3 as iio

    from hack_render.io.image import read_exr

    v = out / "samples" / f"{i:07d}" / "view_00"
    return (iio.imread(v / "segmentation.png"), read_exr(v / "masks.exr"),
            read_exr(v / "depth.exr")["Z"])


def test_hair_metadata_is_written(hair_set, au_names):
    out, cfg = hair_set
    for i in range(3):
        folder = out / "samples" / f"{i:07d}"
        rec = json.loads((folder / "sample.json").read_text())
        params = json.loads((folder / "params.json").read_text())
        want = sample_spec(cfg, 3, i, au_names)["hair"]
        assert rec["hair"] == params["hair"] == want
        assert HairStyle.from_dict(params["hair"]).to_dict() == want
    info = json.loads((out / "config.json").read_text())
    assert info["config"]["hair"] == {"style": "sampled", "lod": 0.05, "pool": 32}
    assert info["labels"][-1]["name"] == "hair"


def test_hair_class_mask_and_depth(hair_set):
    """The hair class is drawn; its soft mask is the strands' coverage and agrees with the
    label: at least the centre ray's 1/9 wherever the label is hair, and summing to about
    the labelled pixels; the strands have depth."""
    out, _ = hair_set
    hid = lab.LABEL_ID["hair"]
    total_seg = total_mask = 0.0
    for i in range(3):
        seg, masks, depth = _view(out, i)
        m = masks["mask.hair"]
        hair = seg == hid
        stack = np.stack([masks[f"mask.{n}"] for n in lab.LABELS], -1)
        assert np.allclose(stack.sum(-1), 1.0, atol=1e-5)
        assert (m[hair] >= 1 / 9 - 1e-6).all()
        assert (depth[hair] > 0.2).all()
        total_seg += hair.sum()
        total_mask += m.sum()
    assert total_seg >= 20
    assert abs(total_mask - total_seg) <= 0.3 * total_seg


def test_hair_samples_do_not_depend_on_order(hair_set, tmp_path):
    """Sample 2 rendered alone (shard 2/3) has the same bytes as after samples 0 and 1:
    the scene rebuilt around each sample's groom depends on that sample alone."""
    out, cfg = hair_set
    run(Job(tmp_path, 3, 3, cfg, shard=(2, 3)), progress=False)
    alone = {k: v for k, v in tree(tmp_path / "samples").items()}
    full = {k: v for k, v in tree(out / "samples").items() if k.startswith("0000002")}
    assert alone == full


def test_no_hair_means_no_hair_class(tmp_path):
    cfg = load_config(overrides=dict(TINY, hair="none"))
    run(Job(tmp_path, 1, 3, cfg), progress=False)
    seg, masks, _ = _view(tmp_path, 0)
    assert not (seg == lab.LABEL_ID["hair"]).any() and masks["mask.hair"].max() == 0
    assert (seg == lab.LABEL_ID["eyelashes"]).any() or \
        masks["mask.eyelashes"].max() > 0  # the lash cards are back
    params = json.loads((tmp_path / "samples" / "0000000" / "params.json").read_text())
    assert params["hair"] is None


def test_a_folder_made_before_hair_is_refused_with_the_reason(hair_set, tmp_path):
    from hack_render.dataset.runner import check_job, run_info

    _, cfg = hair_set
    info = json.loads(json.dumps(run_info(Job(tmp_path, 2, 0, cfg))))
    del info["config"]["hair"]
    info["labels"] = info["labels"][:-1]
    (tmp_path / "config.json").write_text(json.dumps(info))
    with pytest.raises(HackError, match="before the hair layer"):
        check_job(Job(tmp_path, 2, 0, cfg))


def test_cli_hair_option(tmp_path):
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "hack_render.cli", "dataset", "--n", "1", "-o",
           str(tmp_path / "o"), "--hair", "mohawk"]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert r.returncode == 2 and "hair.style" in r.stderr and "afro" in r.stderr


def test_hair_samples_swap_their_grooms_into_the_presets_scenes(tmp_path, monkeypatch):
    """With hair the presets' scenes hold hair slots and each sample's groom is swapped in
    (``HeadScene.set_hair``): one scene a preset, not one a sample, and no groom goes
    the rebuilt-scene way (its files are checked against the order-free run above)."""
    from hack_render.render.scene import HeadScene

    built, swapped = [], []
    init, set_hair = HeadScene.__init__, HeadScene.set_hair

    def counting_init(self, *a, **kw):
        built.append(bool(kw.get("hair_slots")))
        init(self, *a, **kw)

    def counting_set_hair(self, groom, **kw):
        swapped.append(groom.style.archetype)
        set_hair(self, groom, **kw)

    monkeypatch.setattr(HeadScene, "__init__", counting_init)
    monkeypatch.setattr(HeadScene, "set_hair", counting_set_hair)
    cfg = load_config(overrides=TINY)
    run(Job(tmp_path / "ds", 4, 3, cfg), progress=False)
    assert len(swapped) == 4
    assert all(built) and len(built) <= len(TINY["lighting"]["presets"])
