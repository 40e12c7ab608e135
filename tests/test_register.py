"""Registration to scans (hack_render.register) and the shape space learned from
registrations (hack_render.learn.shape): exact distances against brute force, the
similarity, scan reading and units, recovery of known parameters from synthetic scans,
the command's files and resume, baked colours, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from hack_render.errors import HackError
from hack_render.register.align import read_landmarks_3d, umeyama
from hack_render.register.measure import MeshDistance, closest_point_on_triangles
from hack_render.register.scan import detect_units, load_scan
from hack_render.register.synthetic import make_scan, random_rotation


@pytest.fixture(scope="module")
def model():
    from hack_render.geometry import load_default_model

    return load_default_model()


def _brute_closest(p, tri, n=200):
    """Closest of a dense barycentric grid on each triangle (a slow reference)."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    pts = tri[:, None, 0] + u[None, :, None] * (tri[:, None, 1] - tri[:, None, 0]) \
        + v[None, :, None] * (tri[:, None, 2] - tri[:, None, 0])
    d = np.linalg.norm(pts - p[:, None], axis=2)
    return d.min(1)


def test_closest_point_matches_brute_force_in_every_region():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(300, 3, 3))
    p = rng.normal(size=(300, 3)) * 2  # points in every vertex, edge and face region
    q = closest_point_on_triangles(p, tri[:, 0], tri[:, 1], tri[:, 2])
    exact = np.linalg.norm(p - q, axis=1)
    brute = _brute_closest(p, tri)
    assert np.all(exact <= brute + 1e-9)  # never farther than any point of the triangle
    assert np.abs(exact - brute).max() < 0.02  # and the grid's spacing from the best


def test_mesh_distance_is_exact_on_a_mesh():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    md = MeshDistance(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200, 3)) * 0.08
    d, q, _ = md.closest(pts)
    tri = mesh.vertices[mesh.faces]
    brute = np.stack([np.linalg.norm(pts - closest_point_on_triangles(
        pts, *[np.repeat(tri[i:i + 1, k], len(pts), 0) for k in range(3)]), axis=1)
        for i in range(len(tri))], 1).min(1)
    np.testing.assert_allclose(d, brute, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pts - q, axis=1), d, atol=1e-12)


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(51, 3))
    R = random_rotation(rng)
    dst = 3.5 * src @ R.T + np.array([1.0, -2.0, 0.5])
    s, R2, _ = umeyama(src, dst)
    assert s == pytest.approx(3.5)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    s1, R1, _ = umeyama(src, dst / 3.5, with_scale=False)
    assert s1 == 1.0 and np.allclose(R1, R, atol=1e-10)


@pytest.mark.parametrize("metres,units", [(0.25, "m"), (0.6, "m"), (25.0, "cm"), (60.0, "cm"),
                                          (250.0, "mm"), (600.0, "mm")])
def test_units_from_size(metres, units):
    assert detect_units(metres) == units


def test_units_refused_when_no_head_size():
    with pytest.raises(HackError, match="--units"):
        detect_units(1e6)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb", ".xyz", ".npy"])
def test_scan_formats_read_in_metres(tmp_path, suffix):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=120.0)  # mm: a head-sized ball
    path = tmp_path / f"s{suffix}"
    if suffix == ".xyz":
        np.savetxt(path, mesh.vertices)
    elif suffix == ".npy":
        np.save(path, mesh.vertices)
    else:
        mesh.export(path)
    scan = load_scan(path)
    assert scan.units == "mm"
    assert scan.extent == pytest.approx(0.24, rel=0.02)
    assert scan.is_mesh == (suffix not in (".xyz", ".npy"))
    # normals point outwards (the ball's centre is the origin)
    assert (np.einsum("ni,ni->n", scan.normals, scan.points) > 0).mean() > 0.99


@pytest.mark.parametrize("content,match", [
    (b"this is not a mesh\n", "cannot read"),
    (b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n", "empty|no mesh or points"),
])
def test_unreadable_scans_are_refused(tmp_path, content, match):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(HackError, match=match):
        load_scan(path)


def _textured_ball_obj(path):
    """An OBJ of a textured ball (v, vt, f v/vt lines), as scanners write them."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=120.0)
    uv = (mesh.vertices[:, :2] / 240.0 + 0.5).round(6)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u} {v}" for u, v in uv]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in f) for f in mesh.faces]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("frac", [0.2, 0.45, 0.6, 0.8, 0.97])
def test_an_obj_cut_short_is_refused_naming_the_line(tmp_path, frac):
    """A scan cut off mid-file (an interrupted copy) was read without a word: faces cut to
    two corners dropped, a file cut among its texture coordinates read as a point cloud;
    the registration then reported "ok" (issue 65)."""
    data = _textured_ball_obj(tmp_path / "whole.obj").read_bytes()
    assert load_scan(tmp_path / "whole.obj").notes == [
        "units detected: mm (pass --units to override)"]
    cut = len(data) * frac
    cut = int(cut) + 2 if data[int(cut)] in b" \n" else int(cut)  # inside a number or word
    (tmp_path / "scan.obj").write_bytes(data[:cut])
    n = data[:cut].count(b"\n") + 1
    with pytest.raises(HackError, match=rf"scan\.obj:{n}: expected .*cut short"):
        load_scan(tmp_path / "scan.obj")


def test_an_obj_cut_between_numbers_is_read_with_a_note(tmp_path):
    """Cut right after a whole number, a file cannot be told from a shorter one but for
    its missing last newline: read, and the report's notes say so and how much was read."""
    data = _textured_ball_obj(tmp_path / "whole.obj").read_bytes()
    (tmp_path / "scan.obj").write_bytes(data.rstrip(b"\n")[:-1] + b"1")
    scan = load_scan(tmp_path / "scan.obj", units="mm")
    note = "scan.obj does not end with a newline: it may be cut short; read 642 vertices"
    assert scan.notes == [note + " and 1,280 faces"]
    for text, match in [("v 1 2 3\nf 1 2 4\n", r"bad\.obj:2: a face refers to vertex 4"),
                        ("v 1 2 3\nv 1 2 x\n", r"bad\.obj:2: expected numbers after 'v'"),
                        ("v 1 2 3\nf 1/1 1/1 1//1\n", r"bad\.obj:2: .*one form")]:
        (tmp_path / "bad.obj").write_text(text)
        with pytest.raises(HackError, match=match):
            load_scan(tmp_path / "bad.obj")


def test_non_finite_scans_are_refused(tmp_path):
    v = np.random.default_rng(0).normal(size=(500, 3)) * 0.1
    v[7] = np.nan
    np.save(tmp_path / "nan.npy", v)
    with pytest.raises(HackError, match="NaN or infinite"):
        load_scan(tmp_path / "nan.npy")


def test_landmark_files_of_the_wrong_shape_are_named(tmp_path):
    np.save(tmp_path / "l.npy", np.zeros((68, 2)))
    with pytest.raises(HackError, match=r"\(68, 3\).*found shape \(68, 2\)"):
        read_landmarks_3d(tmp_path / "l.npy")
    (tmp_path / "l.json").write_text(json.dumps({"landmarks": np.zeros((51, 3)).tolist()}))
    pts, ids = read_landmarks_3d(tmp_path / "l.json")
    assert pts.shape == (51, 3) and ids[0] == 17


def _posed_truth(model, seed=0, posed=True):
    from hack_render.geometry import distribute_head_rotation

    g = torch.Generator().manual_seed(seed)
    beta = torch.randn(1, 20, generator=g)
    theta = distribute_head_rotation(torch.deg2rad(torch.tensor([[12.0, 25.0, 6.0]]))) \
        if posed else None
    with torch.no_grad():
        out = model(beta=beta, theta=theta, psi="jawOpen=0.2" if posed else None)
    return out.vertices[0].double().numpy(), beta, theta


def test_register_recovers_a_posed_synthetic_scan(model):
    """A re-tessellated, noisy, holed scan of a posed head in a random frame and unit:
    the registration lies on it (scan-to-mesh), its vertices are near the truth, and
    the model's own fit (no offsets) explains most of it."""
    from hack_render.register.fitting import RegisterConfig, model_subsets
    from hack_render.register.pipeline import register
    from hack_render.register.scan import Scan

    truth, _, theta = _posed_truth(model)
    sc = make_scan(model, truth, seed=11, noise_m=0.0003)
    pts = sc.vertices / sc.scale  # metres
    scan = Scan.from_mesh("t", pts, sc.faces)
    lmk = sc.truth[model.landmark_indices.numpy()] / sc.scale
    cfg = RegisterConfig(rigid_iterations=15, model_iterations=120, free_iterations=25,
                         num_shape=30, scan_points=4000)
    reg = register(model, scan, lmk, tuple(range(68)), cfg, progress=False)
    rep = reg.report
    assert rep["status"] == "ok", rep["failure"]
    assert rep["scan_to_mesh_mm"]["all"]["mean"] < 0.6
    assert rep["model_only_scan_to_mesh_mm"]["mean"] < 1.2
    skin, _ = model_subsets(model)
    err = 1000 * np.linalg.norm(reg.vertices - sc.truth / sc.scale, axis=1)[skin]
    assert np.median(err) < 1.5
    # the registration is in the scan's frame: its landmarks on the given ones
    assert rep["landmarks"]["median_mm"] < 2.0
    # the neck is turned by the joints, not the torso by the root (25 deg axial in truth)
    axial = np.rad2deg(np.asarray(reg.params["theta"])[:, 1].sum())
    assert abs(axial - np.rad2deg(theta[0, :, 1].sum().item())) < 7.0, axial


def test_register_command_writes_files_that_round_trip_and_resumes(model, tmp_path):
    from typer.testing import CliRunner

    from hack_render.cli import app
    from hack_render.geometry.params import load_params, model_inputs

    truth, _, _ = _posed_truth(model, seed=1, posed=False)
    sc = make_scan(model, truth, seed=2, holes=1)
    sc.mesh().export(tmp_path / "head.ply")
    np.save(tmp_path / "lmk.npy", sc.truth[model.landmark_indices.numpy()])
    args = ["register", str(tmp_path / "head.ply"), "-o", str(tmp_path / "out"), "--landmarks",
            str(tmp_path / "lmk.npy"), "--iterations", "10,40,10", "--shape-components", "20",
            "--quiet"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    out = tmp_path / "out" / "head"
    rep = json.loads((out / "report.json").read_text())
    assert rep["status"] == "ok" and rep["units"] == sc.units
    assert set(rep["files"]) >= {"registered.obj", "params.json", "offsets.npy", "error.ply",
                                 "error.png", "landmarks.json"}
    reg = trimesh.load(out / "registered.obj", process=False, force="mesh", maintain_order=True)
    assert len(reg.vertices) == model.num_vertices  # the model's vertex order kept
    err = trimesh.load(out / "error.ply", process=False)
    assert len(err.vertices) == model.num_vertices
    # params.json re-posed by the model, moved by the report's similarity, is the
    # registered mesh before its offsets
    params = load_params(out / "params.json")
    with torch.no_grad():
        v = model(**model_inputs(model, params)).vertices[0].double().numpy()
    sim = rep["similarity_scan_to_model"]
    R, t, s = np.asarray(sim["R"]), np.asarray(sim["t"]), sim["scale"]
    back = ((v - t) @ R) / s / rep["scan_scale_m"]
    model_only = trimesh.load(out / "registered_model.obj", process=False, force="mesh",
                              maintain_order=True)
    np.testing.assert_allclose(back, model_only.vertices, atol=2e-5 * sc.scale)
    # finished scans are skipped; changed settings are refused, not silently mixed
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0 and "1 already done" in again.output
    changed = CliRunner().invoke(app, args[:-1] + ["--no-free-form", "--quiet"])
    assert changed.exit_code != 0 and "other inputs or settings" in str(changed.exception or changed.output)


def test_a_sphere_with_landmarks_is_reported_failed(model, tmp_path, monkeypatch):
    """No head: the registration finishes but says it failed (no confident wrong answer)."""
    import functools

    from hack_render.register import pipeline
    from hack_render.register.fitting import RegisterConfig
    from hack_render.register.pipeline import register
    from hack_render.register.scan import Scan, SurfaceIndex

    # the ball's facets are 9 mm across: sampled every 2 mm (38k points) rather than the
    # default 0.8 mm (240k points, whose nearest-point queries were most of the time)
    monkeypatch.setattr(pipeline, "SurfaceIndex", functools.partial(SurfaceIndex,
                                                                    spacing=0.002))

    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.11)
    with torch.no_grad():
        lmk = model().landmarks[0].double().numpy()
    centre = lmk.mean(0)
    v = ball.vertices + centre
    scan = Scan.from_mesh("ball", v, ball.faces)
    # the landmarks put onto the ball: a plausible start with no face behind it
    d = lmk - centre
    lm_ball = centre + 0.11 * d / np.linalg.norm(d, axis=1, keepdims=True)
    cfg = RegisterConfig(rigid_iterations=10, model_iterations=40, free_iterations=0,
                         free_form=False, num_shape=20, scan_points=4000)
    rep = register(model, scan, lm_ball, tuple(range(68)), cfg, progress=False).report
    assert rep["status"] == "failed" and rep["failure"]


def test_landmarks_are_found_on_a_rotated_scan(model):
    """The face is found on a scan in a random orientation and unit, its inner landmarks
    within a few millimetres of the model's landmark vertices."""
    from hack_render.register.find_landmarks import find_landmarks
    from hack_render.register.scan import Scan

    truth, _, _ = _posed_truth(model, seed=3, posed=False)
    sc = make_scan(model, truth, seed=4, retessellated=False)
    pts = sc.vertices / sc.scale
    scan = Scan.from_mesh("t", pts, sc.faces)
    found, ids, info = find_landmarks(scan, size=256)
    ref = sc.truth[model.landmark_indices.numpy()][list(ids)] / sc.scale
    err = 1000 * np.linalg.norm(found - ref, axis=1)
    assert len(ids) >= 35 and np.median(err) < 6.0, (len(ids), np.median(err), info)


def test_baked_colours_are_the_scan_colours(model):
    """A scan coloured from a known diffuse map: the baked map equals it where seen."""
    from appearance import AppearanceModel
    from hack_render.register.bake import bake
    from hack_render.register.scan import Scan

    truth, _, _ = _posed_truth(model, seed=5, posed=False)
    app = AppearanceModel.load()
    tex = app.maps(app.sample_alpha(1, seed=3)).diffuse[0].numpy()  # (256, 512, 3)
    uv = model.vertex_uv.numpy()
    h = tex.shape[0]
    px = np.clip((uv[:, 0] / 2 * 2 * h).astype(int), 0, 2 * h - 1)
    py = np.clip(((1 - uv[:, 1]) * h).astype(int), 0, h - 1)
    colors = tex[py, px]
    skin_like = uv[:, 0] < 2
    scan = Scan.from_mesh("c", truth, model.faces.numpy(), colors=colors)
    maps = bake(truth, model.faces.numpy(), scan, height=256)
    seen = maps["seen"]
    assert seen.mean() > 0.3 and skin_like.any()
    diff = np.abs(maps["diffuse"][seen] - tex[seen]).mean()
    assert diff < 0.03, diff
    assert maps["diffuse"].shape == (256, 512, 3) and np.isfinite(maps["diffuse"]).all()


def test_learn_shape_spans_its_registrations_and_keeps_the_model(model, tmp_path):
    """Six registrations from the model itself: the learned space reconstructs each, and
    the beta-dependent maps carried over give the old model's mesh for the same shape."""
    from hack_render.geometry import HackModel
    from hack_render.geometry.obj_io import write_mesh
    from hack_render.learn.shape import learn_shape

    g = torch.Generator().manual_seed(7)
    betas = torch.randn(6, 10, generator=g)
    paths = []
    with torch.no_grad():
        for i, b in enumerate(betas):
            # without the larynx (eta = 0): the model adds L(beta, eta, tau) to the shape
            v = model(beta=b[None], eta=torch.zeros(1)).vertices[0].numpy()
            paths.append(write_mesh(tmp_path / f"r{i}.obj", v, model.faces.numpy()))
    arrays, meta, curves = learn_shape(paths, None, None)
    new = HackModel(arrays, meta)
    assert new.num_shape == 5
    comp = np.asarray(curves["compactness"])
    assert np.all(np.diff(comp) > 0) and 0.5 < comp[-1] < 1.0 + 1e-9
    assert curves["generalisation_mm_mean"][0] > curves["generalisation_mm_mean"][-1]
    # mesh 0 as learn_shape aligned it: its PCA coordinates give it back exactly
    from hack_render.learn.shape import ALIGN_REGIONS, procrustes

    meshes = np.stack([trimesh.load(p, process=False, force="mesh", maintain_order=True).vertices
                       for p in paths])
    ids = np.flatnonzero(np.isin(model.vertex_region.numpy(),
                                 [model.region_names.index(r) for r in ALIGN_REGIONS]))
    aligned0 = procrustes(meshes, model.template.double().numpy(), ids)[0]
    comps = torch.as_tensor(arrays["shape_components"]).reshape(5, -1).double()
    std = torch.as_tensor(arrays["shape_std"]).double()
    mean = torch.as_tensor(arrays["template_vertices"]).double().reshape(-1)
    w = (comps @ (torch.as_tensor(aligned0).reshape(-1) - mean)) / std
    zero = torch.zeros(1)
    with torch.no_grad():
        v0 = model(beta=betas[:1], eta=zero).vertices[0].double()
        v_new = new(beta=w[None].float(), eta=zero).vertices[0].double()
        # personalised expression through the carried-over MLP against the old model's
        e_new = new(beta=w[None].float(), psi="AU12=1", eta=zero).vertices[0].double() - v_new
        e_old = model(beta=betas[:1], psi="AU12=1", eta=zero).vertices[0].double() - v0
    assert np.abs(v_new.numpy() - aligned0).max() < 2e-4  # metres (float32 model)
    _, R, _ = umeyama(v_new.numpy(), v0.numpy(), with_scale=False)
    # the expression deltas come from the carried-over MLP; Procrustes moves each mesh a
    # little (identity differences), which no identity in the old space does, so beta is
    # carried over to within that motion: within 10 % of the expression's size
    diff = np.linalg.norm(e_new.numpy() @ R.T - e_old.numpy(), axis=1)
    assert diff.max() < 0.1 * np.linalg.norm(e_old.numpy(), axis=1).max(), diff.max()


def test_textured_scans_carry_their_texture_colours(tmp_path):
    """A textured OBJ (texture image + UVs): the surface samples take the texture's colour."""
    from PIL import Image

    from hack_render.register.scan import SurfaceIndex, srgb_to_linear

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.12)
    uv = np.stack([(mesh.vertices[:, 0] > 0) * 0.5 + 0.25, np.full(len(mesh.vertices), 0.5)], 1)
    img = np.zeros((8, 8, 3), np.uint8)
    img[:, :4] = (200, 40, 40)  # u < 0.5: red
    img[:, 4:] = (40, 40, 200)  # u >= 0.5: blue
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(img))
    mesh.export(tmp_path / "t.obj")
    scan = load_scan(tmp_path / "t.obj")
    assert scan.texture is not None and scan.has_color
    index = SurfaceIndex(scan)
    right = index.points[:, 0] > 0.05
    red, blue = srgb_to_linear(np.array([200, 40, 40]) / 255), srgb_to_linear(np.array([40, 40, 200]) / 255)
    np.testing.assert_allclose(np.median(index.colors[right], 0), blue, atol=0.02)
    np.testing.assert_allclose(np.median(index.colors[index.points[:, 0] < -0.05], 0), red, atol=0.02)


def test_landmarks_are_found_on_a_point_cloud(model):
    """A point cloud (no faces, estimated normals) is meshed, then its face found."""
    from hack_render.register.find_landmarks import find_landmarks
    from hack_render.register.scan import Scan, estimate_normals

    truth, _, _ = _posed_truth(model, seed=6, posed=False)
    sc = make_scan(model, truth, seed=8)
    pts = sc.vertices / sc.scale
    found, ids, _ = find_landmarks(Scan("pc", pts, estimate_normals(pts)), size=256)
    ref = sc.truth[model.landmark_indices.numpy()][list(ids)] / sc.scale
    assert len(ids) >= 35 and np.median(1000 * np.linalg.norm(found - ref, axis=1)) < 6.0


def test_register_outputs_feed_the_appearance_builder(tmp_path):
    """`learn appearance OUTDIR` takes register's folders: baked maps in textures/, and
    scans without colours (no maps) left out."""
    from appearance.builder import subject_folders

    for name in ("a", "b", "c"):
        (tmp_path / name / "textures").mkdir(parents=True)
        (tmp_path / name / "textures" / "diffuse.exr").write_bytes(b"")
        (tmp_path / name / "registered.obj").write_text("")
    (tmp_path / "grey").mkdir()
    (tmp_path / "grey" / "registered.obj").write_text("")
    got = [p.relative_to(tmp_path).as_posix() for p in subject_folders(tmp_path)]
    assert got == ["a/textures", "b/textures", "c/textures"]


def _front_of(v: np.ndarray, faces: np.ndarray, z0: float):
    """The mesh's part in front of the plane z = z0 (a scan that stops there)."""
    keep = faces[(v[faces, 2] > z0).all(1)]
    used = np.unique(keep)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return v[used], remap[keep]


def test_error_map_greys_what_the_scan_does_not_cover(model):
    """error.png's legend says grey for "not measured", but the skin beyond a scan's edge
    (here: all behind the ears, the scan being the face and the front of the neck) was
    measured to the scan's edge and drawn red (>= 3 mm) (issue 65). Now it is not
    measured: nan in the vertex errors (and error.ply), grey in the picture; what the scan
    covers keeps its colour."""
    from hack_render.register.fitting import model_subsets
    from hack_render.register.outputs import heat_map_views
    from hack_render.register.pipeline import measure
    from hack_render.register.scan import Scan

    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    faces = model.faces.numpy()
    skin, _ = model_subsets(model)
    z0 = float(np.median(v[skin, 2]))
    scan = Scan.from_mesh("front", *_front_of(v, faces, z0))
    _, err, stats = measure(model, scan, v, lambda x: x)
    front, back = skin[v[skin, 2] > z0 + 0.005], skin[v[skin, 2] < z0 - 0.005]
    assert np.isfinite(err[front]).all() and np.nanmax(err[front]) < 0.05  # on the scan
    assert np.isnan(err[back]).all()
    assert 0.3 < stats["skin_measured"] < 0.9
    # the point cloud of the same front: the same verdict (its spacing: the mesh's edges)
    cloud = Scan(scan.name, scan.points, scan.normals)
    _, err_c, _ = measure(model, cloud, v, lambda x: x)
    assert np.isnan(err_c[back[v[back, 2] < z0 - 0.02]]).all()
    assert np.isfinite(err_c[front[v[front, 2] > z0 + 0.02]]).mean() > 0.95
    # the picture: the side views show the uncovered back of the head in grey, no red
    tiles = np.stack(heat_map_views(v, faces, err, size=96)).astype(int)
    r, g, b = tiles[..., 0], tiles[..., 1], tiles[..., 2]
    red = (r > 60) & (r > 2 * g + 20) & (r > 2 * b + 20)
    grey = (np.abs(r - g) < 6) & (np.abs(g - b) < 6) & (r > 40)
    assert red.sum() == 0, red.sum(axis=(1, 2))
    assert grey[1:].sum(axis=(1, 2)).min() > 300, grey.sum(axis=(1, 2))
