"""A head scene built once, then changed through ``mi.traverse`` parameters.

:class:`HeadScene` assembles the render parts (``parts.py``), their materials
(``materials.py``), a light rig and a camera into one Mitsuba scene. Per-frame changes
(vertices, skin maps, camera pose, light rotation) write into the traversed parameters
and call ``params.update()``: the scene is never reloaded, the BVH is refit/rebuilt by
Mitsuba, and since resolution, spp and the scene's structure stay fixed, Dr.Jit reuses
the kernels it compiled for the first frame.

Its settings (size, samples and sampler, integrator) are ``render/settings.py``'s, whose
names this module re-exports; the skin's passes of ``render(sss=True)`` are
``render/sss.py``'s (:func:`hack_render.render.sss.render_scattered`). What a built scene
gives (images, the denoiser, the backdrop, G-buffers, labels) is
``render/scene_images.py``'s (:class:`~hack_render.render.scene_images.SceneImages`), and
swapping grooms in and posing them ``render/scene_hair.py``'s
(:class:`~hack_render.render.scene_hair.SceneHair`); :class:`HeadScene` extends both.
"""

from __future__ import annotations

import numpy as np

from hack_render.errors import HackError
from hack_render.io.image import read_hdr_image
from hack_render.render import emitters, materials
from hack_render.render.cornea import CorneaRig
from hack_render.render.emitters import (
    area_light_transform,
    camera_to_world,
    check_centred,
    rotation_y,
)
from hack_render.render.engine import ensure_variant, is_jit, release_parked, release_when_safe
from hack_render.render.hair_shapes import (
    HAIR_RR,
    HAIR_RR_DEPTH,
    aligned_float,
    hair_shapes,
    load_shapes,
    shape_control_points,
    slot_capacity,
    slots_take,
    write_slots,
)
from hack_render.render.hair_shapes import PREFIX as HAIR_PREFIX
from hack_render.render.parts import (
    PART_SPECS,
    REGIONS,
    Topology,
    lash_cards,
    split_parts,
    vertex_normals,
)
from hack_render.render.scene_hair import SceneHair
from hack_render.render.scene_images import SceneImages, as_points, composite
from hack_render.render.settings import (
    AUTO_ORTHOGONAL_MIN,
    DEFAULT_INTEGRATOR,
    DEFAULT_SAMPLER,
    INTEGRATORS,
    MAX_PIXELS,
    MAX_SIDE,
    MAX_SPP,
    SAMPLERS,
    SAMPLES_PER_PASS,
    RenderSettings,
    auto_sampler,
    sampler_spp,
    validate_size,
)
from scenes.cameras import Camera
from scenes.lights import LightRig

#: the settings' names are re-exported (``scene.RenderSettings`` and the rest)
__all__ = ["AUTO_ORTHOGONAL_MIN", "DEFAULT_INTEGRATOR", "DEFAULT_SAMPLER", "INTEGRATORS",
           "MAX_PIXELS", "MAX_SIDE", "MAX_SPP", "SAMPLERS", "SAMPLES_PER_PASS", "HeadScene",
           "RenderSettings", "auto_sampler", "composite", "sampler_spp", "validate_size"]


class HeadScene(SceneImages, SceneHair):
    """The head, its materials, lights and camera as one Mitsuba scene.

    Args:
        topology: faces, UVs and materials of the model (``Topology.from_model``).
        vertices: (N, 3) rest/initial vertices, metres (numpy or torch).
        maps: skin maps; constant stand-ins when None.
        lights: a light rig (``scenes.lights.preset``).
        camera: the camera (``scenes.cameras``); later cameras must keep its size.
        settings: resolution, spp, depth, seed (resolution must match the camera).
        iris_rgb: linear RGB of the iris; None: ``maps.iris_rgb``, else the default.
        variant: Mitsuba variant; chosen automatically when None.
        bust_cap: close the cut of the chest and shoulders (``parts.bust_cap``), so that
            it never shows its black inside.
        lash_strands: give the lash cards the procedural strand opacity texture
            (``materials.lash_opacity_map``); False: the uniform ``EYELASH_OPACITY`` of
            earlier versions (a grey band around the eyes in close-ups).
        cornea: show the iris as the camera sees it through the cornea (``cornea.py``:
            the iris vertices are moved for each camera, by :meth:`set_camera` and
            :meth:`set_vertices`); False keeps the plain iris (earlier versions). The
            fitter's ``bridge.DiffRenderer`` writes all positions itself: a plain iris.
        hair: a groom (:class:`hack_render.hair.groom.Groom`, from ``grow`` /
            ``grow_cached``) rendered as curves with Mitsuba's ``hair`` BSDF
            (:mod:`hack_render.render.hair_shapes`: one shape per strand group and melanin
            bucket), posed on ``vertices`` and re-posed by :meth:`set_vertices`; its hits
            are the segmentation's ``hair`` region. A groom with a ``lashes`` group replaces
            the lash cards (the ``eyelashes`` part is not rendered). None: bald, the scene
            of earlier versions.
        hair_slots: hold a curve shape for every shape a groom can have
            (``hair_shapes.slot_ids``), each of a fixed number of segments (a mapping
            {slot id: segments}; True: what ``hair`` fills, ``hair_shapes.slot_capacity``):
            the groom's strands, then a hidden padding strand (``slot_content``), so that
            :meth:`set_hair` swaps in any groom with lashes that fits, without a new scene
            and without compiling the kernels again (the dataset's scenes). The lash cards
            are not rendered (the strand lashes replace them), even while ``hair`` is None.
        like: another scene on the same topology, vertices and ``bust_cap``, whose
            vertex-dependent set-up (the parts, eye axes, corneas, vertex normals and the
            lash opacity map: ~0.2 s) this one reuses, e.g. the dataset's scene of each
            lighting preset; the scene is the same as one built without it.
    """

    def __init__(self, topology: Topology, vertices, lights: LightRig, camera: Camera,
                 settings: RenderSettings | None = None, maps=None,
                 iris_rgb=None, variant: str | None = None, *, bust_cap: bool = True,
                 lash_strands: bool = True, cornea: bool = True, hair=None,
                 hair_slots: bool | dict = False, like: HeadScene | None = None):
        settings = settings or RenderSettings(camera.width, camera.height)
        if (camera.width, camera.height) != (settings.width, settings.height):
            raise HackError(f"camera {camera.name!r}: expected size {settings.width}x"
                            f"{settings.height} (the settings), found {camera.width}x"
                            f"{camera.height}.")
        self.variant = ensure_variant(variant)
        release_parked()  # dropped scenes die here, on the thread that renders
        import mitsuba as mi

        self.settings, self.camera, self.lights = settings, camera, lights
        self.topology = topology
        v = as_points(vertices).reshape(-1, 3)
        if v.shape[0] != topology.num_vertices:
            raise HackError(f"vertices: expected ({topology.num_vertices}, 3) for this "
                            f"topology, found {v.shape}.")
        shared = like._shared if like is not None and like.topology is topology and \
            like._shared[0] == bust_cap and np.array_equal(like._shared[1], v) else None
        if shared is None:
            parts, axes = split_parts(topology, v, cap=bust_cap)
            #: (bust_cap, vertices, parts, eye axes, {cornea, normals, lash map}): reused
            #: by a scene built ``like`` this one
            shared = (bust_cap, v.copy(), parts, axes, {})
        self._shared = shared
        self.parts, self.eye_axes, memo = list(shared[2]), shared[3], shared[4]
        #: the groom rendered (None: bald) and its shapes (``hair_shapes.HairShape``)
        self.hair = hair
        self.hair_shapes = hair_shapes(hair) if hair is not None else []
        #: {slot id: segments} of the hair slots (``hair_slots``; empty: none)
        self.hair_slots = dict(hair_slots) if isinstance(hair_slots, dict) else \
            slot_capacity(hair) if hair_slots else {}
        if self.hair_slots and hair is not None and not slots_take(hair, self.hair_slots):
            raise HackError("hair_slots: the groom has no lashes (a scene with hair slots "
                            "renders the lashes as strands) or does not fit the slots; build "
                            "the scene without slots or with larger ones.")
        if (hair is not None and hair.group("lashes") is not None) or hair_slots:
            # the strands replace ICT's lash cards
            self.parts = [p for p in self.parts if p.name != "eyelashes"]
        self._hair_posed_for: tuple | None = None
        self._hair_written = None  # the posed strands last written into the scene
        self._vertices = v
        iris = [p for p in self.parts if p.name == "iris"]
        #: the corneas refracting the iris for the camera (None: a plain iris)
        if "cornea" not in memo and cornea and iris:
            memo["cornea"] = CorneaRig.from_topology(topology, v, self.eye_axes,
                                                     iris[0].gather)
        self.cornea = memo.get("cornea") if cornea and iris else None
        maps = maps if maps is not None else materials.SkinMaps.constant()
        env = self._env_image(lights)
        jit = is_jit(self.variant)

        skin = mi.load_dict(materials.skin_bsdf(maps, jit))
        # the hack_skin plugin (JIT variants): render(sss=True) weights its lobes
        self.skin_bsdf = skin if hasattr(skin, "lobe_weights") else None
        #: (BSDF, opacity) of the see-through cards (the lashes): the opacity is a loaded
        #: texture plugin (its ``eval_1`` at a hit) or a number
        self.see_through_cards: list[tuple[object, object]] = []
        self.lash_opacity: np.ndarray | None = None
        fixed = materials.fixed_bsdfs(maps.sclera_rgb, maps.eye_gloss)
        normals = memo.get("normals")
        if normals is None:
            normals = memo["normals"] = vertex_normals(v, topology.faces)
        # hide_emitters: camera rays pass through the area lights' rectangles and do not
        # see the environment, so no light is ever in frame and the film's alpha is the
        # subject's coverage; the environment is put back behind the subject as a
        # backdrop (:meth:`backdrop`), lights and shading unchanged (only depth-0 emission
        # is hidden)
        #: the Mitsuba integrator rendering this scene (``settings.integrator``, but
        #: ``volpath`` for ``hack_path`` in a non-JIT variant)
        self.integrator_name = settings.integrator if jit or \
            settings.integrator != "hack_path" else "volpath"
        #: the integrator's properties besides its type, max_depth and hide_emitters
        #: (a hair scene's: Russian roulette from ``HAIR_RR_DEPTH`` and, with hack_path,
        #: from the first event on hair (``HAIR_RR``), and no null surfaces
        #: when strand lashes replace the cards: opaque shadow rays); the skin split's
        #: integrator (``sss.split_integrator``) takes them too
        self.integrator_extra: dict = {}
        if hair is not None or hair_slots:
            self.integrator_extra["rr_depth"] = HAIR_RR_DEPTH
            if self.integrator_name == "hack_path":
                self.integrator_extra["hair_rr"] = HAIR_RR
        if self.integrator_name == "hack_path" and \
                not any(p.name == "eyelashes" for p in self.parts):
            self.integrator_extra["null_surfaces"] = False
        scene: dict = {"type": "scene",
                       "integrator": {"type": self.integrator_name,
                                      "max_depth": settings.max_depth,
                                      "hide_emitters": True, **self.integrator_extra},
                       "sensor": emitters.sensor_dict(camera, settings.passes[1],
                                                      pixel_filter=settings.pixel_filter,
                                                      sampler=settings.mitsuba_sampler)}
        # per-vertex colours given for parts (the fit's bake); an explicit iris_rgb wins
        part_rgb = {k: np.asarray(c) for k, c in (maps.part_rgb or {}).items()
                    if not (k == "iris" and iris_rgb is not None)}
        for part in self.parts:
            if part.name.startswith("skin"):
                bsdf = skin
            elif part.name == "iris":
                bsdf = mi.load_dict(materials.iris_bsdf(maps.eye_gloss))
            elif part.name == "eyelashes":
                opacity = self._lash_opacity(part, v, memo) if lash_strands \
                    else materials.EYELASH_OPACITY
                bsdf = mi.load_dict(materials.eyelash_bsdf(opacity, maps.eye_gloss))
                # see-through cards: the label and AOV passes (and render(sss=True)) look
                # up the same opacity at their hits
                self.see_through_cards.append((bsdf, opacity))
            elif part.name in part_rgb:
                bsdf = mi.load_dict(materials.vertex_colour_bsdf(fixed[part.name]))
            else:
                bsdf = mi.load_dict(fixed[part.name])
            mesh = self._mesh(part, self._positions(part, v, camera), normals[part.gather],
                              bsdf)
            colours = part_rgb.get(part.name)
            if colours is not None and colours.shape != (len(part.gather), 3):
                raise HackError(f"part colours {part.name!r}: expected one per vertex of the "
                                f"part, ({len(part.gather)}, 3), found {colours.shape} "
                                "(another model's?).")
            if part.name == "iris" and colours is None:
                colours = materials.iris_vertex_colors(v[part.gather], self.eye_axes,
                                                       iris_rgb or maps.iris_rgb
                                                       or materials.DEFAULT_IRIS_RGB,
                                                       maps.sclera_rgb)
            if colours is not None:
                mesh.add_attribute("vertex_color", 3,
                                   mi.Float(np.asarray(colours, np.float32).ravel()))
            scene[part.name] = mesh
        posed = self._pose_hair(v) if hair is not None else None
        if self.hair_shapes or self.hair_slots:
            scene.update(load_shapes(hair, posed, self.hair_shapes, self.hair_slots or None,
                                     v.mean(0)))
            self._hair_written = posed
        scene.update(emitters.emitter_dicts(lights, env))
        # optimize=False: Mitsuba's optimisation pass (merging equivalent objects) lists
        # shapes and emitters in an order that varies from load to load (two area lights
        # swapped in ~1 load in 7 under CPU load), and the order decides which light a
        # random number selects; without it the scene keeps this dict's order, so a render
        # is a function of its inputs alone. parallel=False: nothing depends on threads.
        self.scene = mi.load_dict(scene, parallel=False, optimize=False)
        self.params = mi.traverse(self.scene)
        # freed by a later scene or render, never by whatever thread collects this one
        release_when_safe(self, self.scene, self.params)
        self._backdrop: np.ndarray | None = None
        self._skin_key = self._find_skin_key()
        self._shape_regions = self._shape_region_table()
        if self.hair_slots:  # the state set_hair leaves (opaque melanin: no recompiles)
            write_slots(self.params, hair, posed, self.hair_shapes, self.hair_slots,
                        v.mean(0), structure=True)
            self.params.update()

    # --- construction helpers ------------------------------------------------------
    @staticmethod
    def _env_image(rig: LightRig) -> np.ndarray | None:
        if rig.env_map is not None:
            return np.asarray(rig.env_map, dtype=np.float32)
        if rig.env_file is not None:
            return read_hdr_image(rig.env_file)
        return None

    def _lash_opacity(self, part, v: np.ndarray, memo: dict):
        """The lash cards' opacity: a ``bitmap`` texture plugin of the procedural strand
        map (``materials.lash_opacity_map``, kept in :attr:`lash_opacity`) over the cards
        found in the part's UVs (``parts.lash_cards``), or ``EYELASH_OPACITY`` where the
        UVs hold no cards (degenerate UVs): strands need a root-to-tip direction."""
        import mitsuba as mi

        if "lash_map" not in memo:  # None: no cards
            cards = lash_cards(part, v, self.eye_axes)
            memo["lash_map"] = materials.lash_opacity_map(cards) if len(cards) else None
        if memo["lash_map"] is None:
            return materials.EYELASH_OPACITY
        self.lash_opacity = memo["lash_map"]
        return mi.load_dict(materials.bitmap(self.lash_opacity[..., None]))

    def _positions(self, part, v: np.ndarray, camera: Camera) -> np.ndarray:
        """(n, 3) positions of ``part``'s vertices in the posed mesh ``v`` (N, 3): the
        model's, but for the iris seen by ``camera`` through the cornea (``cornea.py``).
        The iris keeps its true normals, so it is shaded as before where it appears."""
        if part.name == "iris" and self.cornea is not None:
            return self.cornea.iris_positions(v, camera.center)
        return part.positions(v)

    @staticmethod
    def _mesh(part, positions, normals, bsdf):
        """A Mitsuba mesh of ``part`` at ``positions`` (n, 3) with ``normals`` (n, 3)."""
        import mitsuba as mi

        mesh = mi.Mesh(part.name, part.num_vertices, len(part.faces),
                       has_vertex_normals=not part.flat, has_vertex_texcoords=True)
        p = mi.traverse(mesh)
        p["vertex_positions"] = mi.Float(positions.ravel().astype(np.float32))
        if not part.flat:
            p["vertex_normals"] = mi.Float(normals.ravel().astype(np.float32))
        p["vertex_texcoords"] = mi.Float(part.texcoords.ravel().astype(np.float32))
        p["faces"] = mi.UInt32(part.faces.ravel().astype(np.uint32))
        p.update()
        mesh.set_bsdf(bsdf)
        mesh.set_id(part.name)
        return mesh

    def _find_skin_key(self) -> str | None:
        for key in self.params.keys():  # noqa: SIM118 (SceneParameters: keys() lists them)
            if key.endswith((".albedo.data", ".base_color.data")):
                return key.rsplit(".", 2)[0]
        return None

    def _shape_region_table(self) -> dict[int, tuple[int, float, float]]:
        """Shape registry id -> (region, u offset, u scale) for the AOV pass."""
        import drjit as dr
        import mitsuba as mi

        by_name = {p.name: p for p in self.parts}
        table = {}
        for shape in self.scene.shapes():
            sid = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])
            part = by_name.get(shape.id())
            if part is not None:
                _, _, u_off, u_scale = PART_SPECS[part.name]
                table[sid] = (part.region, u_off, u_scale)
            elif shape.id().startswith(HAIR_PREFIX):  # curves: no model UV (u = curve's)
                table[sid] = (REGIONS.index("hair"), 0.0, 1.0)
        return table

    # --- per-frame updates ---------------------------------------------------------
    def set_vertices(self, vertices, *, update: bool = True, hair_posed=None,
                     normals=None, iris: bool = True) -> None:
        """New vertex positions (N, 3) metres, same topology; normals are recomputed (or
        given: ``normals``, ``parts.vertex_normals`` of the same vertices, e.g. made on
        another thread), and the hair (if any) is posed on them (or given: ``hair_posed``,
        :meth:`pose_hair` of the same vertices). ``iris=False`` leaves the iris seen
        through the cornea to the :meth:`set_camera` that must follow (it places the iris
        again, for its camera: ~0.04 s saved).

        ``update=False`` defers ``params.update()`` (see :meth:`update`)."""
        import mitsuba as mi

        v = as_points(vertices).reshape(-1, 3)
        if v.shape[0] != self.topology.num_vertices or not np.all(np.isfinite(v)):
            raise HackError(f"vertices: expected finite ({self.topology.num_vertices}, 3), "
                            f"found {v.shape} (finite: {bool(np.all(np.isfinite(v)))}).")
        n = vertex_normals(v, self.topology.faces) if normals is None else normals
        self._vertices = v
        for part in self.parts:
            if iris or part.name != "iris" or self.cornea is None:
                self.params[f"{part.name}.vertex_positions"] = mi.Float(
                    self._positions(part, v, self.camera).ravel().astype(np.float32))
            if not part.flat:
                self.params[f"{part.name}.vertex_normals"] = mi.Float(
                    n[part.gather].ravel().astype(np.float32))
        if self.hair is not None:
            posed = self._pose_hair(v, hair_posed)
            if posed is not self._hair_written:
                if self.hair_slots:
                    write_slots(self.params, self.hair, posed, self.hair_shapes,
                                self.hair_slots, v.mean(0), structure=False)
                else:
                    for sh in self.hair_shapes:
                        self.params[f"{sh.id}.control_points"] = aligned_float(
                            shape_control_points(self.hair, posed, sh))
                self._hair_written = posed
        if update:
            self.params.update()

    def set_maps(self, maps, *, update: bool = True) -> None:
        """New skin maps (same resolution as the first ones keeps kernels cached)."""
        import mitsuba as mi

        if self._skin_key is None:
            return
        k = self._skin_key
        jit = is_jit(self.variant)
        self.params[f"{k}.{'albedo' if jit else 'base_color'}.data"] = mi.TensorXf(maps.diffuse)
        self.params[f"{k}.roughness.data"] = mi.TensorXf(maps.roughness)
        if jit:
            self.params[f"{k}.specular.data"] = mi.TensorXf(maps.specular)
            if maps.normal is not None and f"{k}.normalmap.data" in self.params:
                self.params[f"{k}.normalmap.data"] = mi.TensorXf(maps.normal)
        if update:
            self.params.update()

    def set_part_colours(self, part_rgb: dict, *, update: bool = True) -> None:
        """New per-vertex colours ({part: (n, 3)}) of parts the scene was built with
        colours for (``SkinMaps.part_rgb``), without a new scene."""
        import mitsuba as mi

        for name, colours in part_rgb.items():
            key = f"{name}.vertex_color"
            if key not in self.params:
                raise HackError(f"part colours {name!r}: the scene was built without them; "
                                "expected a part with per-vertex colours.")
            flat = np.asarray(colours, np.float32).ravel()
            n = len(self.params[key])
            if flat.size != n:
                raise HackError(f"part colours {name!r}: expected {n // 3} colours, found "
                                f"{flat.size // 3}.")
            self.params[key] = mi.Float(flat)
        if update:
            self.params.update()

    def set_eyes(self, iris_rgb=None, sclera_rgb=None, eye_gloss=None, *, update=True):
        """Eye colours and gloss (``materials.set_eye_parameters``), without a new scene."""
        iris = [p.gather for p in self.parts if p.name == "iris"]
        materials.set_eye_parameters(self.params, self._vertices[iris[0]] if iris else None,
                                     self.eye_axes, iris_rgb, sclera_rgb, eye_gloss)
        if update:
            self.params.update()

    def set_camera(self, camera: Camera, *, update: bool = True) -> None:
        """Move the camera (and change its focal length); the image size must stay."""
        import mitsuba as mi

        if (camera.width, camera.height) != (self.settings.width, self.settings.height):
            raise HackError(f"camera {camera.name!r}: expected size {self.settings.width}x"
                            f"{self.settings.height}, found {camera.width}x{camera.height}. "
                            "Build a new HeadScene for another resolution.")
        check_centred(camera)
        self.params["sensor.to_world"] = mi.Transform4f(camera_to_world(camera).tolist())
        self.params["sensor.x_fov"] = camera.fov_x_deg
        if self.cornea is not None:  # the iris as the new camera sees it through the cornea
            self.params["iris.vertex_positions"] = mi.Float(
                self.cornea.iris_positions(self._vertices, camera.center).ravel()
                .astype(np.float32))
        self._backdrop = None
        if update:
            self.params.update()
        self.camera = camera

    def set_light_rotation(self, degrees: float, *, update: bool = True) -> None:
        """Rotate the whole rig (environment and area lights) about +Y."""
        import drjit as dr
        import mitsuba as mi

        def opaque(m: np.ndarray):
            # a transform built from Python numbers is a set of literals that Dr.Jit bakes
            # into the kernel: every new angle recompiled the whole path tracer (~0.5 s)
            t = mi.Transform4f(m.tolist())
            dr.make_opaque(t)
            return t

        if "environment.to_world" in self.params:
            self.params["environment.to_world"] = opaque(rotation_y(degrees))
        for i, light in enumerate(self.lights.area):
            key = f"light_{i}.to_world"
            if key in self.params:
                self.params[key] = opaque(area_light_transform(light, degrees))
        self._backdrop = None
        if update:
            self.params.update()

    def update(self) -> None:
        """Apply changes made with ``update=False``. Every update that touches a shape
        rebuilds the ray-tracing acceleration structure (~40 ms for the head at 256 px on
        two cores), so a caller changing vertices, lights and camera together may defer
        all but the last."""
        self.params.update()

    def sync_environment(self) -> None:
        """Give the environment emitter the current scene bounds (cheap: no rebuild).

        Mitsuba's ``Scene.parameters_changed`` hands the environment emitter the scene's
        bounding box *before* recomputing it for moved shapes, so after an update that
        moved the mesh the environment's bounding sphere (which places its sampled
        points, hence the shadow rays' directions to the last bit) is the previous
        geometry's. A second call, with no shape left dirty, only refreshes it: the
        render then depends on the current geometry alone, not on what came before."""
        self.scene.parameters_changed()
