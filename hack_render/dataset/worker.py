"""Rendering one sample to its files: geometry, skin, scene, labels, atomic writes.

A :class:`SampleRenderer` lives in one process (the serial loop or one Ray actor). It
loads the model once and keeps one :class:`~hack_render.render.scene.HeadScene` per
lighting preset, built from the same canonical state (the rest mesh, a fixed camera,
flat skin maps) and then changed per sample through ``set_vertices``, ``set_maps``,
``set_camera`` and ``set_light_rotation`` (then ``sync_environment``, so that the
environment emitter sees the sample's own bounds): every sample is then rendered from a
scene whose content depends on that sample alone, and the box pixel filter makes the
pixels bit-identical whichever process renders it and whatever it rendered before. With
hair in the config, the scenes hold hair slots and each sample's groom is swapped in
(``HeadScene.set_hair``: the same pixels as a scene built around the groom, tested); a
groom no slot layout takes is rendered in a scene built around it, on the sample's own
vertices (:meth:`SampleRenderer.scene_with_hair`): a function of that sample alone too.

Files are encoded and written by a :class:`FileWriter`, in the caller's thread or, for
the serial executor, on one background thread while the next sample renders; either way
each file is written under a temporary name and renamed, and ``sample.json`` (the
completion mark) only after all of the sample's other files are on disk.

Exposure scales every emitter of the rig by 2**exposure; light transport is linear in
the emitted radiance, so it is applied to the rendered radiance (identical in
expectation, and one compiled scene serves every exposure).
"""

from __future__ import annotations

import json
import shutil
import threading
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from appearance.generator import generate_subject
from appearance.model import AppearanceModel
from appearance.projected import SubjectProjector
from hack_render.dataset import labels as lab
from hack_render.dataset.backgrounds import background_image
from hack_render.dataset.config import render_settings
from hack_render.dataset.sampling import model_kwargs, params_file, pool_size, sample_spec
from hack_render.geometry import load_default_model
from hack_render.hair.groom import Groom, GroomCache
from hack_render.hair.pose import pose_groom
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import HairStyle
from hack_render.io import atomic_path, write_json
from hack_render.io.image import rgb_channels, to_srgb8, write_exr
from hack_render.render.hair_shapes import slot_bound, slots_take
from hack_render.render.materials import SkinMaps
from hack_render.render.parts import Topology, vertex_normals
from hack_render.render.scene import HeadScene, composite
from scenes import cameras as cams
from scenes import lights

SAMPLE_RECORD = "sample.json"


def sample_dir(out: Path, index: int) -> Path:
    return Path(out) / "samples" / f"{index:07d}"


def camera_of(view: dict, width: int, name: str):
    """The OpenCV camera of a sampled view description (square images)."""
    K = cams.intrinsics(width, width, view["focal_mm"])
    d = cams.framing_distance(K, width, width, cams.DEFAULT_EXTENT) * view["distance_scale"]
    return cams.orbit(width, width, view["focal_mm"], view["yaw_deg"], view["pitch_deg"],
                      name=name, distance=d)


def _write_png(path: Path, array: np.ndarray) -> None:

    with atomic_path(path) as tmp:
        # zlib level 1: several times faster than the default, files ~10 % larger
        iio.imwrite(tmp, array, extension=".png", compress_level=1)


class SampleRenderer:
    """Renders samples of one dataset config into ``out``; reusable across samples."""

    #: Samples whose files may still be queued when the next sample starts (memory bound).
    max_pending = 2

    def __init__(self, cfg: dict, out: str | Path, seed: int, background_writes: bool = False):
        self.cfg, self.out, self.seed = cfg, Path(out), int(seed)
        self.model = load_default_model()
        self.topology = Topology.from_model(self.model)
        import torch

        with torch.no_grad():
            self.rest = self.model().vertices[0].numpy().astype(np.float64)
        self.larynx_candidates = lab.larynx_candidates(self.model)
        #: the mean rest mesh grooms are grown on (built at the first groom)
        self._surface: HeadSurface | None = None
        #: grown grooms by their strands' key, for every pooled groom (``hair.pool``): a
        #: later person with the same strands gets them recoloured, not grown again
        self._grooms = GroomCache(pool_size(int(cfg["hair"]["pool"])))
        #: :attr:`scenes` holds one scene built around a groom (one set_hair did not take)
        self._hair_scene = False
        #: the presets' scenes hold hair slots (``HeadScene.set_hair``): hair configured
        self.hair_slots = cfg["hair"]["style"] != "none"
        #: {slot id: segments} of the presets' scenes' hair slots: room for every groom
        #: the sampler draws at the config's level of detail (``hair_shapes.slot_bound``),
        #: the same whatever came before (the pixels depend on the slots)
        self.hair_capacity = slot_bound(cfg["hair"]["lod"]) if self.hair_slots else {}
        self.scenes: dict = {}
        self._appearance_model = None
        self._projector: SubjectProjector | None = None
        self._skin_lock = threading.Lock()  # one projector / model, whichever thread asks
        #: index -> future of its :meth:`inputs`, started by :meth:`prefetch`
        self._prefetched: dict[int, Future] = {}
        self._prefetch_pool: ThreadPoolExecutor | None = None
        # made on the prefetch thread while this one builds the scenes, before the first
        # sample's inputs: the projector (~1 s: the appearance model loaded and pooled) and
        # the skin label atlas (~1 s to rasterise; :attr:`atlas` waits for it)
        app = cfg["appearance"]
        if app["source"] == "seed" and app["maps"] == "projected":
            self._prefetcher().submit(self._subject_projector)
        self._atlas: Future = self._prefetcher().submit(lab.skin_label_atlas)
        #: encodes and writes the files; with ``background_writes`` on one thread of its
        #: own, so that a sample's files are written while the next one renders
        self.writer = FileWriter(background_writes)

    @property
    def atlas(self) -> np.ndarray:
        """(H, 2H) uint8: the skin label atlas (``labels.skin_label_atlas``)."""
        return self._atlas.result()

    def _prefetcher(self) -> ThreadPoolExecutor:
        if self._prefetch_pool is None:
            self._prefetch_pool = ThreadPoolExecutor(1, thread_name_prefix="dataset-prefetch")
        return self._prefetch_pool

    # --- parts ----------------------------------------------------------------------
    def spec(self, index: int) -> dict:
        return sample_spec(self.cfg, self.seed, index, self.model.au_names)

    def skin_maps(self, appearance: dict):
        h = self.cfg["appearance"]["height"]
        if appearance["source"] == "seed" and self.cfg["appearance"]["maps"] == "projected":
            return SkinMaps.from_appearance(self._subject_projector().maps(
                appearance["subject"], h))
        if appearance["source"] == "seed":
            return SkinMaps.from_appearance(generate_subject(appearance["subject"], height=h))
        if appearance["source"] == "alpha":
            import torch

            with self._skin_lock:
                if self._appearance_model is None:
                    self._appearance_model = AppearanceModel.load()
            a = torch.tensor([appearance["alpha"]], dtype=torch.float32)
            with torch.no_grad():
                return SkinMaps.from_appearance(self._appearance_model.maps(a))
        return self._flat_maps()

    def _subject_projector(self) -> SubjectProjector:
        with self._skin_lock:
            if self._projector is None:
                self._projector = SubjectProjector()
        return self._projector

    def _flat_maps(self):
        c = SkinMaps.constant(self.cfg["appearance"]["height"])
        flat = np.zeros(c.diffuse.shape, np.float32)
        flat[..., 2] = 1.0
        return SkinMaps(c.diffuse, c.specular, c.roughness, flat)

    def scene(self, preset: str):
        """The scene of a lighting preset (see :meth:`build_scenes`)."""
        if not self.scenes:
            self.build_scenes()
        if preset not in self.scenes:
            self.scenes[preset] = self._build_scene(preset)
        return self.scenes[preset]

    def build_scenes(self) -> None:
        """Build the scene of every configured preset not built yet, in config order.

        Dr.Jit compiles one kernel for every instance of a class that exists in the
        process (the emitters and BSDFs of all scenes), so each scene built or changed
        later would recompile the kernels of the others (~0.5 s each at 256 px). Built
        together, with their light transforms already opaque (``set_light_rotation``),
        every process holds the same instances and each preset compiles once. The serial
        executor's first sample renders in its own preset's scene alone (the start-up is
        one scene, not four) and the others are built right after it (:meth:`submit`): its
        kernels are traced once more, the pixels are the same (the kernels' instances do
        not change what they compute; tests/test_dataset_speed.py)."""
        for preset in self.cfg["lighting"]["presets"]:
            if preset not in self.scenes:
                self.scenes[preset] = self._build_scene(preset)

    def groom(self, hair: dict | None) -> Groom | None:
        """The strands of a sample's ``hair`` (its spec's ``HairStyle.to_dict()``), grown
        on the model's mean rest mesh, or a pooled groom grown before and recoloured (the
        same arrays); None for no hair. A pure function of the style."""
        if hair is None:
            return None
        with self._skin_lock:
            if self._surface is None:
                self._surface = HeadSurface.from_model(self.model)
        return self._grooms.get(self._surface, HairStyle.from_dict(hair))

    def scene_with_hair(self, preset: str, groom: Groom | None, verts: np.ndarray,
                        posed: dict | None = None):
        """The preset's scene holding ``groom``, for a sample with vertices ``verts``
        (``posed``: the groom's strands posed on them, or None to pose them here).

        With hair configured the presets' scenes hold hair slots, and the groom is swapped
        into its preset's scene (``HeadScene.set_hair``, posed on ``verts``; the
        ``set_vertices`` that follows finds them posed): no scene is loaded and no kernel
        compiled again. A groom that the slots do not take (one without lashes, or one
        larger than the slots: a style outside the sampler's ranges) gets a
        new scene of its preset around it, built on its own vertices, and it is the only
        scene alive (the others are dropped: Dr.Jit traces its kernels over every BSDF and
        shape instance in the process; such a scene compiles its kernels again, seconds a
        sample). A sample without hair gets the bald scenes of :meth:`build_scenes`
        (rebuilt if a groom's scene replaced them). Either way the scene is a function of
        the sample alone."""
        standard = slots_take(groom, self.hair_capacity) if self.hair_slots else groom is None
        if standard:
            if self._hair_scene:
                self.scenes.clear()
                self._hair_scene = False
            if self.hair_slots and not self.scenes:  # the first sample's; the rest after it
                self.scenes[preset] = self._build_scene(preset)
            head = self.scene(preset)
            if groom is not None:
                head.set_hair(groom, vertices=verts, hair_posed=posed, update=False)
            return head
        self.scenes.clear()  # dropped scenes die when the next one is built
        head = self.scenes[preset] = self._build_scene(preset, groom, verts, slots=False)
        self._hair_scene = True
        return head

    def _build_scene(self, preset: str, groom: Groom | None = None,
                     verts: np.ndarray | None = None, slots: bool | None = None):
        """A scene of ``preset`` (with ``groom``, on ``verts``; ``slots``: with hair
        slots, default :attr:`hair_slots`)."""
        r = self.cfg["render"]
        settings = render_settings(self.cfg)
        cam = camera_of({"yaw_deg": 0.0, "pitch_deg": 0.0, "distance_scale": 1.0,
                         "focal_mm": 85.0}, r["resolution"], "canonical")
        # the presets' scenes share their vertex-dependent set-up (parts, corneas, ...)
        like = next(iter(self.scenes.values()), None)
        head = HeadScene(self.topology, self.rest if verts is None else verts,
                         lights.preset(preset, 0.0, 0.0), cam,
                         settings, self._flat_maps(), None, r["variant"], hair=groom,
                         hair_slots=self.hair_capacity if slots is None else False,
                         like=like)
        # opaque transforms from the start; applied by the first sample's update (each
        # update that touches a shape rebuilds the acceleration structure: ~0.1 s a scene)
        head.set_light_rotation(0.0, update=False)
        return head

    # --- one sample -----------------------------------------------------------------
    def render(self, index: int) -> dict:
        """Render sample ``index`` and write its files; returns its manifest record once
        every file, ``sample.json`` last, is on disk (see :meth:`submit`)."""
        return self.submit(index).result()

    def inputs(self, index: int) -> dict:
        """What sample ``index`` needs before its scene, each a pure function of the
        config, seed and index: ``spec``, the geometry forward ``out`` and its vertices
        ``verts`` with their ``normals``, the larynx peak (``larynx_vertex``, ``larynx``),
        the skin ``maps``, the ``background`` image (None: the rig's environment), the
        hair's ``groom`` (None: no hair; grown here, on the prefetch thread, while the
        previous sample renders) with its strands posed on ``verts`` (``hair_posed``: for
        scenes with hair slots; None otherwise) and ``params``, the content of its
        ``params.json``."""
        import torch

        spec = self.spec(index)
        with torch.no_grad():
            out = self.model(**model_kwargs(self.model, spec))
        larynx_vertex, larynx = lab.larynx_peak(self.model, out, spec["tau"],
                                                self.larynx_candidates, spec["beta"] or None)
        res = self.cfg["render"]["resolution"]
        verts = out.vertices[0].numpy().astype(np.float64)
        groom = self.groom(spec.get("hair"))
        return {"index": index, "spec": spec, "out": out,
                "verts": verts, "normals": vertex_normals(verts, self.topology.faces),
                "larynx_vertex": larynx_vertex, "larynx": larynx,
                "maps": self.skin_maps(spec["appearance"]),
                "background": background_image(spec["background"], res, res),
                "groom": groom,
                "hair_posed": pose_groom(groom, verts) if groom is not None and
                self.hair_slots else None,
                "params": params_file(self.model, spec)}

    def prefetch(self, index: int) -> None:
        """Start computing sample ``index``'s :meth:`inputs` on a helper thread, so that
        they are ready when :meth:`submit` gets that index (the serial executor names the
        next sample while the current one renders: the path tracer leaves the CPU idle
        while it traces its kernels and while the acceleration structure is rebuilt).
        The inputs are pure functions of the index: the files are the same either way."""
        pool = self._prefetcher()
        while len(self._prefetched) >= 2:  # never taken (an index skipped): dropped
            self._prefetched.pop(next(iter(self._prefetched)))
        index = int(index)
        if index not in self._prefetched:
            self._prefetched[index] = pool.submit(self.inputs, index)

    def submit(self, index: int, then: int | None = None) -> Future:
        """Render sample ``index`` and queue its file writes; returns a future of its
        manifest record. ``then``: the next sample's index, whose inputs are started
        (:meth:`prefetch`) before this sample's scene and render, but after the first
        bald sample's own scene (at the start they would compete with its build).

        The folder is emptied first (a partial sample from an interrupted run is redone).
        Files are encoded and written by :attr:`writer` in the order they are queued
        (in the background when it has a thread, while this thread renders on), each
        under a temporary name then renamed; ``sample.json``, queued last and written only
        if every other file of the sample was, marks the sample complete. The sample's
        :meth:`inputs` come from :meth:`prefetch` when it was given this index.
        """
        self.writer.wait_below(self.max_pending)
        ahead = self._prefetched.pop(int(index), None)
        # the first sample with its inputs still being made (the serial executor's start):
        # only its own preset's scene is built now, while the inputs are made, and the
        # other presets' after its render (:meth:`build_scenes`), while its files are
        # written: the start-up before the first render is one scene, not one per preset
        rest = not self.scenes and self.hair_slots  # hair slots: the other presets after
        if not self.scenes and ahead is not None and not ahead.done():
            first = self.spec(index)
            # bald, or a groom for the hair slots (swapped in after: the scene needs no
            # groom to be built, so it is built while the groom grows)
            if first.get("hair") is None or self.hair_slots:
                preset = first["lighting"]["preset"]
                self.scenes[preset] = self._build_scene(preset)
                rest = True
        if then is not None:  # made while this sample renders (and a groom's scene builds)
            self.prefetch(then)
        inp = ahead.result() if ahead is not None else self.inputs(index)
        spec, out, larynx = inp["spec"], inp["out"], inp["larynx"]
        folder = sample_dir(self.out, index)
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        head = self.scene_with_hair(spec["lighting"]["preset"], inp["groom"], inp["verts"],
                                    inp["hair_posed"])
        # one params.update() (in set_camera) for all of the sample's changes: each update
        # that touches a shape rebuilds the acceleration structure
        # the normals were made on the prefetch thread; the iris is placed by set_camera
        head.set_vertices(inp["verts"], update=False, normals=inp["normals"],
                          iris=not spec["cameras"], hair_posed=inp["hair_posed"])
        head.set_maps(inp["maps"], update=False)
        head.set_light_rotation(spec["lighting"]["rotation_deg"], update=False)
        writes = [self.writer.submit(write_json, folder / "params.json", inp["params"],
                                     indent=1, sort_keys=True)]
        views = []
        larynx_vertex = inp["larynx_vertex"]
        for v, view in enumerate(spec["cameras"]):
            cam = camera_of(view, self.cfg["render"]["resolution"], f"view_{v:02d}")
            views.append(self._render_view(head, cam, spec, v, folder, out, larynx, writes,
                                           inp["background"]))
        spec = dict(spec, larynx_peak_vertex=larynx_vertex, views=views,
                    variant=head.variant)
        record = self.writer.submit(_write_record, self.out, folder, spec, writes)
        if rest and not self._hair_scene:
            self.build_scenes()
        return record

    def _render_view(self, head, cam, spec, v, folder, out, larynx, writes, backdrop) -> dict:
        r = self.cfg["render"]
        vdir = folder / f"view_{v:02d}"
        vdir.mkdir()
        put = self.writer.submit
        head.set_camera(cam)
        # Mitsuba gives the environment emitter the bounds of the geometry *before* an
        # update (its bounding sphere places the sampled environment points, so shadow-ray
        # directions moved in the last bit): without this a pixel or two of ~1 sample in 8
        # depended on the sample rendered before (found by rendering samples in two orders)
        head.sync_environment()
        # labels first: their files are written while the path tracer runs
        aov, seg, masks = lab.label_images(head, r["soft_mask_samples"], self.atlas)
        meta = {"hack_camera": json.dumps(cam.to_dict(), sort_keys=True)}
        # the image's own sampling, in its headers (the labels are not path traced)
        rgb_meta = dict(meta, hack_sampler=head.settings.mitsuba_sampler,
                        hack_spp=str(head.settings.effective_spp))
        writes += [
            put(write_exr, vdir / "depth.exr", {"Z": aov["depth"]}, meta),
            put(write_exr, vdir / "normal.exr",
                {c: aov["normal"][..., i] for i, c in enumerate("XYZ")}, meta),
            put(write_exr, vdir / "uv.exr", {"U": aov["uv"][..., 0], "V": aov["uv"][..., 1]},
                meta),
            put(write_exr, vdir / "albedo.exr", rgb_channels(aov["albedo"]), meta),
            put(_write_png, vdir / "segmentation.png", seg.astype(np.uint8)),
            put(write_exr, vdir / "masks.exr",
                {f"mask.{n}": masks[..., i] for i, n in enumerate(lab.LABELS)})]
        lm = lab.landmark_record(head, cam, out.landmarks[0].numpy(), out.joints[0].numpy(),
                                 larynx)
        writes += [put(write_json, vdir / "landmarks.json", lm, indent=1, sort_keys=True),
                   put(write_json, vdir / "camera.json", cam.to_dict(), indent=1,
                       sort_keys=True)]
        bare = head.render(seed=spec["render_seed"] + v, backdrop=False, sss=r["sss"])
        mode = r["denoise"]
        img = head.denoise(bare, fallback=mode == "auto") if mode != "off" else bare
        gain = np.float32(2.0 ** spec["lighting"]["exposure"])
        if backdrop is None:  # the rig's environment, exposed like the lights
            backdrop = head.backdrop() * gain
        if mode != "off" and r["keep_noisy"]:
            noisy = composite(bare * np.float32([gain, gain, gain, 1.0]), backdrop)
            writes.append(put(write_exr, vdir / "rgb_noisy.exr", rgb_channels(noisy[..., :3]),
                              rgb_meta))
        img = composite(img * np.float32([gain, gain, gain, 1.0]), backdrop)
        # the matte is the geometric coverage of the label rays (the soft masks); the
        # film's alpha (coverage of the path tracer's own samples) agrees up to noise
        alpha = np.clip(1.0 - masks[..., lab.LABEL_ID["background"]], 0.0, 1.0)
        ch = rgb_channels(img[..., :3])
        ch["A"] = alpha
        writes += [put(write_exr, vdir / "rgb.exr", ch, rgb_meta),
                   put(_write_rgb_png, vdir / "rgb.png", img[..., :3], r["tonemap"]),
                   put(_write_png, vdir / "alpha.png", np.round(alpha * 255).astype(np.uint8))]
        return {"name": cam.name, "camera": cam.to_dict(), "sampled": spec["cameras"][v]}

    def close(self) -> None:
        """Wait for every queued write (errors stay with their samples' futures) and stop
        the writer and prefetch threads."""
        if self._prefetch_pool is not None:
            self._prefetch_pool.shutdown(wait=True)
            self._prefetch_pool = None
        self._prefetched.clear()
        self.writer.close()


def _write_rgb_png(path: Path, linear: np.ndarray, tonemap: str) -> None:
    _write_png(path, to_srgb8(linear, 0.0, tonemap))


def _write_record(out: Path, folder: Path, spec: dict, writes: list) -> dict:
    """Write ``sample.json`` (every file with its size) after the sample's other files;
    raises, writing nothing, if any of them failed. Runs on the writer thread, after
    ``writes`` (queued earlier, so already finished)."""
    for w in writes:
        w.result()
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    spec["files"] = {str(p.relative_to(out)): p.stat().st_size for p in files}
    write_json(folder / SAMPLE_RECORD, spec, indent=1, sort_keys=True)
    return spec


class FileWriter:
    """Runs file writes in the order they are submitted: on one background thread
    (``background=True``), or at once in the caller's thread. Returns futures; a failed
    write's exception is raised by its future."""

    def __init__(self, background: bool = False):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="dataset-writer") \
            if background else None
        self._records: deque[Future] = deque()

    @property
    def background(self) -> bool:
        return self._pool is not None

    def submit(self, fn, *args, **kwargs) -> Future:
        if self._pool is not None:
            fut = self._pool.submit(fn, *args, **kwargs)
        else:
            fut = Future()
            try:
                fut.set_result(fn(*args, **kwargs))
            except Exception as err:  # noqa: BLE001 - kept in the future, as a thread would
                fut.set_exception(err)
        if fn is _write_record:
            self._records.append(fut)
        return fut

    def wait_below(self, n: int) -> None:
        """Block until fewer than ``n`` samples' records are still pending (memory bound)."""
        while self._records and (self._records[0].done() or len(self._records) >= n):
            f = self._records.popleft()
            if not f.done():
                wait([f])

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        self._records.clear()
