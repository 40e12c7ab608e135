"""``hack_path``: the path tracer of final renders, whose shadow rays pass the lash cards.

Mitsuba's ``path`` stops a shadow ray at the first surface it meets, so a ``mask`` BSDF's
transparent part (the lash cards: opaque strands on a card that is transparent between
them) blocks the lights as if it were opaque, and what lies under the cards is lit by
BSDF-sampled paths alone (speckled). ``volpath`` passes null-transmissive surfaces in its
shadow rays, but it pays for its medium machinery on every sample: 1.3-1.55x ``path``'s
CPU time per sample on the README's still, with or without the cards in the scene.

``hack_path`` is ``path`` with ``volpath``'s treatment of null surfaces and nothing else
(there are no participating media in a :class:`~hack_render.render.scene.HeadScene`):

- a shadow ray is traced to its closest hit (``ray_intersect_preliminary``); a hit whose
  BSDF has no null component blocks it, a hit on one multiplies its transmittance by the
  BSDF's ``eval_null_transmission`` at that point (the card's ``1 - opacity``) and the
  ray goes on, at most :data:`MAX_NULL_CROSSINGS` times (beyond: blocked);
- a BSDF sample through a null component (``BSDFFlags.Null``) does not count as a bounce
  and keeps the last real scattering event for multiple importance sampling, as in
  ``volpath`` (so light reached through a card is not counted twice);
- ``hide_emitters``: camera rays do not see emitters and pass the area lights' shapes
  (as ``path`` and ``volpath`` do), so the film's alpha is the subject's coverage.

It estimates the same image as ``volpath`` (tests/test_render_integrator.py) at 0.98x
``path``'s cost per sample on the README's still, against volpath's 1.33x (on an eye
close-up, where most shadow rays cross cards, 1.56x against 1.67x; ``python
bench/bench_render.py --only integrator``, docs/render.md).
**Hair** (a scene with Mitsuba's ``hair`` BSDF, told by its glossy transmission:
:func:`is_hair`): ``hair_rr`` (true in a HeadScene with hair, ``hair_shapes.HAIR_RR``)
plays Russian roulette from a path's first event on hair whatever its depth (unbiased);
``hair_depth`` k > 0 ends a path at its k-th event on hair, that event's direct light
sampled alone (MIS weight 1): biased dark, off by default (docs/hair.md, Cost). Neither
changes a scene without hair.

JIT variants only (a Python integrator in a scalar variant would run per sample in
Python): :class:`~hack_render.render.scene.HeadScene` uses ``volpath`` there.

**Skin split** (``split_skin`` true, then :meth:`set_skin`): the same image, and two AOVs
that split it by the path's first real scattering event (null crossings aside): the
light that leaves the skin BSDF's diffuse lobe there (``skin_diffuse.R/G/B``) and its
specular lobe (``skin_specular.R/G/B``); the rest of the image is light whose first
event is on another material. The next-event estimate at that vertex is evaluated per
lobe (the BSDF context's component 0, the diffuse lobe), and the path sampled from it
carries the diffuse lobe's share f_d / f of its BSDF value in its direction into
everything it gathers later: each AOV is an unbiased estimate of its part, and the two
add up to the skin's light exactly. Subsurface scattering (``render/sss.py``) needs the
diffuse part apart; one pass gives it, where weighting the lobes in two renders took
twice the samples.
"""

from __future__ import annotations

# imported by engine.ensure_variant, once a variant is set (so these cost nothing more);
# module level, as the methods below are recompiled by @dr.syntax without closures
import drjit as dr
import mitsuba as mi

NAME = "hack_path"
#: Null surfaces a shadow ray may pass before it counts as blocked (a ray between the
#: lids crosses at most two cards of each lid in practice).
MAX_NULL_CROSSINGS = 6


def mis_weight(pdf_a, pdf_b):
    """The power heuristic (as Mitsuba's integrators): 0 where undefined."""
    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.select(dr.isfinite(w), w, 0.0)


def is_hair(bsdf):
    """Whether ``bsdf`` (a BSDF pointer) is Mitsuba's ``hair`` BSDF: in a
    :class:`~hack_render.render.scene.HeadScene` the only BSDF with a glossy transmission
    (tests/test_render_hair.py checks it)."""
    return mi.has_flag(bsdf.flags(), mi.BSDFFlags.GlossyTransmission)


def make_class():
    """Define the integrator class against the active variant's ``mi.SamplingIntegrator``
    (registered by ``engine.register_plugins``)."""
    class HackPathIntegrator(mi.SamplingIntegrator):
        """See the module docstring. Properties: ``max_depth`` (8; -1: unbounded),
        ``rr_depth`` (5), ``hide_emitters`` (false), ``split_skin`` (false),
        ``null_surfaces`` (true), ``hair_depth`` (0: no budget)."""

        def __init__(self, props):
            super().__init__(props)
            max_depth = int(props.get("max_depth", 8))
            if max_depth < -1 or max_depth == 0:
                raise ValueError(f"{NAME}: max_depth must be -1 or positive, found {max_depth}")
            self.max_depth = 2 ** 32 - 1 if max_depth == -1 else max_depth
            self.rr_depth = int(props.get("rr_depth", 5))
            if self.rr_depth <= 0:
                raise ValueError(f"{NAME}: rr_depth must be positive, found {self.rr_depth}")
            self.split = bool(props.get("split_skin", False))
            # false: the scene has no null surfaces (no lash cards: a groom's strand
            # lashes replace them), so a shadow ray is an any-hit test (``ray_test``), far
            # cheaper than closest hits through a head of hair
            self.null_surfaces = bool(props.get("null_surfaces", True))
            # the hair budget: a path ends at its hair_depth-th scattering event on hair,
            # with that event's direct light sampled alone (0: no budget)
            self.hair_depth = int(props.get("hair_depth", 0))
            if self.hair_depth < 0:
                raise ValueError(f"{NAME}: hair_depth must be >= 0, found {self.hair_depth}")
            # Russian roulette from a path's first event on hair, whatever its depth
            self.hair_rr = bool(props.get("hair_rr", False))
            self.skin_id = mi.UInt32(0)

        def set_skin(self, bsdf):
            """The BSDF whose first-event light the AOVs split by lobe (``split_skin``);
            its pointer is a kernel parameter, so the kernel is cached across scenes."""
            self.skin_id = dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf))
            dr.make_opaque(self.skin_id)

        def aov_names(self):
            if not self.split:
                return []
            return [f"skin_{lobe}.{c}" for lobe in ("diffuse", "specular") for c in "RGB"]

        def to_string(self):
            return (f"HackPathIntegrator[max_depth = {self.max_depth}, "
                    f"rr_depth = {self.rr_depth}, hair_depth = {self.hair_depth}, "
                    f"hide_emitters = {self.hide_emitters}]")

        def shadow(self, scene, si, p, active):
            """Transmittance from ``si`` to ``p``: :meth:`transmittance` through the null
            surfaces, or, in a scene without any (``null_surfaces`` false), one any-hit
            test (``ray_test``)."""
            if self.null_surfaces:
                return self.transmittance(scene, si, p, active)
            blocked = scene.ray_test(si.spawn_ray_to(p), active)
            return dr.select(blocked, 0.0, mi.Spectrum(1.0))

        @dr.syntax
        def transmittance(self, scene, si, p, active):
            """Transmittance from ``si`` to the point ``p`` through null surfaces (0 where
            an opaque surface lies between)."""
            ray = si.spawn_ray_to(p)
            tr = mi.Spectrum(1.0)
            crossings = mi.UInt32(0)
            active = mi.Bool(active)
            while active:
                pi = scene.ray_intersect_preliminary(ray, False, False, active)
                hit = active & pi.is_valid()
                null = hit & mi.has_flag(pi.shape.bsdf().flags(), mi.BSDFFlags.Null)
                tr[hit & ~null] = 0.0
                si_n = pi.compute_surface_interaction(
                    ray, mi.RayFlags.Minimal | mi.RayFlags.UV, null)
                tr[null] = tr * si_n.bsdf().eval_null_transmission(si_n, null)
                crossings[null] = crossings + 1
                tr[null & (crossings >= MAX_NULL_CROSSINGS)] = 0.0
                active = null & (dr.max(tr) > 0.0)
                ray[active] = si_n.spawn_ray_to(p)
            return tr

        @dr.syntax
        def sample(self, scene, sampler, ray_, medium=None, active=True):
            ctx = mi.BSDFContext()
            ray = mi.Ray3f(ray_)
            throughput, result = mi.Spectrum(1.0), mi.Spectrum(0.0)
            eta = mi.Float(1.0)
            depth = mi.UInt32(0)
            active = mi.Bool(active)
            valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
            # the last real (non-null) scattering event, for MIS at emitter hits
            last_si = dr.zeros(mi.Interaction3f)
            last_pdf, last_delta = mi.Float(1.0), mi.Bool(True)
            # skin split: the first real event's class (0 none yet, 1 skin, 2 other), the
            # diffuse lobe's share of the path's throughput after it, the two parts
            ctx_d = mi.BSDFContext()
            ctx_d.component = 0
            first_cls = mi.UInt32(0)
            frac_d = mi.Spectrum(0.0)
            res_d, res_s = mi.Spectrum(0.0), mi.Spectrum(0.0)
            hair_events = mi.UInt32(0)
            while active:
                si = scene.ray_intersect(ray, mi.RayFlags.All, depth == 0, active)
                emitter = si.emitter(scene)
                # ---- emission reached by the last BSDF sample (or the camera)
                hidden = (depth == 0) & self.hide_emitters
                active_e = active & (emitter != None) & ~hidden
                ds = mi.DirectionSample3f(scene, si, last_si)
                em_pdf = scene.pdf_emitter_direction(last_si, ds, active_e & ~last_delta)
                w = dr.select(last_delta, 1.0, mis_weight(last_pdf, em_pdf))
                c_e = throughput * w * emitter.eval(si, active_e)
                result[active_e] = result + c_e
                if self.split:
                    on_skin_path = active_e & (first_cls == 1)
                    res_d[on_skin_path] = res_d + frac_d * c_e
                    res_s[on_skin_path] = res_s + (1.0 - frac_d) * c_e
                # camera rays pass the hidden area lights' shapes
                skip = active & hidden & si.is_valid() & (emitter != None)
                active &= si.is_valid() & ~skip
                bsdf = si.bsdf(ray)
                # ---- the hair budget: the last event on hair gets its direct light from
                # the emitter sample alone (MIS weight 1) and ends the path
                last_hair = mi.Bool(False)
                if self.hair_depth > 0 or self.hair_rr:
                    last_hair = active & is_hair(bsdf) & (self.hair_depth > 0) & \
                        (hair_events + 1 >= self.hair_depth)
                    hair_events[active & is_hair(bsdf)] = hair_events + 1
                # ---- next-event estimation, its shadow ray through null surfaces
                active_em = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & \
                    (depth + 1 < self.max_depth)
                ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), False,
                                                               active_em)
                active_em &= ds.pdf != 0.0
                em_weight *= self.shadow(scene, si, ds.p, active_em)
                bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_em)
                mis_em = dr.select(ds.delta | last_hair, 1.0, mis_weight(ds.pdf, bsdf_pdf))
                c_em = throughput * bsdf_val * em_weight * mis_em
                result[active_em] = result + c_em
                if self.split:
                    on_skin = dr.reinterpret_array(mi.UInt32, bsdf) == self.skin_id
                    at_first = active_em & (first_cls == 0) & on_skin
                    val_d = bsdf.eval(ctx_d, si, si.to_local(ds.d), at_first)
                    c_d = dr.select(at_first, throughput * val_d * em_weight * mis_em,
                                    frac_d * c_em)
                    skin_em = active_em & (at_first | (first_cls == 1))
                    res_d[skin_em] = res_d + c_d
                    res_s[skin_em] = res_s + (c_em - c_d)
                # ---- BSDF sampling; a null sample is no bounce
                bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(),
                                              active)
                real = active & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                if self.split:
                    on_skin = dr.reinterpret_array(mi.UInt32, bsdf) == self.skin_id
                    classify = real & (first_cls == 0)
                    at_skin = classify & on_skin
                    f_all = bsdf.eval(ctx, si, bs.wo, at_skin)
                    f_d = bsdf.eval(ctx_d, si, bs.wo, at_skin)
                    frac_d[at_skin] = dr.select(f_all > 0.0, f_d / f_all, 0.0)
                    first_cls[classify] = dr.select(on_skin, mi.UInt32(1), mi.UInt32(2))
                throughput[active] = throughput * bsdf_weight
                eta[active] = eta * bs.eta
                ray[active] = si.spawn_ray(si.to_world(bs.wo))
                ray[skip] = si.spawn_ray(ray.d)
                depth[real] = depth + 1
                last_si[real] = mi.Interaction3f(si)
                last_pdf[real] = bs.pdf
                last_delta[real] = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                valid_ray |= real
                # ---- Russian roulette
                t_max = dr.max(throughput)
                rr_prob = dr.minimum(t_max * dr.square(eta), 0.95)
                rr_active = (depth >= self.rr_depth) | (hair_events > 0)
                rr_continue = sampler.next_1d() < rr_prob
                throughput[rr_active] = throughput * dr.rcp(rr_prob)
                active = (active | skip) & (depth < self.max_depth) & \
                    (~rr_active | rr_continue) & (t_max != 0.0) & ~last_hair
            aovs = []
            if self.split:
                aovs = [dr.select(valid_ray, part[c], 0.0) for part in (res_d, res_s)
                        for c in range(3)]
            return dr.select(valid_ray, result, 0.0), valid_ray, aovs

    return HackPathIntegrator
