"""A head scene built once, then changed through ``mi.traverse`` parameters.

:class:`HeadScene` assembles the render parts (``parts.py``), their materials
(``materials.py``), a light rig and a camera into one Mitsuba scene. Per-frame changes
(vertices, skin maps, camera pose, light rotation) write into the traversed parameters
and call ``params.update()``: the scene is never reloaded, the BVH is refit/rebuilt by
Mitsuba, and since resolution, spp and the scene's structure stay fixed, Dr.Jit reuses
the kernels it compiled for the first frame.

Its settings (size, samples and sampler, integrator) are ``render/settings.py``'s, whose
names this module re-exports; the skin's passes of ``render(sss=True)`` are
``render/sss.py``'s (:func:`hack_render.render.sss.render_scattered`).
"""

from __future__ import annotations

import warnings

import numpy as np
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.hair.pose import pose_groom
from hack_render.io.image import read_hdr_image
from hack_render.render import denoise as dn
from hack_render.render import emitters, materials
from hack_render.render.aov import (
    environment_backdrop,
    gbuffer,
    label_pass,
    point_visibility,
    region_hits,
)
from hack_render.render.cornea import CorneaRig
from hack_render.render.emitters import (
    area_light_transform,
    camera_to_world,
    check_centred,
    rotation_y,
)
from hack_render.render.engine import ensure_variant, is_jit, release_parked, release_when_safe
from hack_render.render.footprint import denoise_features
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
from hack_render.render.sss import render_scattered
from scenes.cameras import Camera
from scenes.lights import LightRig

#: the settings' names are re-exported (``scene.RenderSettings`` and the rest)
__all__ = ["AUTO_ORTHOGONAL_MIN", "DEFAULT_INTEGRATOR", "DEFAULT_SAMPLER", "INTEGRATORS",
           "MAX_PIXELS", "MAX_SIDE", "MAX_SPP", "SAMPLERS", "SAMPLES_PER_PASS", "HeadScene",
           "RenderSettings", "auto_sampler", "composite", "sampler_spp", "validate_size"]


def composite(image: np.ndarray, backdrop: np.ndarray | None) -> np.ndarray:
    """Premultiplied linear RGBA (H, W, 4) over a linear RGB backdrop (H, W, 3) or None:
    RGB + (1 - alpha) backdrop; alpha is kept (the subject's coverage)."""
    if backdrop is None:
        return image
    out = image.copy()
    out[..., :3] += (1.0 - image[..., 3:4]) * backdrop
    return out


def _np(x) -> np.ndarray:
    x = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
    return x.astype(np.float64)


class HeadScene:
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
        v = _np(vertices).reshape(-1, 3)
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
                bsdf = mi.load_dict(materials.eyelash_bsdf(opacity))
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
        return v[part.gather]

    @staticmethod
    def _mesh(part, positions, normals, bsdf):
        """A Mitsuba mesh of ``part`` at ``positions`` (n, 3) with ``normals`` (n, 3)."""
        import mitsuba as mi

        mesh = mi.Mesh(part.name, len(part.gather), len(part.faces),
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

    def pose_hair(self, vertices) -> dict[str, np.ndarray] | None:
        """The groom's strands on ``vertices`` (N, 3): {group: (S, K, 3)} control points
        (:func:`hack_render.hair.pose.pose_groom`, with collisions), None when bald. Pure
        NumPy on the groom alone: a caller may pose the next frame on another thread and
        hand the result to :meth:`set_vertices` (``hair_posed``)."""
        if self.hair is None:
            return None
        return pose_groom(self.hair, _np(vertices).reshape(-1, 3))

    def _pose_hair(self, v: np.ndarray, posed=None) -> dict[str, np.ndarray]:
        """:meth:`pose_hair` of ``v`` (or ``posed``, already computed for ``v``); posing
        with collisions costs 0.5-5 s for a full head of hair, so the last one is
        remembered."""
        if self._hair_posed_for is not None and np.array_equal(self._hair_posed_for[0], v):
            return self._hair_posed_for[1]
        posed = posed if posed is not None else pose_groom(self.hair, v)
        self._hair_posed_for = (v.copy(), posed)
        return posed

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

        v = _np(vertices).reshape(-1, 3)
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

    def takes_hair(self, groom) -> bool:
        """Whether :meth:`set_hair` takes ``groom`` into this scene: it has hair slots, the
        groom has lashes (a slotted scene has no lash cards) and fits the slots."""
        return bool(self.hair_slots) and slots_take(groom, self.hair_slots)

    def set_hair(self, groom, *, vertices=None, hair_posed=None, update: bool = True) -> None:
        """Render ``groom`` instead of the present one, in place: a scene built with
        ``hair_slots`` (:meth:`takes_hair`) renders what a new ``HeadScene(...,
        hair=groom, hair_slots=<the same slots>)`` would, without loading a scene or compiling its
        kernels again. The strands are posed on ``vertices`` (default: the mesh's
        present vertices; given: the ones a :meth:`set_vertices` that follows moves the
        mesh to, without posing them again) or given posed (``hair_posed``,
        :meth:`pose_hair` of those vertices with this groom). ``update=False`` defers
        ``params.update()``."""
        if not self.takes_hair(groom):
            raise HackError("set_hair: " + (
                "this scene has no hair slots; build it with HeadScene(..., hair_slots=True)"
                if not self.hair_slots else "expected a groom with lashes (a scene with hair "
                "slots renders the lashes as strands) that fits the slots "
                "(hair_shapes.needed_segments); build a HeadScene with this groom"))
        v = self._vertices if vertices is None else _np(vertices).reshape(-1, 3)
        self.hair, self.hair_shapes = groom, hair_shapes(groom)
        self._hair_posed_for = None
        posed = self._pose_hair(v, hair_posed)
        write_slots(self.params, groom, posed, self.hair_shapes, self.hair_slots, v.mean(0),
                    structure=True)
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

    # --- rendering -------------------------------------------------------------------
    def render(self, seed: int | None = None, progress: bool = False,
               backdrop=True, denoise: bool = False, sss: bool = False) -> np.ndarray:
        """Render the image: (H, W, 4) float32 linear Rec.709 RGB + alpha (coverage).

        Samples are split into equal passes of at most ``SAMPLES_PER_PASS`` samples with
        seeds derived from ``seed`` (default: the settings' seed), then averaged.

        Camera rays never see an emitter (the path integrator's ``hide_emitters``): the
        film holds the subject alone, RGB premultiplied by the alpha. ``backdrop`` says
        what fills the rest: True, the rig's environment as seen along each pixel's
        centre ray (:meth:`backdrop`); False, nothing (premultiplied RGBA, for
        compositing); or an (H, W, 3) linear image composited behind the subject.
        ``denoise``: run Intel Open Image Denoise on the subject before compositing
        (:meth:`denoise`; raises ``denoise.DenoiserUnavailable`` without pyoidn).
        ``sss``: subsurface scattering in the skin (:mod:`hack_render.render.sss`: the
        skin's diffuse light rendered apart, in the same pass with ``hack_path``, in a
        second with the other integrators, then diffused by the skin profile); JIT
        variants only (the scalar variant's stand-in skin material renders without it,
        with a warning).
        """
        release_parked()
        base = self.settings.seed if seed is None else int(seed)
        if sss and self.skin_bsdf is None:
            warnings.warn("sss: subsurface scattering needs the hack_skin material of a JIT "
                          "variant (llvm_ad_rgb or cuda_ad_rgb); rendering without it.",
                          stacklevel=2)
            sss = False
        if sss:
            img = render_scattered(self, base, progress)
        else:
            img = self.render_passes(base, progress)
        if denoise:
            img = self.denoise(img)
        return composite(img, self._backdrop_of(backdrop))

    def render_passes(self, base: int, progress: bool, desc: str = "render passes",
                       spp: int | None = None, integrator=None):
        """The premultiplied film averaged over the settings' passes (see :meth:`render`);
        ``spp``: samples per pixel of each pass instead of the settings' (rounded as the
        sampler takes them); ``integrator``: a Mitsuba integrator instead of the scene's
        (its AOVs follow the RGBA channels)."""
        import mitsuba as mi

        n, _ = self.settings.passes
        kw = {} if spp is None else {"spp": sampler_spp(self.settings.mitsuba_sampler,
                                                        max(1, int(spp)))}
        if integrator is not None:
            kw["integrator"] = integrator
        acc = None
        steps = range(n)
        if progress and n > 1:
            steps = tqdm(steps, desc=desc, unit="pass")
        for i in steps:
            img = np.asarray(mi.render(self.scene, seed=(base * 7919 + i) % (2 ** 31), **kw))
            acc = img if acc is None else acc + img
        return (acc / n).astype(np.float32)

    def denoise(self, image: np.ndarray, fallback: bool = False, k: int = 4) -> np.ndarray:
        """A premultiplied render (H, W, 4) of this scene's current state (camera, mesh),
        denoised by OIDN with albedo and normal from :func:`footprint.denoise_features`
        (through the lash cards, as the film sees them); alpha kept. ``fallback``: a missing or failing denoiser returns the image unchanged
        with a warning instead of raising (see ``hack_render.render.denoise``)."""
        albedo, normal = denoise_features(self, k, self.see_through_cards)
        out = image.copy()
        den = dn.denoise(image[..., :3], albedo, normal, fallback=fallback)
        # premultiplied: no coverage, no colour (OIDN leaves ~1e-6 residues there)
        out[..., :3] = np.where(image[..., 3:4] > 0, den, 0.0)
        return out

    def composite(self, image: np.ndarray, backdrop=True) -> np.ndarray:
        """A premultiplied render (``render(backdrop=False)``) over ``backdrop`` (see
        :meth:`render`)."""
        return composite(image, self._backdrop_of(backdrop))

    def _backdrop_of(self, backdrop) -> np.ndarray | None:
        if backdrop is True:
            return self.backdrop()
        if backdrop is False or backdrop is None:
            return None
        bg = np.asarray(backdrop, dtype=np.float32)
        shape = (self.settings.height, self.settings.width, 3)
        if bg.shape != shape or not np.all(np.isfinite(bg)):
            raise HackError(f"backdrop: expected a finite linear RGB image of shape {shape}, "
                            f"found {bg.shape}.")
        return bg

    def backdrop(self) -> np.ndarray:
        """(H, W, 3) float32: the environment's radiance along each pixel-centre camera
        ray (zeros without an environment); what the camera would see behind the
        subject, lights excluded. Cached until the camera or the rig moves."""
        if self._backdrop is None:
            self._backdrop = environment_backdrop(self)
        return self._backdrop

    def aovs(self, see_through=(), hits: bool = False) -> dict[str, np.ndarray]:
        """Pixel-centre G-buffer: see :func:`hack_render.render.aov.gbuffer`."""
        return gbuffer(self, see_through, hits)

    def region_hits(self, offset=(0.5, 0.5), see_through=("eyelashes",)) -> dict:
        """Region ids and model UVs at one sub-pixel point: see :func:`aov.region_hits`."""
        return region_hits(self, offset, see_through)

    def label_pass(self, k: int, region_labels, uv_label_map, uv_regions=(),
                   see_through=("eyelashes",), num_labels: int | None = None,
                   see_through_opacity: float | None = None) -> dict:
        """Label coverage of k x k sub-pixel rays and the pixel-centre G-buffer in one
        batch: see :func:`aov.label_pass`."""
        return label_pass(self, k, region_labels, uv_label_map, uv_regions, see_through,
                          num_labels, see_through_opacity)

    def visibility(self, points, tolerance: float = 2e-3, see_through=("eyelashes",)):
        """Line-of-sight visibility of world points: see :func:`aov.point_visibility`."""
        return point_visibility(self, points, tolerance, see_through)

    @property
    def region_names(self) -> tuple[str, ...]:
        return REGIONS
