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
    (after the projector and the label atlas) while its preset's scene alone is built, the
    other presets' scenes after its render; the files equal those of a renderer that makes
    everything in order, every scene first, in its own thread."""
    cfg = load_config(overrides=TINY)
    ahead = SampleRenderer(cfg, tmp_path / "ahead", 5, background_writes=True)
    assert not ahead.scenes
    alive = []
    render = HeadScene.render

    def counted(self, *args, **kwargs):
        alive.append(len(ahead.scenes))
        return render(self, *args, **kwargs)

    HeadScene.render = counted
    try:
        ahead.prefetch(0)
        ahead.submit(0).result()
    finally:
        HeadScene.render = render
    ahead.close()
    assert alive == [1]  # one scene when the first sample rendered
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
                              moved[next(p for p in a.parts if p.name == "iris").gather]
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


def test_05_appearance_caches_give_the_same_arrays(tmp_path, monkeypatch):
    """The appearance model, the subject projector's operators and the generator's atlas
    precomputation, kept on disk (``appearance.cache``), are the bits made without the
    cache; a damaged entry is made again; with HACK_RENDER_NO_CACHE nothing is written."""
    from appearance import generator
    from appearance.cache import cache_root
    from appearance.model import AppearanceModel
    from appearance.projected import SubjectProjector

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HACK_RENDER_NO_CACHE", "1")
    assert cache_root() is None
    plain = SubjectProjector()
    ctx = generator._atlas_context(32)
    assert not (tmp_path / "hack-render").exists()
    monkeypatch.delenv("HACK_RENDER_NO_CACHE")
    generator.atlas_context.cache_clear()
    try:
        for _ in range(2):  # made and kept, then read back
            kept = SubjectProjector()
            assert all(np.array_equal(getattr(kept, k), getattr(plain, k))
                       for k in ("pinv", "mean", "mask"))
            for k in ("mean", "basis", "gather", "mask"):
                assert np.array_equal(getattr(kept.model, k).numpy(),
                                      getattr(plain.model, k).numpy()), k
            assert kept.model.metadata == plain.model.metadata
            a, b = kept.maps(7, 32), plain.maps(7, 32)
            assert all(np.array_equal(getattr(a, k).numpy(), getattr(b, k).numpy())
                       for k in ("diffuse", "specular", "roughness", "normal"))
            got = generator.atlas_context(32)
            generator.atlas_context.cache_clear()
            assert np.array_equal(got.soft, ctx.soft) and np.array_equal(got.labels, ctx.labels)
            assert got.layout.height == 32 and np.array_equal(got.layout.fill, ctx.layout.fill)
        kinds = {p.name.split("-")[0] for p in cache_root().iterdir()}
        assert kinds == {"atlas_context", "model", "projector"}  # atlases at 32 and 64
        for p in cache_root().glob("projector-*/pinv.npy"):
            p.write_bytes(b"damaged")
        again = SubjectProjector(AppearanceModel.load())  # a model given: not cached
        assert np.array_equal(again.pinv, plain.pinv)
        assert np.array_equal(SubjectProjector().pinv, plain.pinv)  # made again
        assert all(np.load(p).shape == plain.pinv.shape
                   for p in cache_root().glob("projector-*/pinv.npy"))
    finally:
        generator.atlas_context.cache_clear()


def test_06_background_resize_is_scikit_image_resize():
    """``backgrounds.resize_linear`` (no skimage.transform import at the first sample) gives
    scikit-image's ``resize(order=1, anti_aliasing=True, preserve_range=True)`` bit for
    bit: down- and up-sampling, mirrored crops, odd shapes."""
    from skimage.transform import resize

    from hack_render.dataset.backgrounds import PHOTOS, photo, resize_linear

    img = photo(min(PHOTOS))
    rng = np.random.default_rng(0)
    for t in range(8):
        side = [0.03, 0.1, 0.5, 1.0][t % 4]
        ch = max(2, round(min(img.shape[:2]) * side))
        cw = max(2, min(img.shape[1], ch + t - 3))
        y0 = int(rng.integers(0, img.shape[0] - ch + 1))
        x0 = int(rng.integers(0, img.shape[1] - cw + 1))
        crop = img[y0:y0 + ch, x0:x0 + cw]
        crop = crop[:, ::-1] if t % 2 else crop
        for h, w in ((64, 64), (17, 40)):
            a = resize(crop, (h, w), order=1, anti_aliasing=True, preserve_range=True)
            b = resize_linear(crop, h, w)
            assert a.dtype == b.dtype and np.array_equal(a, b), (t, h, w)


def test_07_soft_masks_do_not_depend_on_the_threads_order():
    """The soft masks of one view are the same bits every time: at 160 px the label kernel
    runs in many blocks on several threads, and a pixel's rays (its centre ray with the
    first ones, its sub-pixel rays later) are added to its coverage in whatever order the
    threads run; float32 sums of the lash cards' fractional opacities changed in the last
    bit from run to run (fixed-point sums: ``aov.COVERAGE_ONE``)."""
    import torch

    model = load_default_model()
    topo = Topology.from_model(model)
    with torch.no_grad():
        rest = model().vertices[0].numpy().astype(np.float64)
    cam = camera_of({"yaw_deg": 10.0, "pitch_deg": 0.0, "distance_scale": 0.9,
                     "focal_mm": 105.0}, 160, "close")
    head = HeadScene(topo, rest, lights.preset("studio"), cam,
                     RenderSettings(160, 160, 1, pixel_filter="box"))
    atlas = lab.skin_label_atlas()
    first = lab.label_images(head, 3, atlas)[2]
    lash = first[..., lab.LABEL_ID["eyelashes"]]
    assert ((lash > 0) & (lash < 1)).sum() > 20  # fractional lash pixels in view
    for _ in range(6):
        assert np.array_equal(lab.label_images(head, 3, atlas)[2], first)


def test_08_with_hair_the_first_scene_is_built_while_the_groom_grows(tmp_path, monkeypatch):
    """With hair slots the first sample's scene needs no groom, so the serial executor's
    start builds it while the first groom grows on the prefetch thread (the groom below
    waits for it, up to 20 s); the files equal those of a renderer that makes everything
    in order in its own thread."""
    import time

    cfg = load_config(overrides=dict(TINY, hair={"style": "sampled", "lod": 0.05}))
    ahead = SampleRenderer(cfg, tmp_path / "ahead", 5, background_writes=True)
    assert ahead.hair_slots and ahead.spec(0)["hair"] is not None
    seen = []
    grow = SampleRenderer.groom

    def waiting(self, hair):
        t0 = time.perf_counter()
        while not self.scenes and time.perf_counter() - t0 < 20.0:
            time.sleep(0.01)
        seen.append(bool(self.scenes))
        return grow(self, hair)

    monkeypatch.setattr(SampleRenderer, "groom", waiting)
    ahead.prefetch(0)
    ahead.submit(0).result()
    ahead.close()
    monkeypatch.undo()
    assert seen == [True]
    plain = SampleRenderer(cfg, tmp_path / "plain", 5)
    plain.render(0)
    plain.close()
    assert tree(tmp_path / "ahead") == tree(tmp_path / "plain")
