"""The rigged glTF export (issue 23, part 2 and 3): the file, read back by a reference
evaluator written from the glTF specification, poses like the model's forward pass at
rest and at every animation frame; the Khronos validator finds no errors; size and time
stay within the issue's budget."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from hack_render.export import rig as R
from hack_render.export.person import export_person
from hack_render.export.reference import accessor, evaluate, read_gltf
from hack_render.geometry import load_default_model
from hack_render.geometry.params import ParamSequence, check_params, model_inputs
from hack_render.render import turntable as tt

PARAMS = {"beta": [0.8, -1.2, 0.5], "expression": "AU12=0.6,jawOpen=0.25",
          "head_rotation_deg": [8, 25, -3], "eta": 1.3, "tau": 0.004,
          "global_orient": [0.05, -0.1, 0.02], "transl": [0.01, -0.02, 0.03]}
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def model():
    return load_default_model()


@pytest.fixture(scope="module")
def sequence(model):
    """6 frames of the turntable's look-around and swallow, with expressions and a moving root."""
    seq = tt.motion_sequence(tt.TurntableSpec(6, look_around=True, swallow=True, fps=12))
    rng = np.random.default_rng(0)
    psi = np.clip(rng.normal(0.2, 0.2, (6, model.num_expressions)), 0, 1)
    orient = np.linspace(0, 0.1, 6)[:, None] * np.array([[1.0, 0.5, 0.0]])
    return ParamSequence(fps=12.0, theta=seq.theta, psi=psi, tau=seq.tau,
                         global_orient=orient, transl=np.zeros((6, 3)))


@pytest.fixture(scope="module")
def exported(model, sequence, tmp_path_factory):
    """glb with 8 and 4 influences (skin maps of A(0)), and a .gltf; their reports."""
    from hack_render.render.skin_maps import skin_maps

    folder = tmp_path_factory.mktemp("gltf")
    maps = skin_maps([0.0])
    p = check_params(PARAMS)
    out = {}
    for name, inf in (("p8.glb", 8), ("p4.glb", 4), ("p8.gltf", 8)):
        out[name] = (folder / name, export_person(model, p, folder / name, sequence, maps, inf))
    return out


def forward(model, **frame) -> np.ndarray:
    kw = model_inputs(model, check_params(PARAMS))
    kw.update({k: torch.as_tensor(np.asarray(v)[None], dtype=torch.float32)
               for k, v in frame.items()})
    with torch.no_grad():
        return model(**kw).vertices[0].double().numpy()


def test_default_state_is_the_parameter_files_pose(model, exported):
    path, _ = exported["p8.glb"]
    got = evaluate(path, None, model.num_vertices)
    want = forward(model)
    used = ~np.isnan(got[:, 0])
    # every vertex of a visible face is in the file (the ICT helper shells are not)
    assert used.sum() > 0.97 * model.num_vertices
    err = np.linalg.norm(got[used] - want[used], axis=1)
    assert err.max() < 2e-6, f"max {err.max() * 1e3:.4f} mm at vertex {np.argmax(err)}"


def test_every_animation_frame_matches_the_forward_pass(model, exported, sequence):
    path, _ = exported["p8.glb"]
    for k in range(sequence.frames):
        got = evaluate(path, k, model.num_vertices)
        want = forward(model, theta=sequence.theta[k], psi=sequence.psi[k], tau=sequence.tau[k],
                       global_orient=sequence.global_orient[k], transl=sequence.transl[k])
        used = ~np.isnan(got[:, 0])
        err = np.linalg.norm(got[used] - want[used], axis=1)
        # the larynx slide is interpolated between in-betweens 1 mm apart: <= 0.05 mm
        assert err.max() < 6e-5, f"frame {k}: max {err.max() * 1e3:.4f} mm"


@pytest.mark.parametrize("chain", [0.0, 1.0])
def test_a_gated_models_frames_match_its_forward_pass(model, sequence, tmp_path, chain):
    """A model whose pose correctives are gated by each joint's angle (format 3,
    ``pose_gate_deg``; with ``chain``, format 4's ``pose_gate_chain``, also by the chain's
    net rotation): the file's pose-corrective weights are the model's gated features, so
    every frame still poses like its forward pass, and the file names the gate for players
    that drive the correctives from the joints (the viewer)."""
    import copy
    import math

    gated = copy.deepcopy(model)
    gated.pose_gate_rad = math.radians(20.0)   # wide: most of the sequence's angles gated
    gated.pose_gate_chain = chain
    path = tmp_path / "gated.glb"
    export_person(gated, check_params(PARAMS), path, sequence, None, 8)
    doc, _ = read_gltf(path)
    assert doc["asset"]["extras"]["hack"]["pose_gate_deg"] == pytest.approx(20.0)
    assert doc["asset"]["extras"]["hack"]["pose_gate_chain"] == chain
    rest = evaluate(path, None, model.num_vertices)   # the parameter file's pose
    used = ~np.isnan(rest[:, 0])
    assert np.linalg.norm(rest[used] - forward(gated)[used], axis=1).max() < 2e-6
    other = copy.deepcopy(gated)
    other.pose_gate_chain = 1.0 - chain   # the gate with the chain term the other way
    plain = copy.deepcopy(model)
    plain.pose_gate_rad, plain.pose_gate_chain = None, 0.0   # no gate at all
    ungated = moved = 0.0
    for k in range(sequence.frames):
        frame = {"theta": sequence.theta[k], "psi": sequence.psi[k], "tau": sequence.tau[k],
                 "global_orient": sequence.global_orient[k], "transl": sequence.transl[k]}
        got = evaluate(path, k, model.num_vertices)
        want = forward(gated, **frame)
        used = ~np.isnan(got[:, 0])
        err = np.linalg.norm(got[used] - want[used], axis=1)
        assert err.max() < 6e-5, f"frame {k}: max {err.max() * 1e3:.4f} mm"
        ungated = max(ungated, np.abs(want - forward(plain, **frame)).max())
        moved = max(moved, np.abs(want - forward(other, **frame)).max())
    assert ungated > 1e-4   # the gate moves the mesh: the test above could fail
    assert moved > 1e-5     # and so does its chain term


def test_gltf_with_bin_equals_glb(model, exported):
    a = evaluate(exported["p8.glb"][0], 3, model.num_vertices)
    b = evaluate(exported["p8.gltf"][0], 3, model.num_vertices)
    np.testing.assert_array_equal(a, b)
    assert (exported["p8.gltf"][0].with_suffix(".bin")).is_file()


def test_four_influences_cost_what_the_report_says(model, exported, sequence):
    """4 weights per vertex: the file poses like LBS with the kept weights (exactly), and
    the report's truncation error is that of the default model's limits (~4.6 mm)."""
    path, rep = exported["p4.glb"]
    assert 1e-3 < rep["weight_truncation_error_m"] < 6e-3
    assert exported["p8.glb"][1]["weight_truncation_error_m"] < 1e-8
    doc, buf = read_gltf(path)
    prim = doc["meshes"][0]["primitives"][0]
    assert "JOINTS_1" not in prim["attributes"]
    w = accessor(doc, buf, prim["attributes"]["WEIGHTS_0"])
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    full8 = evaluate(exported["p8.glb"][0], 1, model.num_vertices)
    cut4 = evaluate(path, 1, model.num_vertices)
    used = ~np.isnan(full8[:, 0])
    diff = np.linalg.norm(full8[used] - cut4[used], axis=1).max()
    assert 1e-5 < diff < 6e-3  # a look-around pose: nonzero, within the limits' bound


def test_structure_names_skeleton_and_sparse_targets(model, exported):
    path, rep = exported["p8.glb"]
    doc, buf = read_gltf(path)
    mesh = doc["meshes"][0]
    names = mesh["extras"]["targetNames"]
    assert names[:53] == list(model.expression_names)  # ARKit names, in the model's order
    assert "larynx_size" in names and sum(n.startswith("pose_") for n in names) == 120
    assert len(names) == rep["targets"] == len(mesh["weights"])
    skin = doc["skins"][0]
    assert [doc["nodes"][j]["name"] for j in skin["joints"]] == ["thorax", *model.joint_names]
    ibm = accessor(doc, buf, skin["inverseBindMatrices"]).reshape(-1, 4, 4)
    rest = R.build_rig(model, torch.tensor([PARAMS["beta"]]), PARAMS["eta"]).rest_nodes
    np.testing.assert_allclose(ibm[:, 3, :3], -rest, atol=1e-6)  # column-major translation
    sparse = [t["POSITION"] for p in mesh["primitives"] for t in p["targets"]]
    acc = doc["accessors"]
    assert all("bufferView" not in acc[i] for i in sparse)  # sparse or all-zero, never dense
    assert sum("sparse" in acc[i] for i in sparse) > 214
    mats = {m["name"] for m in doc["materials"]}
    assert {"skin", "teeth", "sclera", "iris"} <= mats
    skin_mat = next(m for m in doc["materials"] if m["name"] == "skin")
    assert skin_mat["extensions"]["KHR_materials_ior"]["ior"] == 1.4
    assert "normalTexture" in skin_mat and len(doc["images"]) == 3
    assert doc["animations"][0]["channels"][-1]["target"]["path"] == "weights"


def test_size_and_time_budget(exported):
    for name in ("p8.glb", "p4.glb"):
        _, rep = exported[name]
        assert rep["bytes"] <= 25e6, f"{name}: {rep['bytes'] / 1e6:.1f} MB"
        assert rep["seconds"] <= 10.0, f"{name}: {rep['seconds']:.1f} s"


def test_tau_weights_interpolate_between_neighbours():
    grid = np.array([-0.002, -0.001, 0.001, 0.002])
    w = R.tau_weights(np.array([0.0, 0.0005, 0.0015, -0.002, 0.05]), grid)
    np.testing.assert_allclose(w, [[0, 0, 0, 0], [0, 0, 0.5, 0], [0, 0, 0.5, 0.5],
                                   [1, 0, 0, 0], [0, 0, 0, 1]])


def test_top_weights_keep_rows_normalised_and_exact_with_eight():
    rng = np.random.default_rng(1)
    w = rng.random((50, 9)) * (rng.random((50, 9)) > 0.3)
    w[:, 0] += 0.01
    w /= w.sum(1, keepdims=True)
    idx, w4 = R.top_weights(w, 4)
    np.testing.assert_allclose(w4.sum(1), 1.0, atol=1e-6)
    assert (np.take_along_axis(w, idx, 1)[w4 > 0] > 0).all()
    w[:, 3] = 0  # at most 8 nonzero: 8 influences keep them all
    w /= w.sum(1, keepdims=True)
    idx8, w8 = R.top_weights(w, 8)
    back = np.zeros_like(w)
    # unused slots: index 0, weight 0
    np.add.at(back, (np.arange(50)[:, None].repeat(8, 1), idx8), w8)
    np.testing.assert_allclose(back, w, atol=1e-6)


def _validator():
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        return None, "node/npm not installed (scripts/setup.sh --test installs them)"
    root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True,
                          check=False).stdout.strip()
    if not (Path(root) / "gltf-validator").is_dir():
        return None, "npm package gltf-validator not installed (scripts/setup.sh --test)"
    return [node, str(HERE / "gltf_validate.js")], root


def test_khronos_validator_reports_no_errors(exported):
    cmd, root = _validator()
    if cmd is None:
        pytest.skip(root)
    files = [str(exported[n][0]) for n in ("p8.glb", "p4.glb", "p8.gltf")]
    r = subprocess.run(cmd + files, capture_output=True, text=True, check=False, timeout=120,
                       env={"NODE_PATH": root, "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    reports = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(reports) == 3
    for rep in reports:
        assert rep["errors"] == 0, rep["messages"]
        # the only warnings: tangents left to the runtime (MikkTSpace) for the normal map
        assert all("GENERATED_TANGENT_SPACE" in m for m in rep["messages"] if m.startswith("1 ")), \
            rep["messages"]


def test_a_fits_part_colours_go_to_the_parts_vertex_colours(model, tmp_path):
    """Skin maps with per-vertex part colours (a fit's bake, ``SkinMaps.part_rgb``, read
    from ``--textures``' ``parts.npz``): each coloured part's primitive carries them as
    ``COLOR_0`` (linear, as the file holds them) under a white material; the other parts
    keep their colour; colours for another model's part are a clear error."""
    import dataclasses

    from hack_render.errors import HackError
    from hack_render.render.parts import Topology, split_parts
    from hack_render.render.skin_maps import skin_maps

    with torch.no_grad():
        rest = model().vertices[0].double().numpy()
    parts = {p.name: p for p in split_parts(Topology.from_model(model), rest)[0]}
    rng = np.random.default_rng(3)
    rgb = {k: rng.uniform(0.05, 0.95, (len(parts[k].gather), 3)).astype(np.float32)
           for k in ("teeth", "iris")}
    maps = dataclasses.replace(skin_maps([0.0]), part_rgb=rgb)
    path = tmp_path / "coloured.glb"
    export_person(model, check_params(PARAMS), path, None, maps, 4)
    doc, buf = read_gltf(path)
    by_name = {doc["materials"][p["material"]]["name"]: p
               for p in doc["meshes"][0]["primitives"]}
    for k, want in rgb.items():
        prim = by_name[k]
        np.testing.assert_allclose(accessor(doc, buf, prim["attributes"]["COLOR_0"]), want,
                                   atol=1e-7)
        assert doc["materials"][prim["material"]]["pbrMetallicRoughness"][
            "baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    assert "COLOR_0" not in by_name["mouth"]["attributes"]
    assert doc["materials"][by_name["mouth"]["material"]]["pbrMetallicRoughness"][
        "baseColorFactor"] != [1.0, 1.0, 1.0, 1.0]
    bad = dataclasses.replace(maps, part_rgb={"teeth": rgb["teeth"][:-1]})
    with pytest.raises(HackError, match="part colours 'teeth': expected one per vertex"):
        export_person(model, check_params(PARAMS), tmp_path / "bad.glb", None, bad, 4)
