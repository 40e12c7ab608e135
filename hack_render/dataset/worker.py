"""Rendering one sample to its files: geometry, skin, scene, labels, atomic writes.

A :class:`SampleRenderer` lives in one process (the serial loop or one Ray actor). It
loads the model once and keeps one :class:`~hack_render.render.scene.HeadScene` per
lighting preset, built from the same canonical state (the rest mesh, a fixed camera,
flat skin maps) and then changed per sample through ``set_vertices``, ``set_maps``,
``set_camera`` and ``set_light_rotation``: every sample is then rendered from a scene
whose content depends on that sample alone, and the box pixel filter makes the pixels
bit-identical whichever process renders it and whatever it rendered before.

Exposure scales every emitter of the rig by 2**exposure; light transport is linear in
the emitted radiance, so it is applied to the rendered radiance (identical in
expectation, and one compiled scene serves every exposure).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from hack_render.dataset import labels as lab
from hack_render.dataset.sampling import model_kwargs, params_file, sample_spec

SAMPLE_RECORD = "sample.json"


def sample_dir(out: Path, index: int) -> Path:
    return Path(out) / "samples" / f"{index:07d}"


def camera_of(view: dict, width: int, name: str):
    """The OpenCV camera of a sampled view description (square images)."""
    from scenes import cameras as cams

    K = cams.intrinsics(width, width, view["focal_mm"])
    d = cams.framing_distance(K, width, width, cams.DEFAULT_EXTENT) * view["distance_scale"]
    return cams.orbit(width, width, view["focal_mm"], view["yaw_deg"], view["pitch_deg"],
                      name=name, distance=d)


def _write_json(path: Path, data) -> None:
    from hack_render.render.image_io import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True))


def _write_png(path: Path, array: np.ndarray) -> None:
    import imageio.v3 as iio

    from hack_render.render.image_io import atomic_path

    with atomic_path(path) as tmp:
        # zlib level 1: several times faster than the default, files ~10 % larger
        iio.imwrite(tmp, array, extension=".png", compress_level=1)


class SampleRenderer:
    """Renders samples of one dataset config into ``out``; reusable across samples."""

    def __init__(self, cfg: dict, out: str | Path, seed: int):
        from hack_render.geometry import load_default_model
        from hack_render.render.parts import Topology

        self.cfg, self.out, self.seed = cfg, Path(out), int(seed)
        self.model = load_default_model()
        self.topology = Topology.from_model(self.model)
        import torch

        with torch.no_grad():
            self.rest = self.model().vertices[0].numpy().astype(np.float64)
        self.larynx_candidates = lab.larynx_candidates(self.model)
        self.atlas = lab.skin_label_atlas()
        self.scenes: dict = {}
        self._appearance_model = None

    # --- parts ----------------------------------------------------------------------
    def spec(self, index: int) -> dict:
        return sample_spec(self.cfg, self.seed, index, self.model.au_names)

    def skin_maps(self, appearance: dict):
        from hack_render.render.materials import SkinMaps

        h = self.cfg["appearance"]["height"]
        if appearance["source"] == "seed":
            from appearance.generator import generate_subject

            return SkinMaps.from_appearance(generate_subject(appearance["subject"], height=h))
        if appearance["source"] == "alpha":
            import torch

            if self._appearance_model is None:
                from appearance.model import AppearanceModel

                self._appearance_model = AppearanceModel.load()
            a = torch.tensor([appearance["alpha"]], dtype=torch.float32)
            with torch.no_grad():
                return SkinMaps.from_appearance(self._appearance_model.maps(a))
        return self._flat_maps()

    def _flat_maps(self):
        from hack_render.render.materials import SkinMaps

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
        """Build the scene of every configured preset, in config order, before any render.

        Dr.Jit compiles one kernel for every instance of a class that exists in the
        process (the emitters and BSDFs of all scenes), so each scene built or changed
        later would recompile the kernels of the others (~0.5 s each at 256 px). Built
        together up front, with their light transforms already opaque (``set_light_rotation``),
        every process holds the same instances and each preset compiles once.
        """
        for preset in self.cfg["lighting"]["presets"]:
            if preset not in self.scenes:
                self.scenes[preset] = self._build_scene(preset)

    def _build_scene(self, preset: str):
        from hack_render.render.scene import HeadScene, RenderSettings
        from scenes import lights

        r = self.cfg["render"]
        settings = RenderSettings(r["resolution"], r["resolution"], r["spp"], r["max_depth"], 0,
                                  pixel_filter="box")
        cam = camera_of({"yaw_deg": 0.0, "pitch_deg": 0.0, "distance_scale": 1.0,
                         "focal_mm": 85.0}, r["resolution"], "canonical")
        head = HeadScene(self.topology, self.rest, lights.preset(preset, 0.0, 0.0), cam,
                         settings, self._flat_maps(), None, r["variant"])
        head.set_light_rotation(0.0)  # opaque transforms from the start
        return head

    # --- one sample -----------------------------------------------------------------
    def render(self, index: int) -> dict:
        """Render sample ``index`` and write its files; returns its manifest record.

        The folder is emptied first (a partial sample from an interrupted run is redone);
        ``sample.json``, written last, marks the sample complete.
        """
        import torch

        spec = self.spec(index)
        folder = sample_dir(self.out, index)
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        with torch.no_grad():
            out = self.model(**model_kwargs(self.model, spec))
        verts = out.vertices[0].numpy().astype(np.float64)
        larynx_vertex, larynx = lab.larynx_peak(self.model, out, spec["tau"],
                                                self.larynx_candidates)
        head = self.scene(spec["lighting"]["preset"])
        # Back to the canonical (rest) mesh first: the ray-tracing acceleration structure
        # built for a sample depends slightly on the one it replaces, and a ray grazing a
        # shared triangle edge could then hit the other triangle, so a pixel or two of a
        # sample depended on which sample the process rendered before (found by rendering
        # the same samples in two orders). The extra rebuild makes every sample's start
        # state the same.
        head.set_vertices(self.rest)
        # then one params.update() (in set_camera) for all of the sample's changes: each
        # update that touches a shape rebuilds the acceleration structure
        head.set_vertices(verts, update=False)
        head.set_maps(self.skin_maps(spec["appearance"]), update=False)
        head.set_light_rotation(spec["lighting"]["rotation_deg"], update=False)
        _write_json(folder / "params.json", params_file(self.model, spec))
        views = []
        for v, view in enumerate(spec["cameras"]):
            cam = camera_of(view, self.cfg["render"]["resolution"], f"view_{v:02d}")
            views.append(self._render_view(head, cam, spec, v, folder, out, larynx))
        spec = dict(spec, larynx_peak_vertex=larynx_vertex, views=views,
                    variant=head.variant)
        files = sorted(p for p in folder.rglob("*") if p.is_file())
        spec["files"] = {str(p.relative_to(self.out)): p.stat().st_size for p in files}
        _write_json(folder / SAMPLE_RECORD, spec)
        return spec

    def _render_view(self, head, cam, spec, v, folder, out, larynx) -> dict:
        from hack_render.render.image_io import rgb_channels, to_srgb8, write_exr

        r = self.cfg["render"]
        vdir = folder / f"view_{v:02d}"
        head.set_camera(cam)
        img = head.render(seed=spec["render_seed"] + v)
        img[..., :3] *= np.float32(2.0 ** spec["lighting"]["exposure"])
        aov, seg, masks = lab.label_images(head, r["soft_mask_samples"], self.atlas)
        # the matte is geometric coverage: the film's alpha is 1 on every pixel once an
        # environment light is visible behind the subject
        alpha = np.clip(1.0 - masks[..., lab.LABEL_ID["background"]], 0.0, 1.0)
        meta = {"hack_camera": json.dumps(cam.to_dict(), sort_keys=True)}
        ch = rgb_channels(img[..., :3])
        ch["A"] = alpha
        write_exr(vdir / "rgb.exr", ch, meta)
        _write_png(vdir / "rgb.png", to_srgb8(img[..., :3], 0.0, r["tonemap"]))
        _write_png(vdir / "alpha.png", np.round(alpha * 255).astype(np.uint8))
        write_exr(vdir / "depth.exr", {"Z": aov["depth"]}, meta)
        write_exr(vdir / "normal.exr", {c: aov["normal"][..., i] for i, c in enumerate("XYZ")}, meta)
        write_exr(vdir / "uv.exr", {"U": aov["uv"][..., 0], "V": aov["uv"][..., 1]}, meta)
        write_exr(vdir / "albedo.exr", rgb_channels(aov["albedo"]), meta)
        _write_png(vdir / "segmentation.png", seg.astype(np.uint8))
        write_exr(vdir / "masks.exr", {f"mask.{n}": masks[..., i] for i, n in enumerate(lab.LABELS)})
        lm = lab.landmark_record(head, cam, out.landmarks[0].numpy(), out.joints[0].numpy(),
                                 larynx)
        _write_json(vdir / "landmarks.json", lm)
        _write_json(vdir / "camera.json", cam.to_dict())
        return {"name": cam.name, "camera": cam.to_dict(), "sampled": spec["cameras"][v]}
