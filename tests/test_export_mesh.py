"""Mesh files keep the model's vertex order (issue 23, part 1): OBJ with separately indexed
texture coordinates and a real .mtl only when there are maps; PLY with per-corner UVs.
Read back with the project's reader and with trimesh."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
import trimesh

from hack_render.geometry import load_default_model
from hack_render.geometry.obj_io import ObjMaterials, read_obj, write_mesh


@pytest.fixture(scope="module")
def model():
    return load_default_model()


@pytest.fixture(scope="module")
def posed(model):
    import torch

    with torch.no_grad():
        out = model(psi=model.expression_vector("AU12=0.6,jawOpen=0.3"),
                    theta=torch.full((1, 8, 3), 0.05))
    return out.vertices[0].numpy()


def test_obj_round_trip_keeps_order_and_seams(model, posed, tmp_path):
    f, uv, tf = model.faces.numpy(), model.uvs.numpy(), model.uv_faces.numpy()
    path = write_mesh(tmp_path / "m.obj", posed, f, uv, tf)
    back = read_obj(path)
    assert back.vertices.shape == (model.num_vertices, 3)  # no seam splits, no drops
    np.testing.assert_array_equal(back.vertices.astype(np.float32), posed)  # bit for bit
    np.testing.assert_array_equal(back.faces, f)
    np.testing.assert_array_equal(back.uv_faces, tf)
    np.testing.assert_allclose(back.uvs, uv, atol=1e-8)
    text = path.read_text()
    assert "mtllib" not in text and "usemtl" not in text  # no maps: no dangling .mtl
    assert not (tmp_path / "m.mtl").exists()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tm = trimesh.load(path, process=False, force="mesh", maintain_order=True)
    # trimesh splits per corner, but every corner lands where the model's does
    np.testing.assert_allclose(tm.vertices[tm.faces], posed[f], atol=1e-7)


def test_obj_with_maps_writes_a_real_mtl(model, posed, tmp_path):
    mats = ObjMaterials(model.material_names, model.face_material.numpy(),
                        {"diffuse": "tex/diffuse.png", "normal": "tex/normal.png"},
                        colours={"M_Teeth": (0.78, 0.72, 0.6)})
    path = write_mesh(tmp_path / "m.obj", posed, model.faces.numpy(), model.uvs.numpy(),
                      model.uv_faces.numpy(), mats)
    assert "mtllib m.mtl" in path.read_text().splitlines()[:3]
    mtl = (tmp_path / "m.mtl").read_text()
    assert mtl.count("newmtl") == len(model.material_names)
    assert "map_Kd -s 0.5 1 1 tex/diffuse.png" in mtl and "norm -s 0.5 1 1 tex/normal.png" in mtl
    assert "Kd 0.7800 0.7200 0.6000" in mtl  # the teeth's own colour
    back = read_obj(path)
    assert back.materials == model.material_names
    np.testing.assert_array_equal(back.face_material, model.face_material.numpy())
    np.testing.assert_array_equal(back.faces, model.faces.numpy())


def test_ply_round_trip_keeps_order(model, posed, tmp_path):
    from trimesh.exchange.ply import load_ply

    f, uv, tf = model.faces.numpy(), model.uvs.numpy(), model.uv_faces.numpy()
    path = write_mesh(tmp_path / "m.ply", posed, f, uv, tf)
    with path.open("rb") as fh:
        d = load_ply(fh, fix_texture=False)
    np.testing.assert_array_equal(d["vertices"].astype(np.float32), posed)
    np.testing.assert_array_equal(d["faces"], f)
    tm = trimesh.load(path, process=False)  # trimesh's default splits at seams ...
    # ... but its per-corner UVs are the model's
    np.testing.assert_allclose(tm.visual.uv[tm.faces], uv[tf], atol=1e-6)
    np.testing.assert_allclose(tm.vertices[tm.faces], posed[f], atol=1e-7)


def test_mesh_cli_writes_model_order_and_no_mtl(tmp_path):
    out = tmp_path / "head.obj"
    r = subprocess.run([sys.executable, "-m", "hack_render.cli", "mesh", "-o", str(out),
                        "--both"], capture_output=True, text=True, check=False)
    assert r.returncode == 0, r.stderr
    m = load_default_model()
    assert read_obj(out).vertices.shape == (m.num_vertices, 3)
    assert "mtllib" not in out.read_text()
    assert (tmp_path / "head.ply").read_bytes().startswith(b"ply\n")


def test_write_mesh_bad_path_is_a_clean_error(model, tmp_path):
    from hack_render.errors import HackError

    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(HackError, match="cannot write"):
        write_mesh(blocker / "m.obj", model.template.numpy(), model.faces.numpy())
    with pytest.raises(HackError, match="unsupported mesh format"):
        write_mesh(tmp_path / "m.stl", model.template.numpy(), model.faces.numpy())
