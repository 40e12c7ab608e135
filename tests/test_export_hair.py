"""Hair in the rigged glTF (issue 61): strands as alpha-textured cards, skinned with the
head. The file, read back by the reference evaluator, keeps every card's root row on the
posed skin at rest and at every animation frame (expressions, a head turn, the larynx);
each card vertex's skin weights are its root triangle's barycentric blend and sum to 1;
the procedural strand texture has gaps in its alpha; the Khronos validator finds no
errors; trimesh loads the file; `export --hair` and `--hair-color` take styles, files and
colours, and refuse bad ones with exit 2."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hack_render.cli import main
from hack_render.errors import HackError
from hack_render.export import rig as R
from hack_render.export.hair_cards import (
    HAIR_ALPHA_CUTOFF,
    blend,
    build_cards,
    groom_for,
    hair_style,
    melanin_rgb,
)
from hack_render.export.person import export_person
from hack_render.export.reference import accessor, evaluate, evaluate_primitives, read_gltf
from hack_render.geometry import load_default_model
from hack_render.geometry.params import ParamSequence, check_params
from hack_render.hair.style import HairStyle
from hack_render.render.hair_options import hair_style as render_hair_style

PARAMS = {"beta": [0.8, -1.2, 0.5], "expression": "AU12=0.6,jawOpen=0.25",
          "head_rotation_deg": [8, 25, -3], "eta": 1.3, "tau": 0.004}
STYLE = HairStyle.archetype_style("short", beard="goatee", lod=0.08, eumelanin=1.3,
                                  greying=0.2)
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def model():
    return load_default_model()


@pytest.fixture(scope="module")
def sequence(model):
    """3 frames: rest, brows up with the jaw open and the head turned, a larynx slide."""
    names = list(model.expression_names)
    psi = np.zeros((3, model.num_expressions))
    for name in ("browInnerUp_L", "browInnerUp_R", "browOuterUp_L", "browOuterUp_R"):
        psi[1, names.index(name)] = 1.0
    psi[1, names.index("jawOpen")] = 0.8
    theta = np.zeros((3, 8, 3))
    theta[1, 7] = [0.2, 0.5, -0.1]
    theta[2, 3] = [-0.15, 0.0, 0.1]
    return ParamSequence(fps=10.0, theta=theta, psi=psi, tau=np.array([0.0, 0.005, -0.01]),
                         global_orient=np.zeros((3, 3)), transl=np.zeros((3, 3)))


@pytest.fixture(scope="module")
def exported(model, sequence, tmp_path_factory):
    folder = tmp_path_factory.mktemp("hair")
    p = check_params(PARAMS)
    out = {}
    for name, inf in (("h8.glb", 8), ("h4.gltf", 4)):
        out[name] = (folder / name,
                     export_person(model, p, folder / name, sequence, None, inf, STYLE))
    return out


@pytest.fixture(scope="module")
def cards(model):
    rig = R.build_rig(model, np.asarray([PARAMS["beta"]]), PARAMS["eta"])
    return rig, build_cards(groom_for(model, STYLE), rig.base, model.faces.numpy(), STYLE.seed)


def _hair_prims(doc):
    return [(i, p) for i, p in enumerate(doc["meshes"][0]["primitives"]) if "hair" in
            p.get("extras", {})]


def test_file_holds_one_card_primitive_per_group_with_every_morph_target(exported, cards):
    path, rep = exported["h8.glb"]
    doc, buf = read_gltf(path)
    prims = _hair_prims(doc)
    names = [p["extras"]["hair"] for _, p in prims]
    assert names == [c.name for c in cards[1]] == ["scalp", "brows", "lashes", "beard"]
    assert rep["hair"]["groups"]["scalp"]["cards"] == cards[1][0].num_cards > 50
    n_targets = len(doc["meshes"][0]["extras"]["targetNames"])
    for (_, p), c in zip(prims, cards[1], strict=True):
        assert len(p["targets"]) == n_targets  # glTF: every primitive has the mesh's targets
        np.testing.assert_allclose(accessor(doc, buf, p["attributes"]["POSITION"]),
                                   c.positions, atol=1e-6)  # the same cards, rebuilt
        mat = doc["materials"][p["material"]]
        assert mat["alphaMode"] == "MASK" and mat["doubleSided"] is True
        assert mat["extras"]["hack"]["procedural"] is True
    # the strands' lashes replace the model's eyelash cards
    assert "eyelashes" not in {m["name"] for m in doc["materials"]}
    assert doc["asset"]["extras"]["hack"]["hair"]["style"]["archetype"] == "short"


@pytest.mark.parametrize("frame", [None, 0, 1, 2])
def test_card_roots_stay_on_the_posed_skin(model, exported, cards, frame):
    """The first row of every card is within 1 mm of its skin point, at rest and in every
    frame (brows raised, jaw open, head turned, larynx slid)."""
    path, _ = exported["h8.glb"]
    faces = model.faces.numpy()
    skin = evaluate(path, frame, model.num_vertices)
    doc, _ = read_gltf(path)
    posed = evaluate_primitives(path, frame)
    moved = {}
    for (i, _), c in zip(_hair_prims(doc), cards[1], strict=True):
        want = blend(skin, faces, c.tri[c.root], c.bary[c.root])
        assert np.isfinite(want).all()
        err = np.linalg.norm(posed[i][c.root] - want, axis=1)
        assert err.max() < 1e-3, f"{c.name}: a root {err.max() * 1e3:.2f} mm off the skin"
        moved[c.name] = posed[i][c.root]
    if frame == 1:  # the brows rode the expression: they moved against the skull's frame
        rest = evaluate_primitives(path, 0)
        brows = next(i for i, p in _hair_prims(doc) if p["extras"]["hair"] == "brows")
        assert np.linalg.norm(posed[brows] - rest[brows], axis=1).max() > 2e-3


@pytest.mark.parametrize("name, influences", [("h8.glb", 8), ("h4.gltf", 4)])
def test_card_weights_are_the_root_triangles_blend(model, exported, cards, name, influences):
    path, _ = exported[name]
    doc, buf = read_gltf(path)
    full = model.skinning_weights.double().numpy()
    faces = model.faces.numpy()
    for (_, p), c in zip(_hair_prims(doc), cards[1], strict=True):
        at = p["attributes"]
        dense = np.zeros((len(c.positions), full.shape[1]))
        for s in range(influences // 4):
            j = accessor(doc, buf, at[f"JOINTS_{s}"]).astype(np.int64)
            w = accessor(doc, buf, at[f"WEIGHTS_{s}"])
            np.add.at(dense, (np.arange(len(j))[:, None].repeat(4, 1), j), w)
        np.testing.assert_allclose(dense.sum(1), 1.0, atol=1e-6)
        want = blend(full, faces, c.tri, c.bary)
        if influences == 4:  # kept to 4 as the head's are
            idx, w4 = R.top_weights(want, 4)
            want = np.zeros_like(want)
            np.add.at(want, (np.arange(len(idx))[:, None].repeat(4, 1), idx), w4)
        np.testing.assert_allclose(dense, want, atol=1e-6)


@pytest.mark.parametrize("archetype, beard", [("long", "none"), ("bun", "stubble"),
                                               ("afro", "full")])
def test_cards_have_unit_normals_and_few_rows(model, archetype, beard):
    """Long strands (cut and gathered at the bust), buns, coils and stubble give cards
    with unit normals at every vertex (the validator's ACCESSOR_VECTOR3_NON_UNIT) and at
    most MAX_ROWS rows."""
    from hack_render.export.hair_cards import MAX_ROWS

    style = HairStyle.archetype_style(archetype, beard=beard, lod=0.03)
    base = model.template.double().numpy()
    for c in build_cards(groom_for(model, style), base, model.faces.numpy()):
        np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-6)
        assert np.isfinite(c.positions).all()
        rows = len(c.positions) // (2 * c.num_cards)
        assert 2 <= rows <= MAX_ROWS


def test_strand_texture_has_gaps_and_melanin_colours(exported):
    import imageio.v3 as iio

    doc, buf = read_gltf(exported["h8.glb"][0])
    hair_images = [im for im in doc["images"] if im["name"].startswith("hair_")]
    assert len(hair_images) == 4 and all("procedural" in im["name"] for im in hair_images)
    for im in hair_images:
        bv = doc["bufferViews"][im["bufferView"]]
        png = iio.imread(io.BytesIO(buf[bv["byteOffset"]:bv["byteOffset"] + bv["byteLength"]]))
        assert png.shape[2] == 4
        alpha = png[..., 3] / 255.0
        gaps = (alpha < HAIR_ALPHA_CUTOFF).mean()
        assert 0.15 < gaps < 0.95, f"{im['name']}: {gaps:.0%} of the texels are gaps"
        assert (alpha[: len(alpha) // 4] >= HAIR_ALPHA_CUTOFF).mean() > 0.05  # strands at the root
    white, black = melanin_rgb(0.0, 0.0), melanin_rgb(8.0, 0.0)
    assert white.min() > 0.98 and black.max() < 0.05
    red = melanin_rgb(0.5, 1.6)
    assert red[0] > 2 * red[1] > 2 * red[2]  # pheomelanin reads red
    blonde, brown = melanin_rgb(0.3, 0.1), melanin_rgb(1.3, 0.1)
    assert (blonde > brown).all()


def _validator():
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        return None, "node/npm not installed (scripts/setup.sh --test)"
    root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True,
                          check=False).stdout.strip()
    if not (Path(root) / "gltf-validator").is_dir():
        return None, "npm package gltf-validator not installed (scripts/setup.sh --test)"
    return [node, str(HERE / "gltf_validate.js")], root


def test_khronos_validator_reports_no_errors(exported):
    cmd, root = _validator()
    if cmd is None:
        pytest.skip(root)
    files = [str(p) for p, _ in exported.values()]
    r = subprocess.run(cmd + files, capture_output=True, text=True, env={"NODE_PATH": root},
                       timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    for line in r.stdout.splitlines():
        rep = json.loads(line)
        assert rep["errors"] == 0, rep["messages"]


def test_trimesh_loads_the_cards(exported):
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.load(exported["h8.glb"][0], force="scene")
    verts = sum(len(g.vertices) for g in scene.geometry.values())
    hair = sum(g["vertices"] for g in exported["h8.glb"][1]["hair"]["groups"].values())
    assert len(scene.geometry) >= 4 and verts > hair


def test_hair_style_resolution(tmp_path):
    assert hair_style(None, None, None) is None  # no hair unless asked
    assert hair_style("none", None, {"archetype": "long"}) is None
    assert hair_style(None, None, {"archetype": "bob"}).archetype == "bob"
    s = hair_style("long", "red", {"archetype": "bob"})
    assert s.archetype == "long" and (s.eumelanin, s.pheomelanin) == (0.5, 1.6)
    assert hair_style("afro", "1.5,0.2", None).eumelanin == 1.5
    (tmp_path / "p.json").write_text(json.dumps({"beta": [1.0], "hair": {"archetype": "crew",
                                                                         "beard": "full"}}))
    (tmp_path / "h.yaml").write_text("archetype: bun\ncolor: blonde\n")
    assert hair_style(str(tmp_path / "p.json"), None, None).beard == "full"
    assert hair_style(str(tmp_path / "h.yaml"), None, None).archetype == "bun"
    # the options mean what they mean for render and turntable (one resolver: a spelling
    # render takes, export takes alike), but a bald style with no brows, lashes or beard
    # has no cards
    for args in (("LONG", "red", None), (None, "brown", {"archetype": "crew", "beard": "full"}),
                 (str(tmp_path / "h.yaml"), None, None), ("bald", None, None)):
        assert hair_style(*args) == render_hair_style(*args) is not None, args
    assert hair_style("off", None, {"archetype": "bob"}) is render_hair_style("off", None) is None
    bare = {"archetype": "bald", "brow_density": 0.0, "lash_length": 0.0}
    assert render_hair_style(None, None, bare).bald and hair_style(None, None, bare) is None
    for args, match in ((("mohawk", None, None), "--hair: expected a style name"),
                        (("short", "green", None), "--hair-color"),
                        ((None, "black", None), "--hair-color: no hair"),
                        (("none", "black", None), "--hair-color"),
                        ((str(tmp_path / "missing.json"), None, None), "file not found"),
                        ((None, None, {"lenght": 0.1}), "--params .*unknown key")):
        with pytest.raises(HackError, match=match):
            hair_style(*args)


def _run(args, capsys):
    code = 0
    try:
        main(args)
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize("extra, want", [
    (["--hair", "mohawk"], "--hair: expected a style name"),
    (["--hair", "short", "--hair-color", "green"], "--hair-color: hair colour"),
    (["--hair-color", "black"], "--hair-color: no hair to colour"),
    (["--hair", "short", "--obj"], "--hair: hair cards need a .glb or .gltf"),
    (["--hair", "nothere.json"], "file not found"),
])
def test_export_cli_refuses_bad_hair_with_exit_2(tmp_path, capsys, extra, want):
    out = tmp_path / ("person.obj" if "--obj" in extra else "person.glb")
    extra = [a for a in extra if a != "--obj"]
    code, _, err = _run(["export", "-o", str(out), *extra], capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and want in lines[0], err
    assert not list(tmp_path.iterdir())


def test_export_cli_hair_from_the_params_file_and_none(tmp_path, capsys):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"hair": {"archetype": "crew", "lod": 0.05,
                                           "beard": "stubble"}}))
    out = tmp_path / "person.glb"
    code, text, err = _run(["export", "--params", str(params), "--hair-color", "blonde",
                            "-o", str(out)], capsys)
    assert code == 0, err
    assert "hair: scalp" in text and "beard" in text
    doc, _ = read_gltf(out)
    style = doc["asset"]["extras"]["hack"]["hair"]["style"]
    assert style["archetype"] == "crew" and style["eumelanin"] == 0.3
    code, text, err = _run(["export", "--params", str(params), "--hair", "none",
                            "-o", str(out)], capsys)
    assert code == 0 and "  hair:" not in text, err
    assert "hair" not in read_gltf(out)[0]["asset"]["extras"]["hack"]
    # a mesh file of a params file with hair: the mesh, and a note that the hair is not in it
    code, text, err = _run(["export", "--params", str(params), "-o", str(tmp_path / "p.ply")],
                           capsys)
    assert code == 0 and (tmp_path / "p.ply").is_file() and "hair section is left out" in err
