"""A head scene built once, then changed through ``mi.traverse`` parameters.

:class:`HeadScene` assembles the render parts (``parts.py``), their materials
(``materials.py``), a light rig and a camera into one Mitsuba scene. Per-frame changes
(vertices, skin maps, camera pose, light rotation) write into the traversed parameters
and call ``params.update()``: the scene is never reloaded, the BVH is refit/rebuilt by
Mitsuba, and since resolution, spp and the scene's structure stay fixed, Dr.Jit reuses
the kernels it compiled for the first frame.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError
from hack_render.render.cornea import CorneaRig
from hack_render.render.engine import ensure_variant, is_jit, release_parked, release_when_safe
from hack_render.render.parts import PART_SPECS, REGIONS, Topology, split_parts, vertex_normals
from scenes.cameras import Camera
from scenes.lights import LightRig

MAX_SIDE = 8192
MAX_PIXELS = 8192 * 8192
MAX_SPP = 1 << 16
#: Samples per render pass (one kernel launch); more spp are split into equal passes.
SAMPLES_PER_PASS = 1 << 24


#: Mitsuba samplers offered. Measured at about 32 spp on a 128 px studio portrait against
#: a 2,048-spp reference (docs/render.md): independent 30.5 dB, stratified (36) 35.3 dB,
#: multijitter (35) 36.7 dB, orthogonal (49) 40.5 dB, independent at 64 spp 33.8 dB.
#: ``auto``: Mitsuba's orthogonal array sampler where the count is near the square of a
#: prime of at least 5 (25, 49, 121, 169, ...), else multijitter (:func:`auto_sampler`).
SAMPLERS = ("auto", "multijitter", "stratified", "orthogonal", "ldsampler", "independent")
DEFAULT_SAMPLER = "auto"
#: ``auto``'s smallest orthogonal count (5^2). On two 256 px stills (hack_path, depth 8;
#: docs/render.md, "Samplers and denoising") the orthogonal array at 25-169 spp is
#: 2.4-4.8 dB less noisy than multijitter at the same count, at 9 spp about 1 dB better.
#: (Under volpath, whose samples lay out their dimensions otherwise, 25 was 2.6 dB worse.)
AUTO_ORTHOGONAL_MIN = 25
#: Integrators of final renders. ``path`` treats every surface as opaque to shadow rays,
#: so the lash cards' whole area blocks direct light from the lights' point of view and
#: what lies under them is lit by BSDF-sampled paths alone (speckled); ``volpath`` and
#: ``hack_path`` (render/integrator.py: ``path`` plus volpath's null surfaces, 0.74x
#: volpath's cost per sample on the README still) trace shadow rays through
#: null-transmissive surfaces, weighted by the ``mask`` BSDF's transparency (see
#: docs/render.md, "Integrator").
INTEGRATORS = ("hack_path", "volpath", "path")
DEFAULT_INTEGRATOR = "hack_path"


def _next_prime(n: int) -> int:
    n = max(n, 2)
    while any(n % d == 0 for d in range(2, math.isqrt(n) + 1)):
        n += 1
    return n


def auto_sampler(spp: int, cap: int | None = None) -> tuple[str, int]:
    """(Mitsuba sampler, sample count) that ``auto`` renders for a requested ``spp``: the
    orthogonal array at the prime square nearest to ``spp`` in ratio, where that is at
    least :data:`AUTO_ORTHOGONAL_MIN`, at most ``cap`` (a pass's sample budget) and
    within 0.7-1.3x of ``spp`` (32 -> 25, 64 -> 49, 100 -> 121), else multijitter (rounded
    as it rounds: 16 -> 16, 36 -> 36)."""
    best = None
    p = _next_prime(math.isqrt(AUTO_ORTHOGONAL_MIN))
    while p * p <= max(4 * spp, AUTO_ORTHOGONAL_MIN):
        if (cap is None or p * p <= cap) and 0.7 <= p * p / spp <= 1.3:
            r = abs(math.log(p * p / spp))
            if best is None or r < best[0]:
                best = (r, p * p)
        p = _next_prime(p + 1)
    if best is not None:
        return "orthogonal", best[1]
    return "multijitter", sampler_spp("multijitter", spp)


def sampler_spp(sampler: str, spp: int) -> int:
    """The sample count Mitsuba's ``sampler`` actually takes for a requested ``spp``
    (its own rounding, checked against Mitsuba in the tests): stratified rounds up to a
    square, multijitter to floor(sqrt n) x ceil(n / floor(sqrt n)), orthogonal to the
    square of a prime (at least 4), ldsampler to a power of 4 (at least 4); ``auto`` as
    :func:`auto_sampler` chooses."""
    if sampler == "auto":
        return auto_sampler(spp)[1]
    if sampler == "independent":
        return spp
    if sampler == "stratified":
        return math.ceil(math.sqrt(spp)) ** 2 if math.isqrt(spp) ** 2 != spp else spp
    if sampler == "multijitter":
        rx = max(1, math.isqrt(spp))
        return rx * math.ceil(spp / rx)
    if sampler == "orthogonal":
        p = math.isqrt(spp)
        p = p if p * p == spp else p + 1
        return _next_prime(p) ** 2
    if sampler == "ldsampler":
        k = 4
        while k < spp:
            k *= 4
        return k
    raise HackError(f"sampler: expected one of {', '.join(SAMPLERS)}, found {sampler!r}.")


@dataclass(frozen=True)
class RenderSettings:
    """Image size, samples per pixel, path depth, seed and sampler, validated on creation.

    Every sampler but ``independent`` rounds the sample count (:func:`sampler_spp`):
    :attr:`effective_spp` is what is rendered."""

    width: int = 512
    height: int = 512
    spp: int = 64
    max_depth: int = 8
    seed: int = 0
    #: ``gaussian`` (smoother) or ``box`` (bit-reproducible, see ``emitters.sensor_dict``).
    pixel_filter: str = "gaussian"
    sampler: str = DEFAULT_SAMPLER
    #: ``hack_path`` or ``volpath`` (shadow rays see through the lash cards' transparent
    #: parts: less noise under the lashes; the same image, hack_path the cheaper; non-JIT
    #: variants render ``hack_path`` as ``volpath``) or ``path`` (every surface blocks
    #: shadow rays; earlier versions)
    integrator: str = DEFAULT_INTEGRATOR

    def __post_init__(self):
        validate_size(self.width, self.height, self.spp)
        if self.integrator not in INTEGRATORS:
            raise HackError(f"integrator: expected one of {', '.join(INTEGRATORS)}, found "
                            f"{self.integrator!r}.")
        if self.sampler not in SAMPLERS:
            raise HackError(f"sampler: expected one of {', '.join(SAMPLERS)}, found "
                            f"{self.sampler!r}.")
        if self.pixel_filter not in ("gaussian", "box"):
            raise HackError(f"pixel filter: expected 'gaussian' or 'box', found "
                            f"{self.pixel_filter!r}.")
        if not 1 <= self.max_depth <= 64:
            raise HackError(f"max depth: expected 1..64 bounces, found {self.max_depth}.")
        if not 0 <= self.seed < 2 ** 31:
            raise HackError(f"seed: expected 0 <= seed < 2^31, found {self.seed}.")

    @property
    def passes(self) -> tuple[int, int]:
        """(number of passes, spp per pass) covering at least ``spp`` samples; the spp per
        pass is rounded as the sampler takes it."""
        n = max(1, math.ceil(self.width * self.height * self.spp / SAMPLES_PER_PASS))
        n = min(n, self.spp)
        return n, self._plan(n)[1]

    def _plan(self, n: int) -> tuple[str, int]:
        per = math.ceil(self.spp / n)
        if self.sampler == "auto":
            return auto_sampler(per, cap=max(per, SAMPLES_PER_PASS // (self.width
                                                                         * self.height)))
        return self.sampler, sampler_spp(self.sampler, per)

    @property
    def mitsuba_sampler(self) -> str:
        """The Mitsuba sampler rendered (``auto`` resolved for this size and count)."""
        return self._plan(self.passes[0])[0]

    @property
    def sampler_label(self) -> str:
        """The sampler as the commands report it (``auto`` with what it chose)."""
        if self.sampler == "auto":
            return f"auto: {self.mitsuba_sampler}"
        return self.sampler

    @property
    def effective_spp(self) -> int:
        """Samples per pixel actually rendered (passes x the sampler's rounded count)."""
        n, per = self.passes
        return n * per

    def spp_note(self) -> str | None:
        """One line when the sampler rounded the requested spp, else None."""
        if self.effective_spp == self.spp:
            return None
        how = ("prime square" if self.mitsuba_sampler == "orthogonal"
               else "count it rounds to")
        return (f"spp: {self.spp} requested, {self.effective_spp} rendered (the "
                f"{self.sampler_label} sampler takes {self.passes[1]} per pass, the "
                f"{how}; --sampler independent takes any count)")


def validate_size(width: int, height: int, spp: int) -> None:
    """Refuse zero, negative or absurd resolutions and sample counts (before allocating)."""
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_SIDE:
            raise HackError(f"image {name}: expected an integer in 1..{MAX_SIDE} pixels, found "
                            f"{v!r}. Pass e.g. --resolution 512.")
    if width * height > MAX_PIXELS:
        raise HackError(f"image size: expected at most {MAX_PIXELS} pixels, found "
                        f"{width}x{height}. Render a smaller image.")
    if not isinstance(spp, (int, np.integer)) or not 1 <= spp <= MAX_SPP:
        raise HackError(f"samples per pixel: expected an integer in 1..{MAX_SPP}, found "
                        f"{spp!r}. 16-64 spp is plenty for previews, 256+ for finals.")


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
        iris_rgb: linear RGB of the iris.
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
    """

    def __init__(self, topology: Topology, vertices, lights: LightRig, camera: Camera,
                 settings: RenderSettings | None = None, maps=None,
                 iris_rgb=None, variant: str | None = None, *, bust_cap: bool = True,
                 lash_strands: bool = True, cornea: bool = True):
        settings = settings or RenderSettings(camera.width, camera.height)
        if (camera.width, camera.height) != (settings.width, settings.height):
            raise HackError(f"camera {camera.name!r}: expected size {settings.width}x"
                            f"{settings.height} (the settings), found {camera.width}x"
                            f"{camera.height}.")
        self.variant = ensure_variant(variant)
        release_parked()  # dropped scenes die here, on the thread that renders
        import mitsuba as mi

        from hack_render.render import emitters, materials

        self.settings, self.camera, self.lights = settings, camera, lights
        self.topology = topology
        v = _np(vertices).reshape(-1, 3)
        if v.shape[0] != topology.num_vertices:
            raise HackError(f"vertices: expected ({topology.num_vertices}, 3) for this "
                            f"topology, found {v.shape}.")
        self.parts, self.eye_axes = split_parts(topology, v, cap=bust_cap)
        self._vertices = v
        iris = [p for p in self.parts if p.name == "iris"]
        #: the corneas refracting the iris for the camera (None: a plain iris)
        self.cornea = CorneaRig.from_topology(topology, v, self.eye_axes, iris[0].gather) \
            if cornea and iris else None
        maps = maps if maps is not None else materials.SkinMaps.constant()
        env = self._env_image(lights)
        jit = is_jit(self.variant)

        skin = mi.load_dict(materials.skin_bsdf(maps, jit))
        # the hack_skin plugin (JIT variants): render(sss=True) weights its lobes
        self._skin_bsdf = skin if hasattr(skin, "lobe_weights") else None
        #: (BSDF, opacity) of the see-through cards (the lashes): the opacity is a loaded
        #: texture plugin (its ``eval_1`` at a hit) or a number
        self._see_through: list[tuple[object, object]] = []
        self.lash_opacity: np.ndarray | None = None
        fixed = materials.fixed_bsdfs()
        normals = vertex_normals(v, topology.faces)
        # hide_emitters: camera rays pass through the area lights' rectangles and do not
        # see the environment, so no light is ever in frame and the film's alpha is the
        # subject's coverage; the environment is put back behind the subject as a
        # backdrop (:meth:`backdrop`), lights and shading unchanged (only depth-0 emission
        # is hidden)
        #: the Mitsuba integrator rendering this scene (``settings.integrator``, but
        #: ``volpath`` for ``hack_path`` in a non-JIT variant)
        self.integrator_name = settings.integrator if jit or \
            settings.integrator != "hack_path" else "volpath"
        self._split = None  # hack_path with the skin split, for render(sss=True)
        scene: dict = {"type": "scene",
                       "integrator": {"type": self.integrator_name,
                                      "max_depth": settings.max_depth,
                                      "hide_emitters": True},
                       "sensor": emitters.sensor_dict(camera, settings.passes[1],
                                                      pixel_filter=settings.pixel_filter,
                                                      sampler=settings.mitsuba_sampler)}
        for part in self.parts:
            if part.name.startswith("skin"):
                bsdf = skin
            elif part.name == "iris":
                bsdf = mi.load_dict(materials.iris_bsdf())
            elif part.name == "eyelashes":
                opacity = self._lash_opacity(part, v) if lash_strands \
                    else materials.EYELASH_OPACITY
                bsdf = mi.load_dict(materials.eyelash_bsdf(opacity))
                # see-through cards: the label and AOV passes (and render(sss=True)) look
                # up the same opacity at their hits
                self._see_through.append((bsdf, opacity))
            else:
                bsdf = mi.load_dict(fixed[part.name])
            mesh = self._mesh(part, self._positions(part, v, camera), normals[part.gather],
                              bsdf)
            if part.name == "iris":
                colours = materials.iris_vertex_colors(v[part.gather], self.eye_axes,
                                                       iris_rgb or materials.DEFAULT_IRIS_RGB)
                mesh.add_attribute("vertex_color", 3, mi.Float(colours.ravel()))
            scene[part.name] = mesh
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

    # --- construction helpers ------------------------------------------------------
    @staticmethod
    def _env_image(rig: LightRig) -> np.ndarray | None:
        from hack_render.render.image_io import read_hdr_image

        if rig.env_map is not None:
            return np.asarray(rig.env_map, dtype=np.float32)
        if rig.env_file is not None:
            return read_hdr_image(rig.env_file)
        return None

    def _lash_opacity(self, part, v: np.ndarray):
        """The lash cards' opacity: a ``bitmap`` texture plugin of the procedural strand
        map (``materials.lash_opacity_map``, kept in :attr:`lash_opacity`) over the cards
        found in the part's UVs (``parts.lash_cards``), or ``EYELASH_OPACITY`` where the
        UVs hold no cards (degenerate UVs): strands need a root-to-tip direction."""
        import mitsuba as mi

        from hack_render.render import materials
        from hack_render.render.parts import lash_cards

        cards = lash_cards(part, v, self.eye_axes)
        if len(cards) == 0:
            return materials.EYELASH_OPACITY
        self.lash_opacity = materials.lash_opacity_map(cards)
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
        return table

    # --- per-frame updates ---------------------------------------------------------
    def set_vertices(self, vertices, *, update: bool = True) -> None:
        """New vertex positions (N, 3) metres, same topology; normals are recomputed.

        ``update=False`` defers ``params.update()`` (see :meth:`update`)."""
        import mitsuba as mi

        v = _np(vertices).reshape(-1, 3)
        if v.shape[0] != self.topology.num_vertices or not np.all(np.isfinite(v)):
            raise HackError(f"vertices: expected finite ({self.topology.num_vertices}, 3), "
                            f"found {v.shape} (finite: {bool(np.all(np.isfinite(v)))}).")
        n = vertex_normals(v, self.topology.faces)
        self._vertices = v
        for part in self.parts:
            self.params[f"{part.name}.vertex_positions"] = mi.Float(
                self._positions(part, v, self.camera).ravel().astype(np.float32))
            if not part.flat:
                self.params[f"{part.name}.vertex_normals"] = mi.Float(
                    n[part.gather].ravel().astype(np.float32))
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

    def set_camera(self, camera: Camera, *, update: bool = True) -> None:
        """Move the camera (and change its focal length); the image size must stay."""
        import mitsuba as mi

        from hack_render.render.emitters import camera_to_world, check_intrinsics

        if (camera.width, camera.height) != (self.settings.width, self.settings.height):
            raise HackError(f"camera {camera.name!r}: expected size {self.settings.width}x"
                            f"{self.settings.height}, found {camera.width}x{camera.height}. "
                            "Build a new HeadScene for another resolution.")
        check_intrinsics(camera)
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

        from hack_render.render.emitters import area_light_transform, rotation_y

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
        if sss and self._skin_bsdf is None:
            warnings.warn("sss: subsurface scattering needs the hack_skin material of a JIT "
                          "variant (llvm_ad_rgb or cuda_ad_rgb); rendering without it.",
                          stacklevel=2)
            sss = False
        img = self._render_sss(base, progress) if sss else self._render_passes(base, progress)
        if denoise:
            img = self.denoise(img)
        return composite(img, self._backdrop_of(backdrop))

    def _render_passes(self, base: int, progress: bool, desc: str = "render passes",
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
            from tqdm import tqdm

            steps = tqdm(steps, desc=desc, unit="pass")
        for i in steps:
            img = np.asarray(mi.render(self.scene, seed=(base * 7919 + i) % (2 ** 31), **kw))
            acc = img if acc is None else acc + img
        return (acc / n).astype(np.float32)

    def set_lobe_weights(self, diffuse: float, specular: float) -> None:
        """Weight the skin material's diffuse and specular lobes (1, 1: the material as
        it is; a lobe weighted 0 is neither evaluated nor sampled). No recompilation."""
        import drjit as dr
        import mitsuba as mi

        if self._skin_bsdf is None:
            raise HackError("lobe weights: this scene's skin is not the hack_skin material "
                            "(a JIT variant's); found the scalar variant's stand-in.")
        w = (mi.Float(float(diffuse)), mi.Float(float(specular)))
        dr.make_opaque(*w)
        self._skin_bsdf.lobe_weights = w

    def lobe_passes(self, seed: int | None = None,
                    progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The two passes of ``render(sss=True)``, premultiplied (H, W, 4) each: the skin's
        diffuse lobe alone, then its specular lobe alone (other materials in both); the
        lobe weights are restored afterwards."""
        release_parked()
        base = self.settings.seed if seed is None else int(seed)
        try:
            self.set_lobe_weights(1.0, 0.0)
            diffuse = self._render_passes(base, progress, "render passes (skin diffuse)")
            self.set_lobe_weights(0.0, 1.0)
            rest = self._render_passes(base, progress, "render passes (specular, rest)")
        finally:
            self.set_lobe_weights(1.0, 1.0)
        return diffuse, rest

    def _render_sss(self, base: int, progress: bool) -> np.ndarray:
        """Render with subsurface scattering in the skin (:mod:`hack_render.render.sss`)."""
        from hack_render.render import sss
        from hack_render.render.footprint import sss_features

        focal = float(self.camera.K[0, 0])
        if self.integrator_name == "hack_path":  # one pass, the skin's diffuse as an AOV
            img = self._render_passes(base, progress, integrator=self._split_integrator())
            f = sss_features(self, self._skin_bsdf, self._see_through)
            out = img[..., :4].copy()
            out[..., :3] = sss.combine_split(img[..., :3], img[..., 4:7], f, focal)
            return out
        diffuse, rest = self.lobe_passes(base, progress)
        f = sss_features(self, self._skin_bsdf, self._see_through)
        out = diffuse.copy()
        out[..., :3] = sss.combine(diffuse[..., :3], rest[..., :3], f, focal)
        return out

    def _split_integrator(self):
        """This scene's ``hack_path`` with the skin split (AOVs skin_diffuse.RGB,
        skin_specular.RGB after RGBA; ``render/integrator.py``), made once."""
        if self._split is None:
            import mitsuba as mi

            self._split = mi.load_dict({"type": "hack_path", "hide_emitters": True,
                                        "max_depth": self.settings.max_depth,
                                        "split_skin": True})
            self._split.set_skin(self._skin_bsdf)
        return self._split

    def denoise(self, image: np.ndarray, fallback: bool = False, k: int = 4) -> np.ndarray:
        """A premultiplied render (H, W, 4) of this scene's current state (camera, mesh),
        denoised by OIDN with albedo and normal from :func:`footprint.denoise_features`
        (through the lash cards, as the film sees them); alpha kept. ``fallback``: a missing or failing denoiser returns the image unchanged
        with a warning instead of raising (see ``hack_render.render.denoise``)."""
        from hack_render.render import denoise as dn
        from hack_render.render.footprint import denoise_features

        albedo, normal = denoise_features(self, k, self._see_through)
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
            import drjit as dr
            import mitsuba as mi

            w, h = self.settings.width, self.settings.height
            env = self.scene.environment()
            if env is None:
                self._backdrop = np.zeros((h, w, 3), np.float32)
            else:
                idx = dr.arange(mi.UInt32, w * h)
                xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
                ray, _ = self.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5))
                si = dr.zeros(mi.SurfaceInteraction3f, w * h)
                si.wi = -ray.d
                rgb = env.eval(si)
                self._backdrop = np.stack([np.broadcast_to(np.asarray(rgb[c], np.float32),
                                                           (w * h,)) for c in range(3)],
                                          -1).reshape(h, w, 3)
        return self._backdrop

    def aovs(self) -> dict[str, np.ndarray]:
        """Pixel-centre G-buffer: see :func:`hack_render.render.aov.gbuffer`."""
        from hack_render.render.aov import gbuffer

        return gbuffer(self)

    def region_hits(self, offset=(0.5, 0.5), see_through=("eyelashes",)) -> dict:
        """Region ids and model UVs at one sub-pixel point: see :func:`aov.region_hits`."""
        from hack_render.render.aov import region_hits

        return region_hits(self, offset, see_through)

    def label_pass(self, k: int, region_labels, uv_label_map, uv_regions=(),
                   see_through=("eyelashes",), num_labels: int | None = None,
                   see_through_opacity: float | None = None) -> dict:
        """Label coverage of k x k sub-pixel rays and the pixel-centre G-buffer in one
        batch: see :func:`aov.label_pass`."""
        from hack_render.render.aov import label_pass

        return label_pass(self, k, region_labels, uv_label_map, uv_regions, see_through,
                          num_labels, see_through_opacity)

    def visibility(self, points, tolerance: float = 2e-3, see_through=("eyelashes",)):
        """Line-of-sight visibility of world points: see :func:`aov.point_visibility`."""
        from hack_render.render.aov import point_visibility

        return point_visibility(self, points, tolerance, see_through)

    @property
    def region_names(self) -> tuple[str, ...]:
        return REGIONS
