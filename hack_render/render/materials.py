"""Materials of the head parts, as Mitsuba plugin dictionaries, and the skin maps.

- skin: ``hack_skin`` (see ``skin_bsdf.py``) driven by the appearance maps; in the
  ``scalar_rgb`` fallback, Mitsuba's ``principled`` with the same maps, ``specular`` 0.35
  (its F0 = 0.08 * 0.35 = 0.028) and a ``normalmap`` wrapper.
- mouth (gums, tongue), teeth, sclera, lacrimal film: ``roughplastic`` (a diffuse base
  under a GGX dielectric coat), wet and glossy where the tissue is.
- iris: ``principled`` over per-vertex colours (pupil, iris with radial striations in
  the iris colour, dark limbal ring); its glossy clearcoat is the cornea's gloss, because
  the outer shell is opened over the cornea (``parts.py``); the cornea's refraction moves
  the iris's vertices for each camera (``cornea.py``), so the gloss sits where the iris
  appears.
- bust cap (closing the cut of the chest): matte grey (a sculpted bust's base), two-sided.
- lacrimal film: two-sided (a thin shell). eyelashes: dark brown, slightly glossy,
  two-sided, their opacity a procedural strand texture (:func:`lash_opacity_map`; ICT's
  lash cards expect an alpha texture that is not shipped), or 50 % where none is drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError
from hack_render.render.parts import LIMBUS_RADIUS, PART_SPECS, PUPIL_RADIUS, radial_eye_distance

DEFAULT_IRIS_RGB = (0.16, 0.09, 0.04)  # a brown iris, linear Rec.709
SCLERA_RGB = (0.70, 0.64, 0.60)
#: the lacrimal film's (caruncle, tear line) base colour; it follows a fitted sclera's
#: colour by the same per-channel ratio (:func:`fixed_bsdfs`)
LACRIMAL_RGB = (0.62, 0.45, 0.42)


@dataclass(frozen=True)
class SkinMaps:
    """Skin texture atlas (numpy, float32), covering u in [0, 2] as [0, 1] x 2 tiles.

    Attributes (H rows, 2H columns, row 0 is v = 1):
        diffuse: (H, 2H, 3) linear Rec.709 albedo. specular: (H, 2H, 1) intensity in [0, 1].
        roughness: (H, 2H, 1) perceptual roughness. normal: (H, 2H, 3) unit tangent-space
        normals (OpenGL, +Y along +v), or None for the interpolated mesh normal.
        iris_rgb: the iris's linear RGB (``fit``'s estimate from the photo, a texture
        folder's ``iris.json``), or None for the renderer's default
        (:data:`DEFAULT_IRIS_RGB`).
        sclera_rgb: the eye whites' linear RGB, as the iris's (``iris.json``'s
        ``sclera_rgb``), or None for :data:`SCLERA_RGB`.
        eye_gloss: the eyes' wet gloss (the sclera's and lacrimal film's coat, the
        cornea's clearcoat) as a share of the default's, in [0, 1]; None for 1.
        part_rgb: per-vertex linear RGB in [0, 1] of the parts that are not skin, by part
            name (:data:`VERTEX_COLOUR_PARTS`; each (n, 3), n the part's vertices), e.g.
            the fit's bake of the photo onto them (``fit/part_bake.py``), replacing the
            part's own colour (the iris's pattern, the teeth's white); a part not named
            keeps its own. None: none.
        brows_baked: the diffuse map holds the person's brows (a fit's bake with
            ``final.features``, a texture folder's ``skin.json``): a render with hair draws
            no brow strands over them.
    """

    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray | None = None
    iris_rgb: tuple[float, float, float] | None = None
    sclera_rgb: tuple[float, float, float] | None = None
    eye_gloss: float | None = None
    part_rgb: dict | None = None
    brows_baked: bool = False

    def __post_init__(self):
        h = self.diffuse.shape[0]
        for name, e in (self.part_rgb or {}).items():
            if name not in VERTEX_COLOUR_PARTS:
                raise HackError(f"part colours: expected parts among {VERTEX_COLOUR_PARTS}, "
                                f"found {name!r}.")
            e = np.asarray(e)
            if e.ndim != 2 or e.shape[1] != 3 or not np.all(np.isfinite(e)) \
                    or e.min() < 0.0 or e.max() > 1.0:
                raise HackError(f"part colours {name!r}: expected (n, 3) linear RGB in [0, 1], "
                                f"found an array of shape {e.shape}"
                                + (" with values outside [0, 1]" if e.ndim == 2 else "") + ".")
        want = {"diffuse": 3, "specular": 1, "roughness": 1, "normal": 3}
        for key, c in want.items():
            a = getattr(self, key)
            if a is None and key == "normal":
                continue
            if a.shape != (h, 2 * h, c):
                raise HackError(f"skin map {key!r}: expected shape ({h}, {2 * h}, {c}) (H, 2H, "
                                f"C), found {a.shape}.")
            if not np.all(np.isfinite(a)):
                raise HackError(f"skin map {key!r}: expected finite values, found NaN/Inf.")

    @staticmethod
    def constant(height: int = 16, albedo=(0.46, 0.29, 0.22), specular: float = 0.6,
                 roughness: float = 0.5) -> SkinMaps:
        """Uniform maps (a stand-in where no appearance model is given)."""
        shape = (height, 2 * height)
        return SkinMaps(np.broadcast_to(np.float32(albedo), shape + (3,)).copy(),
                        np.full(shape + (1,), specular, np.float32),
                        np.full(shape + (1,), roughness, np.float32), None)

    @staticmethod
    def from_appearance(maps, index: int = 0) -> SkinMaps:
        """From ``AppearanceModel.maps(alpha)`` output (batched torch tensors): item ``index``."""
        def get(name):
            x = getattr(maps, name, None)
            if x is None:
                return None
            x = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
            return np.ascontiguousarray(x[index] if x.ndim == 4 else x, dtype=np.float32)

        return SkinMaps(get("diffuse"), get("specular"), get("roughness"), get("normal"))


def bitmap(data: np.ndarray, raw: bool = True) -> dict:
    """A ``bitmap`` texture dict from an (H, W, C) float array (bilinear, clamped at edges)."""
    import mitsuba as mi

    return {"type": "bitmap", "data": mi.TensorXf(np.ascontiguousarray(data, np.float32)),
            "raw": raw, "filter_type": "bilinear", "wrap_mode": "clamp"}


def skin_bsdf(maps: SkinMaps, jit: bool) -> dict:
    """The skin BSDF dict: ``hack_skin`` in JIT variants, ``principled`` in scalar ones."""
    if jit:
        d = {"type": "hack_skin", "albedo": bitmap(maps.diffuse),
             "specular": bitmap(maps.specular), "roughness": bitmap(maps.roughness)}
        if maps.normal is not None:
            d["normalmap"] = bitmap(maps.normal)
        return d
    base = {"type": "principled", "base_color": bitmap(maps.diffuse),
            "roughness": bitmap(maps.roughness), "specular": 0.35}
    if maps.normal is None:
        return base
    return {"type": "normalmap", "normalmap": bitmap(0.5 * maps.normal + 0.5), "bsdf": base}


#: Uniform opacity of the lash cards where no strand texture can be built (see
#: :func:`fixed_bsdfs`; HeadScene uses :func:`lash_opacity_map` on ICT's cards).
EYELASH_OPACITY = 0.5
#: Side (texels) and seed of the procedural lash opacity texture.
LASH_MAP_SIZE = 512
LASH_SEED = 28


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def lash_opacity_map(cards: np.ndarray, size: int = LASH_MAP_SIZE, seed: int = LASH_SEED,
                     density: float = 85.0) -> np.ndarray:
    """A procedural opacity texture of lash strands for the lash cards (not a captured or
    shipped texture: ICT's lash alpha map is not distributed, so it is drawn here).

    Each card (``parts.lash_cards``: u0, u1, v_root, v_tip in Mitsuba texture
    coordinates) gets ``density`` strands per unit of u (about 40 per ICT card, three
    cards per lid), jittered along the lid. A strand is a thin strip from the root
    towards the tip: 1.2-2.0 texels wide at the root (at 512 texels), narrowing by 65 %,
    fully opaque over its first half and fading out (smoothstep) to its length, which is
    0.6-1 of the card (shorter towards the lid's corners), with a slight outward lean and
    a random curl. Coverage across a strip is box-filtered per texel, and strands combine
    as 1 - prod(1 - a). Between strands and beyond the tips the opacity is 0.

    Deterministic: numpy's PCG64 seeded with ``seed``. Returns (size, size) float32 in
    [0, 1]; row r covers v in [r, r + 1) / size, column c covers u in [c, c + 1) / size.
    """
    cards = np.asarray(cards, np.float64).reshape(-1, 4)
    if not 16 <= size <= 8192:
        raise HackError(f"lash texture: expected a size of 16..8192 texels, found {size}.")
    rng = np.random.default_rng(seed)
    keep = np.ones((size, size))  # 1 - opacity
    centre = (np.arange(size) + 0.5) / size  # texel centres, texture units
    unit = size / 512.0  # strand widths are given in texels of a 512 texture
    for u0, u1, v_root, v_tip in cards:
        span = v_tip - v_root
        n = max(1, round(density * float(u1 - u0)))
        s = (np.arange(n) + 0.5 + rng.uniform(-0.35, 0.35, n)) / n  # across the lid
        length = (0.6 + 0.4 * np.sin(np.pi * s) ** 0.5) * rng.uniform(0.65, 1.0, n)
        width = rng.uniform(1.2, 2.0, n) * unit / size  # at the root, texture units
        lean = ((s - 0.5) * 0.3 + rng.normal(0.0, 0.06, n)) * abs(span)
        curl = rng.normal(0.0, 0.05, n) * abs(span)
        rows = np.nonzero((centre - v_root) * np.sign(span) >= 0)[0]
        t = (centre[rows] - v_root) / span
        rows, t = rows[t <= 1.0], t[t <= 1.0]
        for i in range(n):
            on = t <= length[i]
            r, ti = rows[on], t[on]
            mid = u0 + s[i] * (u1 - u0) + lean[i] * ti + curl[i] * ti ** 2
            half = 0.5 * width[i] * (1.0 - 0.65 * ti / length[i])
            fade = 1.0 - _smoothstep(0.5 * length[i], length[i], ti)
            lo = int(np.floor((mid - half).min() * size))
            hi = int(np.ceil((mid + half).max() * size))
            # kept to the card's columns (a strand leaning off the card is cut there)
            cols = np.arange(max(lo, int(np.floor(u0 * size))),
                             min(hi, int(np.ceil(u1 * size)) - 1, size - 1) + 1)
            edges = cols / size
            cover = np.clip(np.minimum((mid + half)[:, None], edges + 1.0 / size)
                            - np.maximum((mid - half)[:, None], edges), 0.0, None) * size
            keep[np.ix_(r, cols)] *= 1.0 - np.clip(cover, 0.0, 1.0) * fade[:, None]
    return (1.0 - keep).astype(np.float32)


def eyelash_bsdf(opacity, eye_gloss=None) -> dict:
    """The lash cards' BSDF: dark brown, slightly glossy, two-sided, behind a ``mask`` whose
    opacity is ``opacity`` (a texture dict or object, e.g. :func:`bitmap` of
    :func:`lash_opacity_map`, or a number). ``eye_gloss`` scales the sheen (None: 1), as
    the eyes' gloss (:func:`fixed_bsdfs`): a fitted light too bright for the eyes' fixed
    colours makes the lashes' sheen a grey band along the lids by as much (the fit's
    eyes' figure: Grace Hopper's +0.6 dB with the sheen scaled so, docs/fit.md)."""
    if isinstance(opacity, (int, float)):
        opacity = {"type": "uniform", "value": float(opacity)}
    lash = _plastic((0.03, 0.02, 0.015), 0.3, 1.55)
    lash["specular_reflectance"] = {"type": "rgb", "value": [_gloss(eye_gloss)] * 3}
    return {"type": "mask", "opacity": opacity, "bsdf": {"type": "twosided", "bsdf": lash}}


def _plastic(rgb, alpha: float, ior: float = 1.4) -> dict:
    return {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": ior,
            "diffuse_reflectance": {"type": "rgb", "value": list(map(float, rgb))}}


def _checked_rgb(rgb, what: str) -> np.ndarray:
    a = np.asarray(rgb, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0) or np.any(a > 1):
        raise HackError(f"{what} colour: expected 3 linear RGB values in [0, 1], found "
                        f"{tuple(np.ravel(rgb))}.")
    return a


def _gloss(gloss) -> float:
    g = 1.0 if gloss is None else float(gloss)
    if not (np.isfinite(g) and 0.0 <= g <= 1.0):
        raise HackError(f"eye gloss: expected a share in [0, 1], found {gloss}.")
    return g


def fixed_bsdfs(sclera_rgb=None, eye_gloss=None) -> dict[str, dict]:
    """BSDF dicts of the non-skin parts, keyed by part name (iris: see :func:`iris_bsdf`).
    ``sclera_rgb``: the eye whites' colour (e.g. ``SkinMaps.sclera_rgb``, fitted to a
    photo), else :data:`SCLERA_RGB`; the lacrimal film follows it by the same ratio.
    ``eye_gloss``: their coat's share of its default reflection (None: 1), the
    ``specular_reflectance`` of both and of the lashes' sheen (:meth:`HeadScene.set_eyes`
    changes it in place)."""
    sclera = np.asarray(SCLERA_RGB) if sclera_rgb is None else _checked_rgb(sclera_rgb,
                                                                            "sclera")
    lacrimal = np.clip(np.asarray(LACRIMAL_RGB) * sclera / np.asarray(SCLERA_RGB), 0.0, 1.0)
    wet = {"sclera": _plastic(sclera, 0.05, 1.376), "lacrimal": _plastic(lacrimal, 0.03, 1.336)}
    for d in wet.values():   # always given (1: the plugin's default), so a scene can change
        d["specular_reflectance"] = {"type": "rgb", "value": [_gloss(eye_gloss)] * 3}
    return {
        "mouth": _plastic((0.42, 0.12, 0.11), 0.2),
        "teeth": _plastic((0.78, 0.72, 0.60), 0.15, 1.5),
        "sclera": wet["sclera"],
        # thin shells, seen from either side
        "lacrimal": {"type": "twosided", "bsdf": wet["lacrimal"]},
        # the cap over the cut of the chest: matte grey, as the base of a sculpted bust
        "bust_cap": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {
            "type": "rgb", "value": [0.40, 0.40, 0.42]}}},
        # lash cards without a strand texture (HeadScene draws one, lash_opacity_map):
        # uniformly half-transparent
        "eyelashes": eyelash_bsdf(EYELASH_OPACITY, eye_gloss),
    }


#: the parts whose colour may be given per vertex (``SkinMaps.part_rgb``)
VERTEX_COLOUR_PARTS = ("iris", "sclera", "lacrimal", "teeth", "mouth")


def vertex_colour_bsdf(fixed: dict) -> dict:
    """The BSDF of a part with per-vertex colours (attribute ``vertex_color``) that is
    otherwise ``fixed`` (one of :func:`fixed_bsdfs`' roughplastic, maybe two-sided): a
    principled BSDF of the same GGX roughness and Fresnel reflectance at normal
    incidence, its base colour the vertex colours (roughplastic needs Texture::mean(),
    which mesh_attribute textures do not implement; see :func:`iris_bsdf`)."""
    inner = fixed.get("bsdf", fixed)
    ior = float(inner.get("int_ior", 1.49))
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    gloss = inner.get("specular_reflectance", {}).get("value", [1.0])[0]
    out = {"type": "principled", "roughness": float(np.sqrt(inner["alpha"])),
           "specular": float(min(1.0, f0 / 0.08 * gloss)),
           "base_color": {"type": "mesh_attribute", "name": "vertex_color"}}
    return {"type": "twosided", "bsdf": out} if fixed.get("type") == "twosided" else out


def iris_bsdf(eye_gloss=None) -> dict:
    """Iris with a glossy corneal coat over per-vertex colours (attribute ``vertex_color``);
    ``eye_gloss`` scales the coat and the iris's own gloss (None: 1)."""
    # principled, not roughplastic: roughplastic needs Texture::mean(), which
    # mesh_attribute textures do not implement. The clearcoat is the corneal gloss.
    return {"type": "principled", "roughness": 0.6, "specular": 0.3 * _gloss(eye_gloss),
            "clearcoat": _gloss(eye_gloss),
            "clearcoat_gloss": 0.97,
            "base_color": {"type": "mesh_attribute", "name": "vertex_color"}}


def iris_vertex_colors(points: np.ndarray, axes, iris_rgb=DEFAULT_IRIS_RGB,
                       sclera_rgb=None) -> np.ndarray:
    """Colours (n, 3) of inner-eye vertices (n, 3) from their distance to the optical axis.

    Pupil (r < 1.7 mm) near black; iris in ``iris_rgb`` with 40 radial striations and a
    lighter collarette; a dark limbal ring towards r = 5.8 mm; the sclera's colour
    (``sclera_rgb``, else :data:`SCLERA_RGB`) beyond.
    """
    rgb = _checked_rgb(DEFAULT_IRIS_RGB if iris_rgb is None else iris_rgb, "iris")
    sclera = np.asarray(SCLERA_RGB) if sclera_rgb is None else _checked_rgb(sclera_rgb,
                                                                            "sclera")
    r, _ = radial_eye_distance(points, axes)
    centres = np.stack([c for c, _ in axes])
    ax = np.stack([a for _, a in axes])
    k = np.argmin(np.linalg.norm(points[:, None] - centres[None], axis=2), axis=1)
    d = points - centres[k]
    up = np.cross(ax[k], np.cross([0.0, 1.0, 0.0], ax[k]))
    side = np.cross(ax[k], up)
    angle = np.arctan2(np.einsum("ij,ij->i", d, side), np.einsum("ij,ij->i", d, up))
    t = np.clip((r - PUPIL_RADIUS) / (LIMBUS_RADIUS - PUPIL_RADIUS), 0.0, 1.0)
    striation = 0.8 + 0.2 * np.cos(40.0 * angle) * np.cos(13.0 * angle + 9.0 * t)
    collarette = 1.0 + 0.5 * np.exp(-0.5 * ((t - 0.3) / 0.08) ** 2)
    limbal = 1.0 - 0.7 * np.clip((t - 0.8) / 0.2, 0.0, 1.0)
    iris = rgb[None] * (striation * collarette * limbal)[:, None]
    out = np.where((r < LIMBUS_RADIUS)[:, None], iris, sclera[None])
    return np.where((r < PUPIL_RADIUS)[:, None], 0.01, out).astype(np.float32)


def set_eye_parameters(params, iris_points, eye_axes, iris_rgb=None, sclera_rgb=None,
                       eye_gloss=None) -> None:
    """Set a ``HeadScene``'s eye parameters (``params``: its ``mitsuba.traverse``) to these
    colours and gloss, as :func:`fixed_bsdfs`, :func:`iris_bsdf` and
    :func:`iris_vertex_colors` (of ``iris_points``, the iris part's vertices; None: none)
    build them; parts the scene lacks are skipped. The image is a scene's built with them,
    within 1e-4 where the gloss changes (the coat's share of the sampling stays the first
    one's; tests/test_render_scene.py). ``params.update()`` is the caller's."""
    import mitsuba as mi

    fixed = fixed_bsdfs(sclera_rgb, eye_gloss)
    coat = iris_bsdf(eye_gloss)
    values: dict = {"iris.bsdf.specular": float(coat["specular"]),
                    "iris.bsdf.clearcoat.value": float(coat["clearcoat"])}
    for key, bsdf in (("sclera.bsdf", fixed["sclera"]),
                      ("lacrimal.bsdf.brdf_0", fixed["lacrimal"]["bsdf"])):
        for attr in ("diffuse_reflectance", "specular_reflectance"):
            values[f"{key}.{attr}.value"] = mi.Color3f(*map(float, bsdf[attr]["value"]))
    values["eyelashes.bsdf.nested_bsdf.brdf_0.specular_reflectance.value"] = mi.Color3f(
        *fixed["eyelashes"]["bsdf"]["bsdf"]["specular_reflectance"]["value"])
    if iris_points is not None:
        values["iris.vertex_color"] = mi.Float(iris_vertex_colors(
            iris_points, eye_axes, DEFAULT_IRIS_RGB if iris_rgb is None else iris_rgb,
            sclera_rgb).ravel())
    for key, value in values.items():
        if key in params:
            params[key] = value


def material_base_colours(material_names, iris_rgb=None, sclera_rgb=None
                          ) -> dict[str, tuple[float, float, float]]:
    """Linear RGB base colour of each non-skin model material (``M_Teeth`` ...), from the
    parts' BSDFs above, for formats that carry one colour per material (MTL, glTF); the
    iris's is ``iris_rgb`` and the sclera's ``sclera_rgb`` (e.g. ``SkinMaps``'), else the
    defaults."""
    iris = tuple(iris_rgb) if iris_rgb is not None else DEFAULT_IRIS_RGB
    fixed = {**fixed_bsdfs(sclera_rgb), "iris": {"diffuse_reflectance": {"value": iris}}}
    out = {}
    for part, (mats, *_) in PART_SPECS.items():
        d = fixed.get(part)
        while d is not None and "diffuse_reflectance" not in d:
            d = d.get("bsdf")
        if d is None:
            continue
        rgb = tuple(float(x) for x in d["diffuse_reflectance"]["value"])
        out.update({m: rgb for m in mats if m in material_names})
    return out
