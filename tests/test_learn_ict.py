"""Building the default model from ICT-FaceKit reproduces the shipped file (slow: ~15 s)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hack_render.errors import HackError

# The raw ICT-FaceKit data is development data, not part of the package: tests that need it
# look for it in HACK_ICT_DIR or beside the checkout and skip, with the reason, without it.
ICT = Path(os.environ.get("HACK_ICT_DIR")
           or Path(__file__).resolve().parents[2] / "shared" / "data" / "ict-facekit")
needs_ict = pytest.mark.skipif(
    not (ICT / "generic_neutral_mesh.obj").is_file(),
    reason=f"raw ICT-FaceKit data not found at {ICT} (development data; set HACK_ICT_DIR)")


def test_load_ict_refuses_bad_folders(tmp_path):
    from hack_render.learn.ict_default import load_ict

    with pytest.raises(HackError, match="not a folder"):
        load_ict(tmp_path / "missing")
    with pytest.raises(HackError, match="generic_neutral_mesh.obj"):
        load_ict(tmp_path)


def test_load_ict_names_where_to_get_the_data(tmp_path):
    from hack_render.learn.ict_default import load_ict

    with pytest.raises(HackError, match="ICT-FaceKit is public"):
        load_ict(tmp_path / "missing")


@needs_ict
def test_packaged_template_is_the_ict_obj(tmp_path):
    """The package's skin template (the atlas's mesh) is ICT-FaceKit's OBJ, exactly; the
    converter writes the same arrays again."""
    from appearance.uv import TEMPLATE_FILE, load_template, write_template_file
    from hack_render.geometry.obj_io import read_obj

    obj = read_obj(ICT / "generic_neutral_mesh.obj")
    for tpl in (load_template(TEMPLATE_FILE), load_template(write_template_file(ICT, tmp_path / "t.npz"))):
        for key in ("vertices", "faces", "uvs", "uv_faces", "face_material", "polygon_of_face"):
            np.testing.assert_array_equal(getattr(tpl, key), getattr(obj, key), err_msg=key)
        assert tpl.materials == obj.materials


def test_shape_pca_is_orthonormal_and_preserves_covariance():
    from hack_render.learn.ict_default import shape_pca

    rng = np.random.default_rng(0)
    modes = rng.standard_normal((6, 40, 3)) * np.linspace(3, 1, 6)[:, None, None]
    comps, std = shape_pca(modes)
    flat = comps.reshape(len(comps), -1)
    np.testing.assert_allclose(flat @ flat.T, np.eye(len(comps)), atol=1e-10)
    d = modes.reshape(6, -1)
    cov_in = d.T @ d
    cov_out = (flat.T * std**2) @ flat
    np.testing.assert_allclose(cov_out, cov_in, atol=1e-8)


@pytest.mark.slow
@needs_ict
def test_build_from_ict_matches_shipped_model(tmp_path):
    from hack_render.learn.ict_default import build_default_model
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file, save_model_file

    arrays, meta = build_default_model(ICT)
    save_model_file(tmp_path / "m.npz", arrays, meta)
    built, _ = load_model_file(tmp_path / "m.npz")
    shipped, meta = load_model_file(default_model_path())
    # The shipped model is v2 (`hack-render learn model`): the v1 build's skeleton,
    # FACS table and generic expressions are kept as they are, and its weights outside the
    # neck, where the pose learner refines them (hack_render.learn.pose_energy) ...
    for key in ("joint_regressor", "expression_basis", "faces", "uvs", "au_matrix"):
        np.testing.assert_allclose(built[key], shipped[key], atol=1e-6, err_msg=key)
    neck = np.zeros(len(built["skinning_weights"]), bool)
    neck[shipped["pose_pca_vertices"]] = True
    np.testing.assert_allclose(built["skinning_weights"][~neck], shipped["skinning_weights"][~neck],
                               atol=1e-6)
    # ... and its template differs only where the larynx was removed (front neck).
    moved = np.linalg.norm(built["template_vertices"] - shipped["template_vertices"], axis=1)
    if meta.get("model_version", 1) >= 2:
        assert (moved > 1e-6).sum() < 0.02 * len(moved)
        assert moved.max() < 0.01
        moved_at = built["template_vertices"][moved > 1e-6]
        assert np.all(np.abs(moved_at[:, 0]) < 0.04) and np.all(moved_at[:, 2] > 0)  # front neck
    else:
        assert moved.max() < 1e-6


def test_load_ict_reads_original_facexmodel_folder(tmp_path):
    """The original ICT-FaceKit layout: one OBJ per identity mode and per expression."""
    import json

    from hack_render.learn.ict_default import load_ict

    root = tmp_path / "ICT-FaceKit" / "FaceXModel"
    root.mkdir(parents=True)
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)

    def write(name, verts):
        lines = [f"v {x} {y} {z}" for x, y, z in verts] + ["vt 0 0", "vt 1 0", "vt 0 1", "vt 1 1",
                                                          "usemtl M_Face", "f 1/1 2/2 4/4 3/3"]
        (root / name).write_text("\n".join(lines) + "\n")

    write("generic_neutral_mesh.obj", base)
    rng = np.random.default_rng(1)
    ids = [rng.standard_normal((4, 3)) for _ in range(2)]
    exps = {"jawOpen": rng.standard_normal((4, 3)), "eyeBlink_L": rng.standard_normal((4, 3))}
    for i, d in enumerate(ids):
        write(f"identity{i:03d}.obj", base + d)
    for name, d in exps.items():
        write(f"{name}.obj", base + d)
    (root / "vertex_indices.json").write_text(json.dumps({"expressions": list(exps), "idx_to_landmark_verts": [0]}))
    ict = load_ict(root.parent)  # the repository root is accepted too
    np.testing.assert_allclose(ict["identity"], np.stack(ids), atol=1e-5)
    np.testing.assert_allclose(ict["expressions"], np.stack(list(exps.values())), atol=1e-5)
    assert ict["expression_names"] == list(exps)
    assert len(ict["mesh"].faces) == 2  # the quad, fan-triangulated
