"""Per-pixel features over each pixel's footprint, for the denoiser and the skin's
subsurface scattering.

Unlike :mod:`hack_render.render.aov` (one ray through each pixel centre, crisp ids),
these average k x k stratified primary rays per pixel, so edges are antialiased like the
render's film. Both follow a ray through the see-through cards the renderer sees through
(the eyelashes, ``HeadScene.see_through_cards``): a ray that meets one counts the card with
weight ``opacity`` at the hit (a number, or the strand texture looked up at the hit's UV,
as the card's ``mask`` BSDF does) and what lies behind it with the rest, up to
``CARD_LAYERS`` cards deep. The film sees the skin through the lashes' gaps, so features
that stopped at the first card (a dark ring of lash albedo over the eyelids) would not
explain the image the denoiser is given.

The rays of :mod:`hack_render.render.aov` are traced with the helpers here: the first hit
past the lights (:func:`camera_hit`) and a card's opacity at a hit (:func:`opacity_at`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from hack_render.errors import HackError
from hack_render.hair.style import slab_albedo

#: How many see-through cards a footprint ray is followed through: the lashes are three
#: cards deep on each lid, and a ray grazing the lids crosses up to 7 where the strands'
#: gaps let it (tests/test_render_lashes.py::test_06: with 6, 0.6 % of an eye close-up's
#: pixels lost up to a third of their weight; with 8, none).
CARD_LAYERS = 8


def emitter_layers(head) -> int:
    """How many emitter shapes a camera ray may have to pass (the rig's area lights)."""
    return sum(1 for shape in head.scene.shapes() if shape.is_emitter())


def camera_hit(head, ray, active=True, coherent: bool = False):
    """The first intersection along ``ray`` that is not an emitter's shape (a camera ray
    looks through the area lights, as the renderer's ``hide_emitters`` does). Returns a
    SurfaceInteraction3f (invalid where nothing else is hit)."""
    import drjit as dr
    import mitsuba as mi

    active = mi.Bool(active)
    layers = emitter_layers(head)
    if layers == 0:
        return head.scene.ray_intersect(ray, mi.RayFlags.All, coherent, active)
    ray = mi.Ray3f(ray)
    pi = head.scene.ray_intersect_preliminary(ray, coherent, active)
    for _ in range(layers):
        # only the rays that met a light's rectangle are traced again, from just past it
        # (10 um; the head is metres away from it)
        skip = active & pi.is_valid() & pi.shape.is_emitter()
        ray.o = dr.select(skip, ray(pi.t + 1e-5), ray.o)
        pi = dr.select(skip, head.scene.ray_intersect_preliminary(ray, coherent, skip), pi)
    return pi.compute_surface_interaction(ray, mi.RayFlags.All, active)


def opacity_at(opacity, si, active):
    """A see-through card's opacity at intersections ``si``: a number, or a texture plugin
    looked up at the hit's UV (``eval_1``, what the ``mask`` BSDF does), clipped to [0, 1]."""
    import drjit as dr
    import mitsuba as mi

    if isinstance(opacity, (int, float)):
        return mi.Float(float(opacity))
    return dr.clip(opacity.eval_1(si, active), 0.0, 1.0)


def _footprint_rays(head, k: int, lanes):
    """The primary rays of footprint lanes ``lanes`` (a Dr.Jit UInt32 of lane indices,
    k x k stratified rays per pixel, pixel-major): (pixel index of each, the ray)."""
    import mitsuba as mi

    if not 1 <= k <= 16:
        raise HackError(f"footprint features: expected 1 <= k <= 16 rays per side, found {k}.")
    w, h, kk = head.camera.width, head.camera.height, k * k
    pix, sub = lanes // kk, lanes % kk
    x = mi.Float(pix % w) + (mi.Float(sub % k) + 0.5) / k
    y = mi.Float(pix // w) + (mi.Float(sub // k) + 0.5) / k
    sensor = head.scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    return pix, ray


class Layer(NamedTuple):
    """Footprint hits at one depth of cards: each ray's pixel index, the ray, its hit,
    whether the hit counts, and its weight (what the cards in front of it let through,
    times its own opacity where it is a card)."""
    pix: object
    ray: object
    hit: object
    ok: object
    weight: object


def footprint_means(head, k: int, see_through, values) -> list[np.ndarray]:
    """Per-pixel means over k x k stratified primary rays per pixel (each pixel's
    footprint, so edges are antialiased like the render's), looking through the lights,
    of the Floats ``values(layer)`` returns for the hits of each :class:`Layer`: the first
    hit and, behind each see-through card (``see_through``: (bsdf, opacity) pairs), the
    next, weighted by what the cards in front let through (weights of a ray sum to 1
    where it ends within ``CARD_LAYERS`` cards). (H, W) float32
    arrays, one per value.

    Two kernels: the first hits of all rays; then the rays on a card (a few per cent of a
    portrait's), compacted, traced again from the camera and on through the cards."""
    import drjit as dr
    import mitsuba as mi

    cards = [(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(card)), opacity)
             for card, opacity in see_through]

    def card_at(hit, ray, ok):  # (on a card, the opacity there: 1 elsewhere)
        ids = dr.reinterpret_array(mi.UInt32, hit.bsdf(ray))
        on_card, opacity = mi.Bool(False), mi.Float(1.0)
        for cid, op in cards:
            this = ok & (ids == cid)
            on_card |= this
            opacity = dr.select(this, opacity_at(op, hit, this), opacity)
        return on_card, opacity

    w, h = head.camera.width, head.camera.height
    acc = None

    def add(layer):
        nonlocal acc
        vals = values(layer)
        if acc is None:
            acc = [dr.zeros(mi.Float, w * h) for _ in vals]
        for a, value in zip(acc, vals, strict=True):
            dr.scatter_reduce(dr.ReduceOp.Add, a, value, layer.pix)

    lanes = dr.arange(mi.UInt32, w * h * k * k)
    pix, ray = _footprint_rays(head, k, lanes)
    hit = camera_hit(head, ray, coherent=True)
    ok = hit.is_valid()
    on_card, opacity = card_at(hit, ray, ok)
    add(Layer(pix, ray, hit, ok, opacity))
    dr.eval(acc, on_card)
    idx = dr.compress(on_card) if cards else None
    if idx is not None and dr.width(idx) > 0:
        pix, ray = _footprint_rays(head, k, dr.gather(mi.UInt32, lanes, idx))
        hit = camera_hit(head, ray, coherent=True)  # the first card, again
        ok = hit.is_valid()
        on_card, opacity = card_at(hit, ray, ok)
        trans = 1.0 - opacity
        for _ in range(CARD_LAYERS - 1):
            hit = camera_hit(head, hit.spawn_ray(ray.d), on_card, coherent=True)
            ok = on_card & hit.is_valid()
            on_card, opacity = card_at(hit, ray, ok)
            add(Layer(pix, ray, hit, ok, trans * opacity))
            trans = trans * (1.0 - opacity)
    dr.eval(acc)
    return [np.asarray(a, np.float32).reshape(h, w) / np.float32(k * k) for a in acc]


def hair_albedos(head) -> list[tuple[object, np.ndarray]]:
    """(bsdf, linear RGB albedo (3,)) of each hair shape of ``head`` (its ``hair_shapes``,
    found among the scene's shapes by id): the colour a thick layer of strands of the
    shape's melanin renders, :func:`hack_render.hair.style.slab_albedo` (the calibration
    measured by ``bench/hair_albedo.py``). Empty for a bald head."""
    shapes = {sh.id: sh for sh in getattr(head, "hair_shapes", ())}
    if not shapes:
        return []
    return [(shape.bsdf(), slab_albedo(shapes[shape.id()].eumelanin,
                                       shapes[shape.id()].pheomelanin))
            for shape in head.scene.shapes() if shape.id() in shapes]


def denoise_features(head, k: int = 4, see_through=()) -> tuple[np.ndarray, np.ndarray]:
    """The denoiser's auxiliary images: albedo and world-space shading normal, each
    (H, W, 3) float32, averaged over k x k stratified primary rays per pixel and through
    the ``see_through`` cards (see the module's notes; as Cycles' denoising features pass
    transparent surfaces); 0 where nothing is hit.

    A hit on a hair strand (:func:`hair_albedos`) gives the hair's colour as it renders
    (``eval_diffuse_reflectance`` of Mitsuba's ``hair`` BSDF is a grey unrelated to it)
    and the direction to the camera as its normal: a curve's shading normal turns across
    every strand, which OIDN reads as detail to keep. Of the normals tried on the hair of
    the Cycles comparison (``bench/bench_hair_cycles.py``: the shading normal, the
    strand's normal turned to face the camera, the camera direction), the camera direction
    left OIDN the least error over the whole image, and the calibrated colour more than
    the BSDF's grey or an albedo of 1 (docs/hair.md, "Against Blender Cycles")."""
    import drjit as dr
    import mitsuba as mi

    hair = [(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf)), rgb)
            for bsdf, rgb in hair_albedos(head)]

    def values(layer):
        hit, ok, w = layer.hit, layer.ok, layer.weight
        b = hit.bsdf(layer.ray)
        albedo = b.eval_diffuse_reflectance(hit, ok)
        normal = hit.sh_frame.n
        if hair:
            ids = dr.reinterpret_array(mi.UInt32, b)
            for hid, rgb in hair:
                on = ok & (ids == hid)
                albedo = dr.select(on, mi.Color3f(*(float(c) for c in rgb)), albedo)
                normal = dr.select(on, -layer.ray.d, normal)
        albedo = dr.select(ok, albedo * w, 0.0)
        normal = dr.select(ok, normal * w, 0.0)
        return [albedo[c] for c in range(3)] + [normal[c] for c in range(3)]

    m = footprint_means(head, k, see_through, values)
    return np.stack(m[:3], -1), np.stack(m[3:], -1)


def sss_features(head, skin_bsdf, see_through=(), k: int = 4) -> dict[str, np.ndarray]:
    """What :func:`hack_render.render.sss.scatter` needs, over each pixel's k x k rays:
    ``albedo`` (H, W, 3) of every hit, ``skin_albedo`` (H, W, 3) of the hits on
    ``skin_bsdf`` only (0 elsewhere), ``skin`` (H, W) the fraction of the pixel's light
    that comes from it, and ``depth`` (H, W) the mean distance from the camera to those
    hits, metres (0 where none). ``see_through``: (bsdf, opacity) pairs of cards the
    renderer sees through (the eyelashes; see the module's notes)."""
    import drjit as dr
    import mitsuba as mi

    skin_id = dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(skin_bsdf))

    def values(layer):
        hit, ok, w = layer.hit, layer.ok, layer.weight
        b = hit.bsdf(layer.ray)
        on = ok & (dr.reinterpret_array(mi.UInt32, b) == skin_id)
        a = dr.select(ok, b.eval_diffuse_reflectance(hit, ok), 0.0) * w
        skin_a = dr.select(on, a, 0.0)
        return ([a[c] for c in range(3)] + [skin_a[c] for c in range(3)]
                + [dr.select(on, w, 0.0), dr.select(on, w * dr.norm(hit.p - layer.ray.o), 0.0)])

    m = footprint_means(head, k, see_through, values)
    depth = np.where(m[6] > 0, m[7] / np.maximum(m[6], 1e-12), 0.0).astype(np.float32)
    return {"albedo": np.stack(m[:3], -1), "skin_albedo": np.stack(m[3:6], -1),
            "skin": m[6], "depth": depth}
