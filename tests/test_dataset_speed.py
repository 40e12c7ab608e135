"""Dataset start-up (issue 65): scenes built ``like`` another, work moved to the prefetch
thread. Each must leave the files as they were: same scene, same pixels, same labels."""

from __future__ import annotations

import numpy as np

from hack_render.dataset import labels as lab
from hack_render.dataset.config import load_config
from hack_render.dataset.worker import SampleRenderer, camera_of
from hack_render.geometry import load_default_model
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import lights

#: as tests/test_dataset.py's (bald: a groom's scene is built per sample)
TINY = {"render": {"resolution": 32, "spp": 2, "soft_mask_samples": 2},
        "appearance": {"height": 32}, "lighting": {"presets": ["studio", "light_stage"]},
        "hair": "none"}


def tree(folder) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _scene(topo, verts, preset, like=None):
    cam = camera_of({"yaw_deg": 20.0, "pitch_deg": 5.0, "distance_scale": 1.0,
                     "focal_mm": 85.0}, 32, "t")
    # the box filter: bit-reproducible pixels (``emitters.sensor_dict``)
    settings = RenderSettings(32, 32, 4, pixel_filter="box")
    return HeadScene(topo, verts, lights.preset(preset), cam, settings, like=like)


def test_01_scene_built_like_another_is_the_same_scene():
    """A preset's scene reusing another's vertex-dependent set-up renders the same pixels
    and labels as one built from scratch; a scene on other vertices reuses nothing."""
    import torch

    model = load_default_model()
    topo = Topology.from_model(model)
    with torch.no_grad():
        rest = model().vertices[0].numpy().astype(np.float64)
    first = _scene(topo, rest, "studio")
    shared = _scene(topo, rest, "window", like=first)
    fresh = _scene(topo, rest, "window")
    assert shared._shared is first._shared and fresh._shared is not first._shared
    assert [p.name for p in shared.parts] == [p.name for p in fresh.parts]
    assert np.array_equal(shared.render(seed=3), fresh.render(seed=3))
    atlas = lab.skin_label_atlas()
    a, b = (lab.label_images(h, 2, atlas) for h in (shared, fresh))
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
    assert np.array_equal(a[0]["depth"], b[0]["depth"])
    moved = _scene(topo, rest * 1.01, "window", like=first)
    assert moved._shared is not first._shared


def test_02_first_sample_prefetched_while_scenes_build_gives_the_same_files(tmp_path):
    """The serial executor's start: the first sample's inputs made on the prefetch thread
    (after the projector and the label atlas) while the scenes are built; the files equal
    those of a renderer that makes everything in order, in its own thread."""
    cfg = load_config(overrides=TINY)
    ahead = SampleRenderer(cfg, tmp_path / "ahead", 5, background_writes=True)
    assert not ahead.scenes
    ahead.prefetch(0)
    ahead.submit(0).result()
    ahead.close()
    assert set(ahead.scenes) == set(cfg["lighting"]["presets"])
    plain = SampleRenderer(cfg, tmp_path / "plain", 5)
    plain.render(0)
    plain.close()
    a, b = tree(tmp_path / "ahead"), tree(tmp_path / "plain")
    assert any(k.endswith("segmentation.png") for k in a)
    assert a == b
    assert np.array_equal(ahead.atlas, lab.skin_label_atlas())


def test_03_normals_given_and_iris_left_to_the_camera_give_the_same_parameters():
    """``set_vertices(normals=..., iris=False)`` then ``set_camera``, as the dataset does
    (normals made on the prefetch thread), leaves the scene's mesh parameters as
    ``set_vertices`` then ``set_camera`` does."""
    import torch

    from hack_render.render.parts import vertex_normals

    model = load_default_model()
    topo = Topology.from_model(model)
    with torch.no_grad():
        rest = model().vertices[0].numpy().astype(np.float64)
        moved = model(theta=torch.full((1, 8, 3), 0.05, dtype=torch.float32)).vertices[0]
    moved = moved.numpy().astype(np.float64)
    cam = camera_of({"yaw_deg": -30.0, "pitch_deg": 10.0, "distance_scale": 1.1,
                     "focal_mm": 60.0}, 32, "u")
    a, b = _scene(topo, rest, "studio"), _scene(topo, rest, "studio")
    a.set_vertices(moved, update=False)
    a.set_camera(cam)
    b.set_vertices(moved, update=False, normals=vertex_normals(moved, topo.faces), iris=False)
    b.set_camera(cam)
    keys = [f"{p.name}.{k}" for p in a.parts for k in ("vertex_positions", "vertex_normals")
            if f"{p.name}.{k}" in a.params]
    assert "iris.vertex_positions" in keys and len(keys) > 10
    for k in keys:
        assert np.array_equal(np.asarray(a.params[k]), np.asarray(b.params[k])), k
    assert not np.array_equal(np.asarray(a.params["iris.vertex_positions"]),
                              moved[[p for p in a.parts if p.name == "iris"][0].gather]
                              .ravel().astype(np.float32))  # the cornea moved the iris


def test_04_label_atlas_cache_round_trip(tmp_path, monkeypatch):
    """The atlas kept on disk is the one rasterised; a damaged file is made again; with
    HACK_RENDER_NO_CACHE nothing is written."""
    h = 32
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("HACK_RENDER_NO_CACHE", raising=False)
    lab.skin_label_atlas.cache_clear()
    try:
        ref = lab.label_atlas(h)
        path = lab.atlas_cache_path(h)
        assert path is not None and not path.exists()
        assert np.array_equal(lab.skin_label_atlas(h), ref) and path.is_file()
        assert np.array_equal(np.load(path), ref)
        path.write_bytes(b"damaged")
        lab.skin_label_atlas.cache_clear()
        assert np.array_equal(lab.skin_label_atlas(h), ref)
        assert np.array_equal(np.load(path), ref)  # rewritten
        assert lab.atlas_cache_path(2 * h) != path
        monkeypatch.setenv("HACK_RENDER_NO_CACHE", "1")
        assert lab.atlas_cache_path(h) is None
    finally:
        lab.skin_label_atlas.cache_clear()
