"""HACK motion on other characters (paper Sec. 6.2): the procedural long-necked character
(made from the template, labelled procedural) passes the pose-space stress test's fold and
stretch checks; retargeting onto glTF neck chains round-trips in each bone's rest frame;
`hack-render transfer` writes a glTF that the reference evaluator poses as the character
rig does; on a glTF character (the same procedural character, written as a plain skinned
glTF) the head follows the global pose, expressions and the larynx move the right regions,
and the baked maps land where they should; bad inputs exit with code 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.export.gltf import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    UBYTE,
    USHORT,
    GltfBuilder,
    write_document,
)
from hack_render.export.reference import accessor, read_gltf
from hack_render.geometry import load_default_model
from hack_render.geometry.params import ParamSequence, save_sequence
from hack_render.motion import character as C
from hack_render.motion import retarget as RT


@pytest.fixture(scope="module")
def model():
    return load_default_model()


@pytest.fixture(scope="module")
def long_neck(model):
    ch = C.long_neck_character(model)
    return ch, C.character_rig(model, ch)


def _motion(frames=6, seed=0):
    from hack_render.geometry.deformation import sample_joint_poses

    g = torch.Generator().manual_seed(seed)
    theta = sample_joint_poses(frames, g).numpy()
    psi = np.zeros((frames, 53))
    psi[:, 20] = np.linspace(0, 1, frames)  # jawOpen
    return ParamSequence(fps=12.0, theta=theta, psi=psi, tau=np.linspace(0, 0.015, frames))


# ------------------------------------------------------------------ the long-necked character
def test_01_long_neck_is_procedural_and_long(model, long_neck):
    ch, _ = long_neck
    with torch.no_grad():
        j0 = model(beta=torch.zeros(1, 0)).rest_joints[0].double().numpy()
    neck = lambda j: np.linalg.norm(np.diff(j, axis=0), axis=1).sum()
    assert abs(neck(ch.joints) / neck(j0) - 2.5) < 1e-9
    assert ch.meta["provenance"]["kind"] == "procedural"
    skull = ch.weights[:, -1] == 1  # rigid with o-c1: moved up by the lengthening, reshaped
    assert skull.sum() > 20000
    C.check_character(ch, model)  # it validates


def test_02_transferred_poses_pass_the_fold_and_stretch_checks(model, long_neck):
    """60 poses of the stress test's families (per-joint uniform and whole-head, singly and
    combined): no pose folds more skin than the character's plain LBS, and the pose
    correctives (transferred from the person) keep stretch at or below LBS's in median
    and worst case, and within 12 points of it on every pose (measured with model version
    5: no folds; median 0.219 against 0.238, largest excess 0.115 at a whole-head flexion,
    4 poses above 0.09, 7 above 0.06; version 4: 0.083; version 3: 0.072. The bound was 8
    points until version 4 and 9 until version 5: versions 3, 4 and 5 fold the person's
    neck in 15, 1 and 0 of the pose bench's 20,000 neutral pairs (plain LBS 1,258) and
    transfer to this 2.5x longer neck a little less well; docs/motion.md)."""
    from hack_render.geometry.deformation import sample_pose_space

    _, crig = long_neck
    theta = torch.cat(list(sample_pose_space(60, seed=2100).values())).numpy()
    a = C.pose_checks(crig, model, theta)
    b = C.pose_checks(C.lbs_only(crig), model, theta)
    assert (a["folded"] <= b["folded"]).all(), np.flatnonzero(a["folded"] > b["folded"])
    assert np.median(a["stretch"]) <= np.median(b["stretch"])
    assert a["stretch"].max() <= b["stretch"].max()
    assert (a["stretch"] - b["stretch"]).max() <= 0.12
    assert a["folded"].sum() == 0


def test_03_expressions_transfer_onto_the_character(model, long_neck):
    """jawOpen moves the character's jaw by about what it moves the person's (deformation
    transfer keeps local deformation: the skull is 1.35x longer, so somewhat more); what
    no target moves stays put, and where the person's jawOpen is still the character's
    moves little (one Poisson solve serves all targets, so their union is free)."""
    from hack_render.export import rig as R

    _, crig = long_neck
    human = R.build_rig(model, None, 1.0)
    j = model.expression_names.index("jawOpen")
    d_h = np.linalg.norm(human.targets[j], axis=1)
    d_c = np.linalg.norm(crig.rig.targets[j], axis=1)
    assert 0.7 < d_c.max() / d_h.max() < 2.0, (d_c.max(), d_h.max())
    moved = np.any(human.targets != 0, axis=(0, 2))
    assert (np.abs(crig.rig.targets[:, ~moved]) == 0).all()
    assert d_c[d_h == 0].max() < 0.15 * d_c.max(), (d_c[d_h == 0].max(), d_c.max())


# ------------------------------------------------------------------ glTF neck chains
def _chain_gltf(path, names=("hips", "spine", "neck_01", "neck_02", "neck_03", "head"),
                seed=0):
    """A glTF character: a chain of bones with random rest orientations, each carrying a
    small box (no UVs) skinned rigidly to it."""
    rng = np.random.default_rng(seed)
    g = GltfBuilder()
    nodes, pos, joints, world = [], [], [], []
    w_parent = np.eye(4)
    for i, name in enumerate(names):
        q = rng.normal(size=4)
        q = q / np.linalg.norm(q) * np.sign(q[3])
        node = {"name": name, "rotation": q.tolist(),
                "translation": [0.0, 0.08 if i else 1.0, 0.0]}
        if i + 1 < len(names):
            node["children"] = [i + 1]
        nodes.append(node)
        w = w_parent @ RT._local(node)
        world.append(w)
        w_parent = w
        box = (np.array(np.meshgrid([-1, 1], [0, 2], [-1, 1], indexing="ij")).reshape(3, -1).T
               * 0.02)
        pos.append((w[:3, :3] @ box.T).T + w[:3, 3])
        joints.append(np.full((8, 4), 0))
        joints[-1][:, 0] = i
    pos = np.concatenate(pos)
    jnt = np.concatenate(joints)
    wts = np.zeros((len(pos), 4))
    wts[:, 0] = 1
    cube = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    faces = np.concatenate([cube + 8 * i for i in range(len(names))])
    attrs = {"POSITION": g.accessor(pos, FLOAT, "VEC3", ARRAY_BUFFER, bounds=True),
             "JOINTS_0": g.accessor(jnt, UBYTE, "VEC4", ARRAY_BUFFER),
             "WEIGHTS_0": g.accessor(wts, FLOAT, "VEC4", ARRAY_BUFFER)}
    g._add("meshes", {"primitives": [{"attributes": attrs, "mode": 4, "indices": g.accessor(
        faces.reshape(-1, 1), USHORT, "SCALAR", ELEMENT_ARRAY_BUFFER)}]})
    for n in nodes:
        g._add("nodes", n)
    ibm = np.stack([np.linalg.inv(w).T.reshape(16) for w in world])
    skin = g._add("skins", {"joints": list(range(len(names))),
                            "inverseBindMatrices": g.accessor(ibm, FLOAT, "MAT4")})
    mesh_node = g._add("nodes", {"name": "body", "mesh": 0, "skin": skin})
    g.doc["scenes"] = [{"nodes": [0, mesh_node]}]
    g.doc["scene"] = 0
    write_document(g, path)
    return path


def _animated_world(path, frame, full=False):
    """World rotation (n, 3, 3) (or matrix (n, 4, 4)) of every node at an animation
    keyframe of our clip."""
    doc, buf = read_gltf(path)
    nodes = [dict(n) for n in doc["nodes"]]
    anim = next(a for a in doc["animations"] if a["name"] == "hack_transfer")
    for ch in anim["channels"]:
        if ch["target"]["path"] != "weights":
            nodes[ch["target"]["node"]][ch["target"]["path"]] = accessor(
                doc, buf, anim["samplers"][ch["sampler"]]["output"])[frame].tolist()
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}

    def world(i):
        m = RT._local(nodes[i])
        return world(parent[i]) @ m if i in parent else m

    return np.stack([world(i) if full else world(i)[:3, :3] for i in range(len(nodes))])


def test_04_retarget_round_trip_in_each_bones_rest_frame(model, tmp_path):
    """Bones with arbitrary rest orientations: after retargeting, each chain bone's world
    rotation is the product of its (and its ancestors') HACK joint rotations times its
    rest rotation, so the head turns exactly as HACK's skull does (to 1e-6)."""
    path = _chain_gltf(tmp_path / "chain.glb")
    ch = RT.load_gltf_character(path)
    with torch.no_grad():
        hj = model(beta=torch.zeros(1, 0)).rest_joints[0].double().numpy()
    bones, assign = RT.joint_map(ch, hj)
    assert [ch.names[b] for b in bones] == ["neck_01", "neck_02", "neck_03", "head"]
    assert assign == sorted(assign) and assign[0] == 0 and assign[-1] == 3
    seq = _motion(5)
    quats = RT.retarget(ch, bones, assign, seq.theta)
    out = RT.write_animated(ch, bones, quats, seq.fps, tmp_path / "out.glb", {"test": 1})
    from hack_render.motion.head_to_neck import head_orientation

    rb = RT.bone_rotations(seq.theta, assign, len(bones))
    for f in range(5):
        w = _animated_world(out[0], f)
        acc = np.eye(3)
        for k, b in enumerate(bones):
            acc = acc @ rb[f, k]
            np.testing.assert_allclose(w[b], acc @ ch.world[b, :3, :3], atol=1e-6)
        head = head_orientation(torch.as_tensor(seq.theta[f])).numpy()
        np.testing.assert_allclose(w[bones[-1]], head @ ch.world[bones[-1], :3, :3], atol=1e-6)
        np.testing.assert_allclose(w[0], ch.world[0, :3, :3], atol=1e-6)  # the body stays


def test_05_hack_export_as_target_reproduces_the_joints(model, tmp_path):
    """HACK's own exported glTF, mapped joint to joint by a name map: the retargeted
    skeleton puts every joint where the model's forward pass does (to 0.01 mm)."""
    from hack_render.export.person import export_person
    from hack_render.geometry.skeleton import JOINT_NAMES

    glb = tmp_path / "person.glb"
    export_person(model, {}, glb)
    ch = RT.load_gltf_character(glb)
    bones, assign = RT.joint_map(ch, None, name_map={j: j for j in JOINT_NAMES})
    assert assign == list(range(8))
    seq = _motion(4, seed=3)
    out = RT.write_animated(ch, bones, RT.retarget(ch, bones, assign, seq.theta), seq.fps,
                            tmp_path / "again.glb", {})
    doc, buf = read_gltf(out[0])
    with torch.no_grad():
        want = model(theta=torch.as_tensor(seq.theta, dtype=torch.float32)).joints.numpy()
    for f in range(4):
        nodes = [dict(n) for n in doc["nodes"]]
        anim = doc["animations"][-1]
        for c in anim["channels"]:
            nodes[c["target"]["node"]]["rotation"] = accessor(
                doc, buf, anim["samplers"][c["sampler"]]["output"])[f].tolist()
        m = np.eye(4)
        got = []
        for i in range(9):  # thorax, then the chain
            m = m @ RT._local(nodes[i])
            got.append(m[:3, 3])
        np.testing.assert_allclose(np.array(got[1:]), want[f], atol=1e-5)


def test_06_uv_atlas_for_a_character_without_uvs(tmp_path):
    path = _chain_gltf(tmp_path / "chain.glb")
    ch = RT.load_gltf_character(path)
    before = accessor(ch.doc, ch.buf, ch.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"])
    assert RT.add_uv_atlas(ch) == [(0, 0)]
    prim = ch.doc["meshes"][0]["primitives"][0]
    uv = accessor(ch.doc, ch.buf, prim["attributes"]["TEXCOORD_0"])
    pos = accessor(ch.doc, ch.buf, prim["attributes"]["POSITION"])
    assert len(uv) == len(pos) >= len(before) and uv.min() >= 0 and uv.max() <= 1
    idx = accessor(ch.doc, ch.buf, prim["indices"])[:, 0].astype(int).reshape(-1, 3)
    a, b = uv[idx[:, 1]] - uv[idx[:, 0]], uv[idx[:, 2]] - uv[idx[:, 0]]
    area = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    assert (np.abs(area) > 0).all()  # every triangle has room in the atlas
    assert RT.add_uv_atlas(ch) == []  # it has UVs now


# ------------------------------------------------------------------ the command
@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    from hack_render.cli import main

    d = tmp_path_factory.mktemp("transfer")
    motion = save_sequence(d / "anim.npz", _motion(6, seed=5))
    main(["transfer", "--motion", str(motion), "--target", "procedural:long-neck", "-o",
          str(d / "out"), "--no-turntable", "--influences", "8", "--quiet"])
    return d


def test_07_cli_writes_a_glb_that_poses_like_the_character_rig(model, long_neck, cli_run):
    """The glTF (the export's format, 8 influences: exact) evaluated by the reference
    reader at each keyframe equals the character rig's own posing (to 0.05 mm), and its
    metadata and report say the character is procedural."""
    from hack_render.export.reference import evaluate

    _, crig = long_neck
    seq = _motion(6, seed=5)
    verts, _ = crig.pose(seq.psi, seq.theta, seq.tau)
    glb = cli_run / "out" / "long_neck.glb"
    for f in (0, 3, 5):
        got = evaluate(glb, f, model.num_vertices)
        ok = np.isfinite(got).all(1)
        assert ok.sum() > 0.95 * len(ok)
        np.testing.assert_allclose(got[ok], verts[f][ok], atol=5e-5)
    doc, _ = read_gltf(glb)
    assert doc["asset"]["extras"]["hack"]["character"]["provenance"]["kind"] == "procedural"
    rep = json.loads((cli_run / "out" / "report.json").read_text())
    assert rep["deformation"]["frames"] == 6 and rep["deformation"]["frames_folding_more_than_lbs"] == 0


def _code(args):
    from hack_render.cli import main

    with pytest.raises(SystemExit) as e:
        main(args)
    return e.value.code


def test_08_bad_inputs_exit_2(model, tmp_path, capsys):
    good = save_sequence(tmp_path / "good.npz", _motion(3))
    nan = tmp_path / "nan.npz"
    theta = np.zeros((3, 8, 3))
    theta[1, 2, 0] = np.nan
    np.savez(nan, theta=theta, fps=12.0)
    shape = tmp_path / "shape.npz"
    np.savez(shape, theta=np.zeros((3, 7, 3)), fps=12.0)
    no_neck = _chain_gltf(tmp_path / "noneck.glb", names=("a", "b", "c", "d"))
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, vertices=np.zeros((100, 3)), joints=np.zeros((8, 3)))
    jointless = tmp_path / "jointless.npz"
    np.savez(jointless, vertices=model.template.numpy())
    cases = [(nan, "procedural:long-neck", "NaN"),
             (shape, "procedural:long-neck", "8 x 3"),
             (good, str(no_neck), "no neck chain"),
             (good, str(wrong), "topology"),
             (good, str(jointless), "neck chain"),
             (good, str(tmp_path / "x.obj"), "expected a character"),
             (tmp_path / "missing.npz", "procedural:long-neck", "not found")]
    for motion, target, msg in cases:
        assert _code(["transfer", "--motion", str(motion), "--target", target, "-o",
                      str(tmp_path / "o"), "--no-turntable", "--quiet"]) == 2, (motion, target)
        assert msg in capsys.readouterr().err, (motion, target, msg)
    assert _code(["transfer", "--motion", str(good), "--target", str(no_neck), "-o",
                  str(tmp_path / "o"), "--bake-size", "5", "--quiet"]) == 2
    assert "--bake-size: expected an integer in 16..8192 texels" in capsys.readouterr().err
    with pytest.raises(HackError, match="not an ancestor"):
        RT.find_neck_chain(RT.load_gltf_character(no_neck), ["d", "a"])
    from hack_render.geometry.skeleton import JOINT_NAMES

    chain = RT.load_gltf_character(_chain_gltf(tmp_path / "c.glb"))
    with pytest.raises(HackError, match="every HACK joint"):
        RT.joint_map(chain, None, name_map={"c7-t1": "neck_01"})
    down = {j: ("head" if k < 4 else "neck_01") for k, j in enumerate(JOINT_NAMES)}
    with pytest.raises(HackError, match="upwards"):
        RT.joint_map(chain, None, name_map=down)


@pytest.mark.slow
def test_09_cli_turntable(tmp_path):
    """The turntable of the transferred motion (Mitsuba; about a minute on 2 cores)."""
    from hack_render.cli import main

    motion = save_sequence(tmp_path / "anim.npz", _motion(4))
    main(["transfer", "--motion", str(motion), "--target", "procedural:long-neck", "-o",
          str(tmp_path / "out"), "--frames", "4", "--resolution", "64", "--spp", "4", "--quiet"])
    import imageio.v3 as iio

    frames = [iio.imread(tmp_path / "out" / "turntable" / "frames" / f"frame_{i:04d}.png")
              for i in range(4)]
    assert (tmp_path / "out" / "turntable" / "turntable.mp4").stat().st_size > 0
    assert all(f.std() > 5 for f in frames)  # something is in view


def test_10_cli_gltf_target(tmp_path, capsys):
    """A glTF target through the command: found chain, arc-length mapping in the report,
    the animation added to a copy (the input untouched), a UV atlas for its UV-less box."""
    from hack_render.cli import main

    src = _chain_gltf(tmp_path / "chain.glb")
    before = src.read_bytes()
    motion = save_sequence(tmp_path / "anim.npz", _motion(3))
    main(["transfer", "--motion", str(motion), "--target", str(src), "-o", str(tmp_path / "o"),
          "--no-turntable", "--quiet", "--bake-size", "64"])
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["target"]["method"] == "arc length along the neck chain"
    assert rep["target"]["mapping"]["c7-t1"] == "neck_01" and rep["target"]["mapping"]["o-c1"] == "head"
    assert rep["target"]["uv_atlas_primitives"] == 1
    doc, _ = read_gltf(tmp_path / "o" / "chain_hack.glb")
    assert [a["name"] for a in doc["animations"]] == ["hack_transfer"]
    assert "TEXCOORD_0" in doc["meshes"][0]["primitives"][0]["attributes"]
    assert src.read_bytes() == before


def test_11_gltf_skinning_and_turntable(tmp_path):
    """posed_mesh (glTF skinning, used by the glTF turntable): at rest it gives the file's
    positions; under the retargeted clip each box moves rigidly with its bone, as the
    animated file's node matrices say; the command renders a turntable of it."""
    from hack_render.cli import main

    path = _chain_gltf(tmp_path / "chain.glb")
    ch = RT.load_gltf_character(path)
    prim = ch.doc["meshes"][0]["primitives"][0]
    rest = accessor(ch.doc, ch.buf, prim["attributes"]["POSITION"])
    v0, f0 = RT.posed_mesh(ch)
    np.testing.assert_allclose(v0, rest, atol=1e-6)
    assert f0.shape == (12 * 6, 3)
    bones, assign = RT.joint_map(ch, np.cumsum(np.ones((8, 3)) * [0, 0.02, 0], 0))
    seq = _motion(3, seed=7)
    quats = RT.retarget(ch, bones, assign, seq.theta)
    out = RT.write_animated(ch, bones, quats, seq.fps, tmp_path / "a.glb", {})[0]
    for f in range(3):
        v, _ = RT.posed_mesh(ch, bones, quats[f])
        wa = _animated_world(out, f, full=True)
        for b in range(6):
            m = wa[b] @ np.linalg.inv(ch.world[b])
            np.testing.assert_allclose(v[8 * b:8 * b + 8], rest[8 * b:8 * b + 8] @ m[:3, :3].T
                                       + m[:3, 3], atol=1e-5)
    motion = save_sequence(tmp_path / "anim.npz", seq)
    main(["transfer", "--motion", str(motion), "--target", str(path), "-o", str(tmp_path / "o"),
          "--frames", "2", "--resolution", "32", "--spp", "1", "--quiet", "--bake-size", "64"])
    import imageio.v3 as iio

    img = iio.imread(tmp_path / "o" / "turntable" / "frames" / "frame_0001.png")
    assert img.shape == (32, 32, 3) and img.std() > 3  # the boxes are in view


# ------------------------------------------------------------------ glTF: global pose, expressions, maps
def _uv_maps(h=128):
    """Skin maps that encode the atlas position: diffuse (u / 2, v, 0.25), specular v,
    roughness 0.5, normal a constant tilt (0.3, -0.2, 0.93) in HACK's tangent frames."""
    from hack_render.render.materials import SkinMaps

    u = (np.arange(2 * h) + 0.5) / h
    v = 1 - (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    diffuse = np.stack([uu / 2, vv, np.full_like(uu, 0.25)], -1).astype(np.float32)
    n = np.array([0.3, -0.2, 0.93])
    n = np.broadcast_to(n / np.linalg.norm(n), (h, 2 * h, 3)).astype(np.float32).copy()
    return SkinMaps(diffuse, vv[..., None].astype(np.float32),
                    np.full((h, 2 * h, 1), 0.5, np.float32), n)


@pytest.fixture(scope="module")
def gltf_run(model, tmp_path_factory):
    """The procedural long-necked character as a plain glTF (skin only, no UVs, 6 bones),
    through the transfer: frame 0 neutral; 1 global pose, neck pose and jawOpen; 2 the
    larynx slid 15 mm and the body moved."""
    from hack_render.motion.transfer import run_transfer

    d = tmp_path_factory.mktemp("gltf")
    src = C.long_neck_gltf(model, d / "long_neck.glb")
    g = torch.Generator().manual_seed(11)
    from hack_render.geometry.deformation import sample_joint_poses

    theta = np.zeros((3, 8, 3))
    theta[1] = 0.5 * sample_joint_poses(1, g).numpy()[0]
    psi = np.zeros((3, model.num_expressions))
    psi[1, model.expression_names.index("jawOpen")] = 1.0
    go = np.zeros((3, 3))
    go[1] = [0.2, 0.6, -0.1]
    transl = np.zeros((3, 3))
    transl[2] = [0.05, 0.02, -0.03]
    seq = ParamSequence(fps=12.0, theta=theta, psi=psi, tau=np.array([0.0, 0.0, 0.015]),
                        global_orient=go, transl=transl)
    motion = save_sequence(d / "anim.npz", seq)
    rep = run_transfer(model, motion, str(src), d / "out", {}, maps=_uv_maps(), bake_size=256,
                       progress=False)
    return d, src, seq, rep


def _file_frame(ch, frame):
    """(nodes, morph) of the written clip at a keyframe, for retarget.posed_primitives."""
    doc, buf = ch.doc, ch.buf
    nodes = [dict(n) for n in doc["nodes"]]
    morph = {}
    anim = next(a for a in doc["animations"] if a["name"] == "hack_transfer")
    for c in anim["channels"]:
        val = accessor(doc, buf, anim["samplers"][c["sampler"]]["output"])
        n, p = c["target"]["node"], c["target"]["path"]
        if p == "weights":
            k = len(doc["meshes"][doc["nodes"][n]["mesh"]]["weights"])
            morph[doc["nodes"][n]["mesh"]] = val.reshape(-1, k)[frame]
        else:
            nodes[n][p] = val[frame].tolist()
    return nodes, morph


def _template_index(model, ch_out):
    """The rest primitive and each of its vertices' template vertex (``_HACK_VERTEX``,
    carried through the atlas's vertex split)."""
    rest = next(RT.posed_primitives(ch_out, morph={0: np.zeros(1000)}))
    prim = ch_out.doc["meshes"][0]["primitives"][0]
    tmpl = accessor(ch_out.doc, ch_out.buf, prim["attributes"]["_HACK_VERTEX"])[:, 0]
    tmpl = np.round(tmpl).astype(np.int64)
    lc = C.long_neck_character(model)
    np.testing.assert_allclose(rest.vertices, lc.vertices[tmpl], atol=1e-6)
    return rest, tmpl


def test_12_gltf_head_follows_the_global_pose(model, gltf_run):
    """HACK's global rotation turns the body's root (hips), so the head bone's world
    rotation is global x the skull's rotation over the thorax (x its rest rotation), to
    1e-6; the translation moves the root by transl; the neck bones follow as before."""
    from hack_render.motion.head_to_neck import head_orientation

    d, _, seq, rep = gltf_run
    assert rep["target"]["global_pose"].startswith("global_orient and transl on 'hips'")
    out = d / "out" / "long_neck_hack.glb"
    ch = RT.load_gltf_character(out)
    head = ch.node("head")
    r_g = RT._matrices(seq.global_orient)
    for f in range(3):
        w = _animated_world(out, f, full=True)
        want = r_g[f] @ head_orientation(torch.as_tensor(seq.theta[f])).numpy()
        np.testing.assert_allclose(w[head][:3, :3], want @ ch.world[head, :3, :3], atol=1e-6)
        np.testing.assert_allclose(w[0][:3, 3], ch.world[0, :3, 3] + seq.transl[f], atol=1e-6)
    assert np.degrees(np.arccos((np.trace(r_g[1]) - 1) / 2)) > 30  # a real turn


def test_13_gltf_expression_and_larynx_move_the_right_regions(model, gltf_run):
    """Morph targets by closest-point transfer: at the jawOpen frame the chin and lower
    lip move as the person's do, scaled as the skull was (per axis 0.85, 1, 1.35, blended
    by the o-c1 weight; the alignment recovers that scale): median length ratio 0.9 to 1.1
    and the jaw drops; the back of the head does not move; at the 15 mm larynx slide the
    larynx moves by the person's in-betweens (same ratio), what they leave still does not move."""
    from hack_render.export import rig as R

    d, _, _, rep = gltf_run
    human = R.build_rig(model, None, 1.0)
    ch = RT.load_gltf_character(d / "out" / "long_neck_hack.glb")
    rest, tmpl = _template_index(model, ch)
    s = np.array(rep["target"]["alignment"]["skull_scale"])
    np.testing.assert_allclose(s, [0.85, 1.0, 1.35], atol=0.01)
    scale = 1 + model.skinning_weights[:, -1].double().numpy()[tmpl, None] * (s - 1)
    base = next(RT.posed_primitives(ch, None, _file_frame(ch, 0)[1])).vertices

    def ratio(got, want, sel):
        return np.linalg.norm(got[sel], axis=1) / np.linalg.norm(want[sel] * scale[sel], axis=1)

    jaw = human.targets[model.expression_names.index("jawOpen")][tmpl]
    moved = next(RT.posed_primitives(ch, None, _file_frame(ch, 1)[1])).vertices - base
    mouth = np.linalg.norm(jaw, axis=1) > 0.005
    assert mouth.sum() > 200
    r = ratio(moved, jaw, mouth)
    assert 0.9 <= np.median(r) <= 1.1 and np.quantile(r, 0.1) > 0.8, np.quantile(r, [0.1, 0.5])
    assert (moved[mouth][:, 1] < 0).mean() > 0.9  # the jaw drops
    back = (np.linalg.norm(jaw, axis=1) == 0) & (rest.vertices[:, 2] < np.median(rest.vertices[:, 2]))
    assert np.abs(moved[back]).max() < 1e-4
    lar = next(RT.posed_primitives(ch, None, _file_frame(ch, 2)[1])).vertices - base
    want = (R.tau_weights(np.array([0.015]), human.tau_grid)[0]
            @ human.targets[human.slots["larynx_slide"]].reshape(len(human.tau_grid), -1)
            ).reshape(-1, 3)[tmpl]
    sel = np.linalg.norm(want, axis=1) > 0.001
    assert sel.sum() > 30
    r = ratio(lar, want, sel)
    assert 0.9 <= np.median(r) <= 1.1 and np.quantile(r, 0.1) > 0.8, np.quantile(r, [0.1, 0.5])
    assert np.abs(lar[np.linalg.norm(want, axis=1) == 0]).max() < 1e-4  # the face among them


def test_14_gltf_maps_baked_in_the_right_places(model, gltf_run):
    """Every covered texel of the baked atlas holds the HACK atlas position of the same
    surface point of the template (the diffuse encodes it): within 0.01 (u / 2 and v,
    8-bit sRGB) on 99 % of the texels; the normal map, turned back into world space through the character's
    tangent frames, is HACK's perturbed normal (within 3 degrees on 95 %); the file is
    textured (base colour, normal, specular) and labelled derived."""
    import imageio.v3 as iio

    from appearance.colour_space import srgb_decode
    from hack_render.motion import surface_transfer as ST
    from hack_render.render.parts import Topology

    d, _, _, rep = gltf_run
    ch = RT.load_gltf_character(d / "out" / "long_neck_hack.glb")
    rest, tmpl = _template_index(model, ch)
    prim = ch.doc["meshes"][0]["primitives"][0]
    mat = ch.doc["materials"][prim["material"]]
    assert mat["name"].startswith("hack_skin_baked") and "normalTexture" in mat
    assert "KHR_materials_specular" in mat["extensions"]
    assert "derived" in rep["target"]["derived"]["maps"]

    def image(tex):
        bv = ch.doc["bufferViews"][ch.doc["images"][ch.doc["textures"][tex]["source"]]["bufferView"]]
        o = bv.get("byteOffset", 0)
        return iio.imread(ch.buf[o:o + bv["byteLength"]]) / 255.0

    uv = accessor(ch.doc, ch.buf, prim["attributes"]["TEXCOORD_0"])
    s = 256
    face, bary = ST.rasterize_atlas(uv[rest.faces], s)
    cov = np.flatnonzero(face.ravel() >= 0)
    f, b = face.ravel()[cov], bary.reshape(-1, 3)[cov].astype(np.float64)
    # ground truth: the same surface point's atlas position on the template (the
    # character's triangles are the template's skin triangles)
    topo = Topology.from_model(model)
    key = {tuple(sorted(t)): i for i, t in enumerate(topo.faces.tolist())}
    tv = tmpl[rest.faces[f]]  # (Q, 3) template vertices of each texel's triangle
    tf = np.array([key[tuple(sorted(t))] for t in tv.tolist()])
    corner = (topo.faces[tf][:, None, :] == tv[:, :, None]).argmax(2)  # (Q, 3)
    h_uv = np.einsum("qk,qkc->qc", b, topo.uvs[topo.uv_faces[tf][np.arange(len(tf))[:, None],
                                                                 corner]])
    got = srgb_decode(image(mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]))
    got = got.reshape(-1, 3)[cov]
    err = np.maximum(np.abs(got[:, 0] - h_uv[:, 0] / 2), np.abs(got[:, 1] - h_uv[:, 1]))
    assert np.quantile(err, 0.99) < 0.01 and np.median(err) < 0.004, np.quantile(err, [0.5, 0.99])
    # the normal map: the character's tangent frame at each texel -> world normal
    nrm = image(mat["normalTexture"]["index"]) * 2 - 1
    surf = ST.hack_surface(model, _person_rig(model), ch.world[[ch.node(n) for n in
                           ("neck_01", "neck_02", "neck_03", "head")], :3, 3],
                           rest.vertices[np.isin(rest.dominant, [ch.node("head")])])
    cov, f, b = cov[::20], f[::20], b[::20]
    pts = np.einsum("qk,qkc->qc", b, rest.vertices[rest.faces[f]])
    cn = np.einsum("qk,qkc->qc", b, ST._vertex_normals(rest.vertices, rest.faces)[rest.faces[f]])
    uv_up = np.stack([uv[:, 0], 1 - uv[:, 1]], 1)
    c_frame = ST._frame(ST.tangent_frames(rest.vertices, rest.faces, uv_up[rest.faces])[f], cn)
    world_c = np.einsum("qi,qic->qc", nrm.reshape(-1, 3)[cov], c_frame)
    hf, hb, _ = ST.closest_points(surf.vertices, surf.faces, pts)
    hn = np.einsum("qk,qkc->qc", hb, ST._vertex_normals(surf.vertices, surf.faces)[surf.faces[hf]])
    h_frame = ST._frame(ST.tangent_frames(surf.vertices, surf.faces, surf.uv)[hf], hn)
    tilt = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    world_h = np.einsum("i,qic->qc", tilt, h_frame)
    cosang = (world_c * world_h).sum(1) / np.linalg.norm(world_c, axis=1)
    assert np.quantile(np.degrees(np.arccos(np.clip(cosang, -1, 1))), 0.95) < 3.0


def _person_rig(model):
    from hack_render.export import rig as R

    return R.build_rig(model, None, 1.0)


def test_15_gltf_output_passes_the_khronos_validator(gltf_run):
    import subprocess

    from tests.test_export_gltf import _validator

    cmd, root = _validator()
    if cmd is None:
        pytest.skip(root)
    d = gltf_run[0]
    r = subprocess.run(cmd + [str(d / "out" / "long_neck_hack.glb")], capture_output=True,
                       text=True, check=False, timeout=120,
                       env={"NODE_PATH": root, "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout.splitlines()[0])
    assert rep["errors"] == 0, rep["messages"]
