"""Dataset: sampling purity, config errors, labels, files, shards, kill + resume, Ray."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hack_render.dataset import labels as lab
from hack_render.dataset.config import DEFAULTS, load_config
from hack_render.dataset.runner import Job, parse_shard, run
from hack_render.dataset.sampling import degrees_within_limits, sample_spec
from hack_render.errors import HackError

#: without hair: the strands' own tests are tests/test_dataset_hair.py (a scene is built
#: around each sample's groom: several seconds a sample)
TINY = {"render": {"resolution": 32, "spp": 2, "soft_mask_samples": 2},
        "appearance": {"height": 32}, "lighting": {"presets": ["studio", "light_stage"]},
        "hair": "none"}


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def au_names():
    from hack_render.geometry import load_default_model

    return load_default_model().au_names


# --- sampling -------------------------------------------------------------------------
def test_sample_is_pure_function_of_seed_and_index(au_names):
    cfg = load_config()
    a = [sample_spec(cfg, 7, i, au_names) for i in (5, 2, 9)]
    b = [sample_spec(cfg, 7, i, au_names) for i in (9, 2, 5)][::-1]
    assert json.dumps(a) == json.dumps(b)
    assert sample_spec(cfg, 7, 5, au_names) != sample_spec(cfg, 8, 5, au_names)
    assert sample_spec(cfg, 7, 5, au_names) != sample_spec(cfg, 7, 6, au_names)


def test_changing_one_section_leaves_the_others(au_names):
    a = sample_spec(load_config(), 1, 3, au_names)
    b = sample_spec(load_config(overrides={"camera": {"yaw_deg": [10, 20]}}), 1, 3, au_names)
    assert a["cameras"] != b["cameras"] and 10 <= b["cameras"][0]["yaw_deg"] <= 20
    for k in ("beta", "expression", "theta", "eta", "tau", "appearance", "lighting",
              "background", "hair"):
        assert a[k] == b[k], k
    c = sample_spec(load_config(overrides={"background": {"crop": [0.5, 0.6]}}), 1, 3,
                    au_names)
    assert c["background"] != a["background"] and 0.5 <= c["background"]["crop"][2] <= 0.6
    assert {k: v for k, v in c.items() if k != "background"} == \
        {k: v for k, v in a.items() if k != "background"}


def test_sampled_values_respect_the_config(au_names):
    cfg = load_config(overrides={"identity": {"components": 12, "truncation": 1.0},
                                 "expression": {"max_active": 2, "p_neutral": 0.0},
                                 "neck": {"head_std_deg": [40, 80, 30], "joint_noise_deg": 5},
                                 "larynx": {"p_swallow": 1.0},
                                 "camera": {"views": 3}})
    for i in range(40):
        s = sample_spec(cfg, 0, i, au_names)
        assert len(s["beta"]) == 12 and max(abs(x) for x in s["beta"]) <= 1.0
        assert 1 <= len(s["expression"]) <= 2
        assert all(a in au_names and 0.2 <= w <= 1.0 for a, w in s["expression"].items())
        # wide head rotations plus noise still end inside every joint's limits
        assert degrees_within_limits(s["theta"])
        assert s["swallow_phase"] is not None and 0 <= s["swallow_phase"] < 1
        assert len(s["cameras"]) == 3
    # the neck actually moves: the head rotations are not all clamped to zero
    spread = np.std([sample_spec(cfg, 0, i, au_names)["head_rotation_deg"] for i in range(40)], 0)
    assert (spread > 5).all()


# --- config errors ----------------------------------------------------------------------
@pytest.mark.parametrize("override,key", [
    ({"camera": {"yaw_deg": [30, 10]}}, "camera.yaw_deg"),
    ({"lighting": {"presets": ["studio", "disco"]}}, "lighting.presets"),
    ({"render": {"spp": 0}}, "render.spp"),
    ({"render": {"resolution": "big"}}, "render.resolution"),
    ({"larynx": {"p_swallow": 1.5}}, "larynx.p_swallow"),
    ({"camera": {"fov": 3}}, "camera.fov"),
    ({"neck": {"head_std_deg": [1, 2]}}, "neck.head_std_deg"),
    ({"background": {"source": "sky"}}, "background.source"),
    ({"background": {"photos": ["astronaut"]}}, "background.photos"),
    ({"background": {"luminance": [0.5, 0.1]}}, "background.luminance"),
    ({"render": {"denoise": "yes"}}, "render.denoise"),
    ({"render": {"sampler": "sobol"}}, "render.sampler"),
    ({"render": {"integrator": "bdpt"}}, "render.integrator"),
])
def test_bad_config_names_the_key(override, key):
    with pytest.raises(HackError, match=key.replace(".", r"\.")):
        load_config(overrides=override)


def test_config_file_errors(tmp_path):
    bad = tmp_path / "d.yaml"
    bad.write_text("camera:\n  focal_mm: [100, 50]\n")
    with pytest.raises(HackError, match="camera.focal_mm"):
        load_config(bad)
    bad.write_text("expression: {aus: [AU12, AU99]}\n")
    with pytest.raises(HackError, match="expression.aus"):
        run(Job(tmp_path / "o", 1, 0, load_config(bad)), progress=False)
    assert not (tmp_path / "o" / "samples").exists() or not any((tmp_path / "o" / "samples").iterdir())


def test_bad_job_values_fail_before_rendering(tmp_path):
    cfg = load_config(overrides=TINY)
    with pytest.raises(HackError, match="--n"):
        run(Job(tmp_path / "a", -1, 0, cfg), progress=False)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(HackError, match="output"):
        run(Job(blocker / "sub", 1, 0, cfg), progress=False)
    for text in ("3/2", "a/b", "1/0", "-1/4"):
        with pytest.raises(HackError, match="--shard"):
            parse_shard(text)
    assert parse_shard("2/5") == (2, 5)


def test_cli_bad_values_exit_2(tmp_path):
    cmd = [sys.executable, "-m", "hack_render.cli", "dataset", "--n", "-3", "-o", str(tmp_path)]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert r.returncode == 2 and "--n" in r.stderr


# --- labels -------------------------------------------------------------------------------
def test_label_table_covers_the_issue():
    for name in ("background", "face_skin", "neck_skin", "scalp", "lips", "eyes", "eyebrows",
                 "teeth", "gums_tongue", "eyelashes"):
        assert name in lab.LABELS
    assert set(lab.LABEL_DESCRIPTIONS) == set(lab.LABELS)


def test_label_atlas_places_regions_where_the_template_has_them():
    """UV lookups of known template vertices land on the expected labels."""
    from hack_render.geometry import load_default_model
    from hack_render.render.parts import REGIONS

    m = load_default_model()
    atlas = lab.skin_label_atlas()
    uv = m.vertex_uv.numpy()
    lm = m.landmark_indices.numpy()
    region = np.full((1, 1), REGIONS.index("face"))

    def label_of(v):
        return lab.LABELS[int(lab.to_labels(region, uv[v][None, None], atlas)[0, 0])]

    # upper-lip outer contour landmark (51) and brow landmarks (17-26, Multi-PIE)
    assert label_of(lm[51]) == "lips"
    assert sum(label_of(v) == "eyebrows" for v in lm[17:27]) >= 7
    # nose tip (30) is face skin
    assert label_of(lm[30]) == "face_skin"
    # front-of-neck vertices below the C4-C5 level are neck skin (the submental
    # area above it counts as face skin in the appearance atlas)
    t = m.template.numpy()
    c45_y = m.joints_template[m.joint_names.index("c4-c5"), 1].item()
    neck = np.flatnonzero((m.vertex_region.numpy() == m.region_names.index("neck"))
                          & (np.abs(t[:, 0]) < 0.01) & (t[:, 2] > 0.02) & (t[:, 1] < c45_y))
    back_region = np.full((1, 1), REGIONS.index("back_head"))
    labels = [lab.LABELS[int(lab.to_labels(back_region if uv[v, 0] >= 1 else region,
                                           uv[v][None, None], atlas)[0, 0])] for v in neck]
    assert len(labels) >= 5 and labels.count("neck_skin") >= 0.9 * len(labels)


@pytest.fixture(scope="module")
def label_texels():
    """The label atlas with its template layout: (atlas, layout, template mesh)."""
    from appearance.uv import default_template, rasterize_layout

    return lab.skin_label_atlas(), rasterize_layout(lab.ATLAS_HEIGHT), default_template()


def test_ears_are_the_pinna_on_both_atlas_tiles(label_texels):
    """The pinna's outer side lies on the face tile (it was `cheeks`, so face skin), and the
    appearance `ears` box covered the head skin behind the ear (issue 28)."""
    atlas, lay, mesh = label_texels
    v = mesh.vertices
    # EAR_VERTICES: one run of vertices beside the head per side, ids next to it elsewhere
    for (first, last), side in zip(lab.EAR_VERTICES, (1, -1)):
        assert (side * v[first:last + 1, 0] > 6.0).all()
    assert abs(v[lab.EAR_VERTICES[0][0] - 1, 0]) < 6 and abs(v[lab.EAR_VERTICES[1][1] + 1, 0]) < 6
    ears = atlas == lab.LABEL_ID["ears"]
    x, y, z = (lay.position[..., k] for k in range(3))
    face, back = lay.mask & (lay.tile == 0), lay.mask & (lay.tile == 1)
    tri = mesh.faces[np.where(lay.mask, lay.face, 0)]
    patch = np.zeros(lay.mask.shape, bool)
    for first, last in lab.EAR_VERTICES:
        patch |= ((tri >= first) & (tri <= last)).all(-1)
    # outer side: every face-tile texel of an ear patch more than 8 cm from the midline
    # (helix, antihelix, lobe; the head is at most 7.9 cm wide there) is `ears` (0 % before)
    outer = face & patch & (np.abs(x) > 8.0)
    assert outer.sum() > 500 and ears[outer].all()
    # cranial side: the back tile beyond 8.1 cm at ear height is the back of the pinna
    cranial = back & (np.abs(x) > 8.1) & (y > -3) & (y < 5)
    assert cranial.sum() > 50 and ears[cranial].all()
    # and nothing else: not the patches' cheek in front of the tragus, not the head skin
    # behind the ear (facing outwards on the back tile: 1350 texels before), nor elsewhere
    facing_out = lay.normal[..., 0] * np.sign(x) > 0.5
    assert not ears[face & (z > 2.0)].any()
    assert not ears[back & facing_out].any()
    assert not ears[lay.mask & (np.abs(x) < 6.0)].any()


def test_no_neck_label_on_the_face_above_the_jaw(label_texels):
    """A `neck` spot sat on the jaw below each ear (issue 28): on the face tile, neck skin
    is one region (the throat), all of it below the jaw contour's landmarks 4 and 12."""
    from scipy import ndimage

    from appearance.regions import LANDMARK_VERTICES

    atlas, lay, mesh = label_texels
    jaw_y = mesh.vertices[LANDMARK_VERTICES[[4, 12]], 1].max()
    face = lay.mask & (lay.tile == 0)
    neck = face & (atlas == lab.LABEL_ID["neck_skin"])
    assert neck.sum() > 1000
    assert not neck[lay.position[..., 1] > jaw_y].any()  # 216 texels before
    assert ndimage.label(neck)[1] == 1  # 3 regions before


def test_socket_texels_are_never_neck(label_texels):
    """The back tile's socket rims (triangles with a socket vertex whose nearest corner is
    a lip or lid vertex) were `neck` (issue 28): every texel of a triangle with a
    socket vertex is gums/tongue (mouth socket) or eyes (eye sockets)."""
    from appearance.regions import SOCKET_VERTICES
    from hack_render.geometry import load_default_model

    atlas, lay, mesh = label_texels
    model = load_default_model()
    groups, names = model.vertex_group.numpy(), model.group_names
    tri = mesh.faces[np.where(lay.mask, lay.face, 0)]
    corner = (tri >= SOCKET_VERTICES[0]) & (tri <= SOCKET_VERTICES[1])
    socket = lay.mask & (lay.tile == 1) & corner.any(-1)
    mouth = socket & (groups[np.where(corner, tri, 0)] == names.index("mouth_socket")).any(-1)
    assert socket.sum() > 1000 and mouth.sum() > 500
    # before: 206 rim texels of the three sockets were neck
    assert (atlas[mouth] == lab.LABEL_ID["gums_tongue"]).all()
    assert (atlas[socket & ~mouth] == lab.LABEL_ID["eyes"]).all()


def test_larynx_peak_follows_tau_and_sits_at_c4_c5(monkeypatch):
    import torch

    from hack_render.geometry import load_default_model

    m = load_default_model()
    assert m.has_larynx  # the shipped v2 model
    beta = torch.randn(1, 10, generator=torch.Generator().manual_seed(3))

    def peak(tau, eta=1.0):
        with torch.no_grad():
            out = m(beta=beta, eta=torch.tensor([eta]), tau=torch.tensor([tau]))
        k, p = lab.larynx_peak(m, out, tau, beta=beta)
        return k, p, out

    k, p, out = peak(0.0)
    # at the C4-C5 vertebral level, measured along the neck's axis (the ICT neck leans
    # forward ~24 degrees, so the front skin at a level sits lower than its joint)
    j = out.joints[0].numpy().astype(np.float64)
    name = m.joint_names.index
    axis = j[name("c3-c4")] - j[name("c6-c7")]
    axis /= np.linalg.norm(axis)
    assert abs((p - j[name("c4-c5")]) @ axis) <= lab.LARYNX_WINDOW[0]
    assert abs(p[0]) < lab.LARYNX_WINDOW[1]  # on the midline
    assert p[2] > out.joints[0, :, 2].max().item()  # in front of the spine
    # the vertex the larynx displaces most, whatever its size (eta = 0: a flat neck)
    assert peak(0.0, eta=0.0)[0] == peak(0.0, eta=2.0)[0] == k
    # sliding the larynx moves the peak vertex up the neck, never down, at the slide's
    # rate (a vertex label: it steps by the neck's 4-7 mm vertex spacing), not sideways
    taus = np.linspace(-0.015, 0.015, 13)
    ys = np.array([peak(t)[1] for t in taus])
    assert np.all(np.diff(ys[:, 1]) >= 0)
    assert abs(np.polyfit(taus, ys[:, 1], 1)[0] - 1.0) < 0.3
    assert np.ptp(ys[:, 0]) < 0.003
    # without a larynx basis: the most anterior midline neck vertex near C4-C5
    monkeypatch.setattr(m, "has_larynx", False)
    with torch.no_grad():
        out0 = m()
    k0, _p0 = lab.larynx_peak(m, out0, 0.0)
    cand = lab.larynx_candidates(m)
    rest = out0.rest_vertices[0].numpy()
    c45 = out0.rest_joints[0, m.joint_names.index("c4-c5")].numpy()
    win = cand[np.abs(rest[cand, 1] - c45[1]) < lab.LARYNX_WINDOW[0]]
    assert len(win) and rest[k0, 2] == rest[win, 2].max()


def _visibility_reference(head, points, tolerance=2e-3, see_through=("eyelashes",)):
    """Point visibility one ray layer at a time, the layer logic in numpy, full surface
    intersections, shapes' regions from the scene's dict; each layer starts 10 um past
    the last hit on the camera-to-point line."""
    import drjit as dr
    import mitsuba as mi

    from hack_render.render.parts import REGIONS

    cam = head.camera
    p = np.asarray(points, np.float64).reshape(-1, 3)
    z = (p @ cam.R.T + cam.t)[:, 2]
    px = cam.project(p)
    in_image = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) \
        & (px[:, 1] < cam.height)
    d = p - cam.center
    dist = np.linalg.norm(d, axis=1)
    d = d / dist[:, None]
    ray = mi.Ray3f(mi.Point3f(*[np.full(len(p), c, np.float32) for c in cam.center]),
                   mi.Vector3f(*[d[:, k].astype(np.float32) for k in range(3)]))
    through = [REGIONS.index(n) for n in see_through]
    through_ids = [sid for sid, (reg, _, _) in head._shape_regions.items() if reg in through]
    # the lights' rectangles: camera rays look through them
    emitter_ids = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0])
                   for s in head.scene.shapes() if s.is_emitter()]
    through_ids += emitter_ids
    blocked, alive, travelled = np.zeros(len(p), bool), np.ones(len(p), bool), np.zeros(len(p))
    for _ in range(4 + len(emitter_ids)):
        si = head.scene.ray_intersect(ray)
        ids = np.asarray(dr.reinterpret_array(mi.UInt32, si.shape), np.int64)
        t = np.where(np.asarray(si.is_valid(), bool), np.asarray(si.t, np.float64), np.inf)
        hit_before = alive & (travelled + t < dist - tolerance)
        passes = hit_before & np.isin(ids, through_ids)
        blocked |= hit_before & ~passes
        alive = passes
        if not alive.any():
            break
        travelled += np.where(alive, t + 1e-5, 0.0)
        ray = mi.Ray3f(ray(mi.Float(np.where(alive, t, 0.0).astype(np.float32)) + 1e-5), ray.d)
    return in_image, in_image & ~blocked


def test_point_visibility_one_kernel_matches_layer_by_layer(tmp_path):
    """Landmark visibility (one Dr.Jit kernel, see-through layers unrolled) gives the same
    flags as the layer-by-layer reference on skin vertices all round the head (front
    visible, back occluded), the eyelash cards' vertices and points inside the neck."""
    import torch

    from hack_render.dataset.sampling import model_kwargs
    from hack_render.dataset.worker import SampleRenderer, camera_of
    from hack_render.render.parts import vertex_normals

    r = SampleRenderer(load_config(overrides=TINY), tmp_path, 0)
    spec = r.spec(0)
    with torch.no_grad():
        out = r.model(**model_kwargs(r.model, spec))
    v = out.vertices[0].numpy().astype(np.float64)
    head = r.scene(spec["lighting"]["preset"])
    head.set_vertices(v)
    head.set_camera(camera_of(spec["cameras"][0], 32, "v"))
    # nudge vertices 1 mm outwards so that they are not hidden by their own triangles
    pts = v + 1e-3 * vertex_normals(v, r.topology.faces)
    group = r.model.vertex_group.numpy()
    eyes = np.isin(group, [r.model.group_names.index(g) for g in r.model.group_names
                           if g.startswith(("eyeball", "eyelashes"))])
    pts = np.concatenate([pts[::7], pts[eyes], out.joints[0].numpy(),
                          out.landmarks[0].numpy()])
    for see_through in (("eyelashes",), ()):
        got = head.visibility(pts, see_through=see_through)
        want = _visibility_reference(head, pts, see_through=see_through)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    got = head.visibility(pts)
    assert got[1].sum() > 100 and (got[0] & ~got[1]).sum() > 100  # both cases present
    # the see-through layers matter here: with opaque lashes fewer points are visible
    assert head.visibility(pts, see_through=())[1].sum() < got[1].sum()


# --- rendering: files, labels, determinism -------------------------------------------------
@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "full"
    cfg = load_config(overrides=dict(TINY, camera={"views": 2}))
    summary = run(Job(out, 3, 11, cfg), progress=False)
    return out, cfg, summary


def test_sample_files_and_labels(rendered):
    import imageio.v3 as iio

    from hack_render.io.image import read_exr

    out, _cfg, summary = rendered
    assert summary == {"rendered": 3, "skipped": 0, "total": 3,
                       "manifest": str(out / "manifest" / "shard-000-of-001.jsonl")}
    lines = (out / "manifest" / "shard-000-of-001.jsonl").read_text().splitlines()
    assert [json.loads(x)["index"] for x in lines] == [0, 1, 2]
    v = out / "samples" / "0000001" / "view_01"
    rgb = read_exr(v / "rgb.exr")
    depth = read_exr(v / "depth.exr")["Z"]
    seg = iio.imread(v / "segmentation.png")
    masks = read_exr(v / "masks.exr")
    normal = read_exr(v / "normal.exr")
    hit = seg > 0
    assert hit.any() and (~hit).any()
    # depth: positive planar z on the subject, 0 (the documented background) elsewhere
    assert (depth[hit] > 0.2).all() and (depth[~hit] == 0).all()
    # camera-space normals (OpenCV) of visible surfaces face the camera: z < 0 mostly
    nz = normal["Z"][hit]
    assert np.mean(nz < 0) > 0.95
    # soft masks: a partition of unity whose argmax matches the hard labels mostly
    stack = np.stack([masks[f"mask.{n}"] for n in lab.LABELS], -1)
    assert np.allclose(stack.sum(-1), 1.0, atol=1e-5)
    assert np.mean(stack.argmax(-1) == seg) > 0.85
    # the alpha matte is the coverage of the subject: 1 - background mask, in EXR and PNG
    assert np.allclose(rgb["A"], 1.0 - stack[..., 0], atol=1e-6)
    assert rgb["A"][stack[..., 0] == 1].max() == 0 and rgb["A"][stack[..., 0] == 0].min() == 1
    alpha8 = iio.imread(v / "alpha.png")
    assert np.abs(alpha8 / 255.0 - rgb["A"]).max() <= 0.5 / 255 + 1e-6
    # landmarks: projections of the 3D points with K, R, t; the face is seen
    cam = json.loads((v / "camera.json").read_text())
    K, R, t = (np.array(cam[k]) for k in ("K", "R", "t"))
    lm = json.loads((v / "landmarks.json").read_text())
    p3 = np.array(lm["face68"]["points_3d"])
    x = (p3 @ R.T + t) @ K.T
    assert np.allclose(x[:, :2] / x[:, 2:], lm["face68"]["points_2d"], atol=1e-6)
    assert sum(lm["face68"]["visible"]) >= 20
    assert len(lm["joints8"]["points_2d"]) == 8 and not any(lm["joints8"]["visible"])
    assert len(lm["larynx_peak"]["points_2d"]) == 1
    rec = json.loads((out / "samples" / "0000001" / "sample.json").read_text())
    assert [w["name"] for w in rec["views"]] == ["view_00", "view_01"]
    params = json.loads((out / "samples" / "0000001" / "params.json").read_text())
    assert np.allclose(params["theta"], rec["theta"])


def _eroded(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 3 x 3 neighbourhood lies in ``mask``."""
    p = np.pad(mask, 1)
    return np.all([p[dy:dy + mask.shape[0], dx:dx + mask.shape[1]]
                   for dy in range(3) for dx in range(3)], axis=0)


def test_background_photo_is_behind_the_subject_only(rendered, tmp_path):
    """Each sample's photo (scikit-image's, sampled crop) fills exactly the uncovered
    pixels: where the matte is 0 the RGB is the photo; where it is 1 the RGB and every
    label are those of the same sample rendered over its environment instead."""
    from hack_render.dataset.backgrounds import PHOTOS, background_image
    from hack_render.io.image import read_exr

    out, _cfg, _ = rendered
    env_cfg = load_config(overrides=dict(TINY, camera={"views": 2},
                                         background={"source": "environment"}))
    run(Job(tmp_path / "env", 3, 11, env_cfg), progress=False)
    names = set()
    for i in range(3):
        rec = json.loads((out / "samples" / f"{i:07d}" / "sample.json").read_text())
        bg = rec["background"]
        assert bg["source"] == "photo" and bg["name"] in PHOTOS
        names.add(bg["name"])
        photo = background_image(bg, 32, 32)
        assert abs(float(np.mean(photo @ [0.2126, 0.7152, 0.0722])) - bg["luminance"]) \
            < 0.5 * bg["luminance"]
        for v in range(2):
            a = out / "samples" / f"{i:07d}" / f"view_{v:02d}"
            b = tmp_path / "env" / "samples" / f"{i:07d}" / f"view_{v:02d}"
            rgb, rgb_env = read_exr(a / "rgb.exr"), read_exr(b / "rgb.exr")
            # the matte comes from the label rays, the film's coverage from its own
            # samples: they differ at the outline, so compare one pixel inside it
            clear, inside = _eroded(rgb["A"] == 0), _eroded(rgb["A"] == 1)
            img = np.stack([rgb[c] for c in "RGB"], -1)
            img_env = np.stack([rgb_env[c] for c in "RGB"], -1)
            np.testing.assert_allclose(img[clear], photo[clear], rtol=1e-5, atol=1e-7)
            assert clear.sum() > 100 and inside.sum() > 100
            np.testing.assert_allclose(img[inside], img_env[inside], rtol=1e-5, atol=1e-6)
            for name in ("segmentation.png", "depth.exr", "masks.exr", "alpha.png"):
                assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert len(names) >= 2  # seeded: different samples, different photos


def test_denoised_samples_keep_the_noisy_image(tmp_path, monkeypatch):
    """render.denoise on + keep_noisy: rgb.exr is OIDN's output over the same background,
    rgb_noisy.exr the path tracer's; without pyoidn 'on' is refused naming the extra."""
    pytest.importorskip("pyoidn")
    from hack_render.io.image import read_exr

    cfg = load_config(overrides=dict(TINY, render=dict(TINY["render"], denoise="on",
                                                       keep_noisy=True)))
    run(Job(tmp_path / "d", 1, 4, cfg), progress=False)
    v = tmp_path / "d" / "samples" / "0000000" / "view_00"
    den, noisy = read_exr(v / "rgb.exr"), read_exr(v / "rgb_noisy.exr")
    clear, inside = _eroded(den["A"] == 0), _eroded(den["A"] == 1)
    d = np.stack([den[c] for c in "RGB"], -1)
    n = np.stack([noisy[c] for c in "RGB"], -1)
    np.testing.assert_allclose(d[clear], n[clear], rtol=1e-5, atol=1e-7)
    assert np.abs(d[inside] - n[inside]).mean() > 1e-3  # the subject was denoised
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    with pytest.raises(HackError, match=r"hack-render\[denoise\]"):
        run(Job(tmp_path / "e", 1, 4, cfg), progress=False)


@pytest.mark.parametrize("k", [0, 2, 3])
def test_one_batch_labels_match_the_per_pass_reference(tmp_path, k):
    """label_images (one ray batch, labels looked up in Dr.Jit) gives exactly the G-buffer
    and segmentation, and the soft masks to rounding, of the reference: a pixel-centre pass
    plus one pass per sub-pixel point, labels in numpy."""
    from hack_render.dataset.worker import SampleRenderer

    cfg = load_config(overrides=dict(TINY, render={"resolution": 48, "spp": 1}))
    r = SampleRenderer(cfg, tmp_path, 5)
    r.render(0)
    head = r.scene(r.spec(0)["lighting"]["preset"])
    aov, seg, masks = lab.label_images(head, k, r.atlas)
    ref_aov = head.aovs()
    ref_seg = lab.to_labels(ref_aov["segmentation"], ref_aov["uv"], r.atlas)
    ref_masks = lab.soft_masks(head, k, r.atlas) if k else \
        np.eye(len(lab.LABELS), dtype=np.float32)[ref_seg]
    for key in ref_aov:
        assert np.array_equal(aov[key], ref_aov[key]), key
    assert np.array_equal(seg, ref_seg)
    # the lash cards' opacity varies along the strands: float32 sums in the kernel against
    # float64 ones in numpy, so equal to rounding
    np.testing.assert_allclose(masks, ref_masks, rtol=0, atol=1e-6)
    assert np.allclose(masks.sum(-1), 1.0, atol=1e-6)
    if k:  # the lash layer (rays continued behind the cards) is exercised
        lash = masks[..., lab.LABEL_ID["eyelashes"]]
        assert ((lash > 0) & (lash < 1)).any()


def test_scene_keeps_the_rig_order_of_lights(tmp_path):
    """Which light a random number selects depends on the scene's emitter order. Mitsuba's
    load-time optimisation listed them in an order that changed from load to load (the
    byte-identity flake of issue 7); HeadScene must keep the rig's order on every load."""
    from hack_render.dataset.worker import SampleRenderer
    from scenes.lights import preset

    rig = [f"light_{i}" for i in range(len(preset("studio").area))] + ["environment"]
    assert len(rig) >= 3
    r = SampleRenderer(load_config(overrides=TINY), tmp_path, 0)
    for _ in range(3):
        r.scenes.clear()
        scene = r.scene("studio").scene
        order = [e.get_shape().id() if e.get_shape() is not None else e.id()
                 for e in scene.emitters()]
        assert order == rig


def test_shards_and_order_give_the_same_files(rendered, tmp_path):
    out, cfg, _ = rendered
    sharded = tmp_path / "sharded"
    for k in (1, 0):  # the second shard first
        run(Job(sharded, 3, 11, cfg, (k, 2)), progress=False)
    a, b = tree(out), tree(sharded)
    samples = {k: v for k, v in a.items() if k.startswith("samples/")}
    assert samples == {k: v for k, v in b.items() if k.startswith("samples/")}
    m0 = (sharded / "manifest" / "shard-000-of-002.jsonl").read_text().splitlines()
    m1 = (sharded / "manifest" / "shard-001-of-002.jsonl").read_text().splitlines()
    full = (out / "manifest" / "shard-000-of-001.jsonl").read_text().splitlines()
    assert sorted(m0 + m1, key=lambda s: json.loads(s)["index"]) == full


@pytest.mark.slow
def test_render_order_does_not_change_pixels(tmp_path):
    """The same 16 samples rendered forwards and in a shuffled order by one renderer give
    the same RGB bytes. Before the worker refreshed the environment emitter's bounds
    (``HeadScene.sync_environment``; earlier, a rebuild from the rest mesh), the
    environment's bounding sphere was the previous sample's and ~1 sample in 16 had a
    pixel or two changed (64 px, 8 spp, all presets)."""
    from hack_render.dataset.worker import SampleRenderer

    cfg = load_config(overrides={"render": {"resolution": 64, "spp": 8, "soft_mask_samples": 0},
                                 "appearance": {"height": 64}, "hair": "none"})
    n = 16
    images = []
    for order in (range(n), np.random.default_rng(1).permutation(n)):
        out = tmp_path / f"o{len(images)}"
        r = SampleRenderer(cfg, out, 0)
        for i in order:
            r.render(int(i))
        images.append({i: (out / "samples" / f"{i:07d}" / "view_00" / "rgb.exr").read_bytes()
                       for i in range(n)})
    assert [i for i in range(n) if images[0][i] != images[1][i]] == []


def test_environment_bounds_follow_the_current_mesh(tmp_path):
    """Mitsuba hands the environment emitter the scene bounds from before an update, so
    the points it samples (and the shadow rays towards them, to the last bit) depended on
    the previously rendered mesh: the cause of the render-order flake. After
    ``sync_environment`` they depend on the current mesh alone."""
    import drjit as dr
    import mitsuba as mi
    import torch

    from hack_render.dataset.sampling import model_kwargs
    from hack_render.dataset.worker import SampleRenderer

    r = SampleRenderer(load_config(overrides=TINY), tmp_path, 0)
    head = r.scene("light_stage")  # a constant environment and no area lights
    with torch.no_grad():
        verts = [r.model(**model_kwargs(r.model, r.spec(i))).vertices[0].numpy()
                 for i in range(3)]
    n = 512

    def env_points(previous: int, sync: bool) -> np.ndarray:
        head.set_vertices(verts[previous])
        head.set_vertices(verts[0])
        if sync:
            head.sync_environment()
        it = dr.zeros(mi.Interaction3f, n)
        it.p = mi.Point3f(*[mi.Float(c) for c in
                            np.random.default_rng(0).uniform(-0.1, 0.1, (3, n))])
        u = mi.Point2f(*[mi.Float(c) for c in np.random.default_rng(1).uniform(0, 1, (2, n))])
        ds, _ = head.scene.sample_emitter_direction(it, u, False)
        return np.asarray(ds.p)

    assert np.array_equal(env_points(1, True), env_points(2, True))
    # the Mitsuba behaviour worked around (if this fails, Mitsuba no longer needs it)
    assert not np.array_equal(env_points(1, False), env_points(2, False))


def test_inline_and_background_writes_give_the_same_files(rendered, tmp_path):
    """``run`` writes on a background thread, ``SampleRenderer.render`` in the caller's."""
    from hack_render.dataset.worker import SampleRenderer

    out, cfg, _ = rendered
    SampleRenderer(cfg, tmp_path, 11).render(1)
    got = {k: v for k, v in tree(tmp_path).items() if k.startswith("samples/")}
    assert got and got == {k: v for k, v in tree(out).items()
                           if k.startswith("samples/0000001/")}


def test_failed_write_leaves_the_sample_incomplete(tmp_path, monkeypatch):
    """A write that fails on the writer thread surfaces in the sample's result and
    ``sample.json`` is not written, so --resume redoes the sample."""
    from hack_render.dataset import worker
    from hack_render.dataset.worker import SampleRenderer
    from hack_render.io import image

    real = image.write_exr

    def disk_full(path, *a, **k):
        if Path(path).name == "masks.exr":
            raise OSError("No space left on device")
        return real(path, *a, **k)

    monkeypatch.setattr(image, "write_exr", disk_full)
    monkeypatch.setattr(worker, "write_exr", disk_full, raising=False)  # imported at the top
    r = SampleRenderer(load_config(overrides=TINY), tmp_path, 0, background_writes=True)
    with pytest.raises(OSError, match="No space"):
        r.render(0)
    r.close()
    folder = tmp_path / "samples" / "0000000"
    assert (folder / "view_00" / "rgb.exr").is_file()  # queued after masks.exr: written
    assert not (folder / "sample.json").exists()
    assert not list(folder.rglob(".*"))  # no temporaries left


def test_interrupt_finishes_the_queued_writes_then_resume_completes(rendered, tmp_path,
                                                                    monkeypatch):
    """Ctrl-C while the next sample renders: the samples already handed to the writer
    are completed (files, sample.json, manifest line) before the run stops."""
    from hack_render.dataset.worker import SampleRenderer

    out, cfg, _ = rendered
    real = SampleRenderer.submit

    def submit(self, index, then=None):
        if index == 1:
            raise KeyboardInterrupt
        return real(self, index, then)

    monkeypatch.setattr(SampleRenderer, "submit", submit)
    target = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        run(Job(target, 3, 11, cfg), progress=False)
    assert (target / "samples" / "0000000" / "sample.json").is_file()
    log = (target / "manifest" / "shard-000-of-001.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in log] == [0]
    monkeypatch.setattr(SampleRenderer, "submit", real)
    summary = run(Job(target, 3, 11, cfg, resume=True), progress=False)
    assert summary["skipped"] == 1 and summary["rendered"] == 2
    assert tree(target) == {k: v for k, v in tree(out).items() if k != "preview.png"}


def test_other_config_in_same_folder_is_refused(rendered):
    out, cfg, _ = rendered
    other = load_config(overrides=dict(TINY, camera={"views": 1}))
    with pytest.raises(HackError, match="differs"):
        run(Job(out, 3, 11, other, resume=True), progress=False)
    with pytest.raises(HackError, match="seed"):
        run(Job(out, 3, 12, cfg, resume=True), progress=False)


def test_kill_midway_then_resume_gives_the_uninterrupted_files(rendered, tmp_path):
    """SIGKILL a CLI run after its first complete sample, damage one more sample as a kill
    between two file writes would, resume: the folder equals the uninterrupted run's."""
    import yaml

    out, cfg, _ = rendered
    cfg_file = tmp_path / "cfg.yaml"
    cfg_file.write_text(yaml.safe_dump(cfg))
    target = tmp_path / "killed"
    cmd = [sys.executable, "-m", "hack_render.cli", "dataset", "--n", "3", "-o", str(target),
           "--seed", "11", "--config", str(cfg_file)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    first = target / "samples" / "0000000" / "sample.json"
    deadline = time.time() + 300
    while not first.is_file() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert first.is_file()
    assert not (target / "samples" / "0000002" / "sample.json").is_file()
    # a partial sample: files without its record, one of them truncated, a stray temporary
    partial = target / "samples" / "0000002" / "view_00"
    partial.mkdir(parents=True, exist_ok=True)
    (partial / "rgb.png").write_bytes(b"\x89PNG truncated")
    (partial / ".depth.x1y2.exr").write_bytes(b"half")
    (partial / ".tmp-0a1b2c-x1y2z3w4.exr").write_bytes(b"half")  # hack_render.io's name
    # a complete sample with a damaged file is redone too
    if (target / "samples" / "0000001" / "sample.json").is_file():
        (target / "samples" / "0000001" / "view_00" / "depth.exr").write_bytes(b"bad")
    summary = run(Job(target, 3, 11, cfg, resume=True), progress=False)
    assert summary["skipped"] >= 1 and summary["rendered"] >= 1
    assert tree(target) == tree(out)
    again = run(Job(target, 3, 11, cfg, resume=True), progress=False)
    assert again["rendered"] == 0 and again["skipped"] == 3


def test_preview_contact_sheet(rendered, tmp_path):
    import imageio.v3 as iio

    from hack_render.dataset.preview import contact_sheet

    out, _, _ = rendered
    path = contact_sheet(out, tmp_path / "sheet.png", count=4, columns=2)
    img = iio.imread(path)
    assert img.shape == (64, 64, 3)
    # landmark dots (pure green) are drawn on the tiles
    assert np.any((img[..., 1] > 200) & (img[..., 0] < 80) & (img[..., 2] < 100))
    with pytest.raises(HackError, match="complete samples"):
        contact_sheet(tmp_path / "empty")


# --- Ray -----------------------------------------------------------------------------------
def test_ray_two_workers_match_serial(rendered, tmp_path):
    """Ray (the test extra installs it) in local mode with 2 actors: the same files as the
    serial run."""
    pytest.importorskip("ray")
    out, cfg, _ = rendered
    target = tmp_path / "ray"
    summary = run(Job(target, 3, 11, cfg), executor="ray", workers=2, progress=False)
    assert summary["rendered"] == 3
    a = {k: v for k, v in tree(out).items() if k != "preview.png"}
    assert tree(target) == a


def test_ray_missing_is_a_clear_error(tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_ray(name, *a, **k):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(HackError, match=r"hack-render\[ray\]"):
        run(Job(tmp_path, 1, 0, load_config(overrides=TINY)), executor="ray", progress=False)


def test_defaults_are_valid():
    assert load_config() == load_config(overrides={})
    assert set(DEFAULTS) == {"render", "identity", "expression", "neck", "larynx",
                             "appearance", "lighting", "background", "camera", "hair"}


def test_render_sss_option(tmp_path):
    """render.sss: subsurface scattering in the skin of the RGB images (off by default);
    the labels do not change with it, and a non-boolean value is a clear error."""
    import imageio.v3 as iio

    from hack_render.io.image import read_exr

    assert load_config()["render"]["sss"] is False
    outs = {}
    for flag in (False, True):
        cfg = load_config(overrides=dict(TINY, render=dict(TINY["render"], sss=flag)))
        out = tmp_path / f"sss{int(flag)}"
        assert run(Job(out, 1, 5, cfg), progress=False)["rendered"] == 1
        outs[flag] = out / "samples" / "0000000" / "view_00"
    a, b = (read_exr(outs[k] / "rgb.exr") for k in (False, True))
    assert not np.array_equal(a["R"], b["R"])
    np.testing.assert_allclose(b["R"].sum(), a["R"].sum(), rtol=0.05)
    assert np.array_equal(iio.imread(outs[False] / "segmentation.png"),
                          iio.imread(outs[True] / "segmentation.png"))
    with pytest.raises(HackError, match="render.sss"):
        load_config(overrides={"render": {"sss": "yes"}})
