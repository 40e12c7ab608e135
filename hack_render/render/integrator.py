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
JIT variants only (a Python integrator in a scalar variant would run per sample in
Python): :class:`~hack_render.render.scene.HeadScene` uses ``volpath`` there.
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


def make_class():
    """Define the integrator class against the active variant's ``mi.SamplingIntegrator``
    (registered by ``engine.register_plugins``)."""
    class HackPathIntegrator(mi.SamplingIntegrator):
        """See the module docstring. Properties: ``max_depth`` (8; -1: unbounded),
        ``rr_depth`` (5), ``hide_emitters`` (false)."""

        def __init__(self, props):
            super().__init__(props)
            max_depth = int(props.get("max_depth", 8))
            if max_depth < -1 or max_depth == 0:
                raise ValueError(f"{NAME}: max_depth must be -1 or positive, found {max_depth}")
            self.max_depth = 2 ** 32 - 1 if max_depth == -1 else max_depth
            self.rr_depth = int(props.get("rr_depth", 5))
            if self.rr_depth <= 0:
                raise ValueError(f"{NAME}: rr_depth must be positive, found {self.rr_depth}")

        def aov_names(self):
            return []

        def to_string(self):
            return (f"HackPathIntegrator[max_depth = {self.max_depth}, "
                    f"rr_depth = {self.rr_depth}, hide_emitters = {self.hide_emitters}]")

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
            while active:
                si = scene.ray_intersect(ray, mi.RayFlags.All, depth == 0, active)
                emitter = si.emitter(scene)
                # ---- emission reached by the last BSDF sample (or the camera)
                hidden = (depth == 0) & self.hide_emitters
                active_e = active & (emitter != None) & ~hidden
                ds = mi.DirectionSample3f(scene, si, last_si)
                em_pdf = scene.pdf_emitter_direction(last_si, ds, active_e & ~last_delta)
                w = dr.select(last_delta, 1.0, mis_weight(last_pdf, em_pdf))
                result[active_e] = result + throughput * w * emitter.eval(si, active_e)
                # camera rays pass the hidden area lights' shapes
                skip = active & hidden & si.is_valid() & (emitter != None)
                active &= si.is_valid() & ~skip
                bsdf = si.bsdf(ray)
                # ---- next-event estimation, its shadow ray through null surfaces
                active_em = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & \
                    (depth + 1 < self.max_depth)
                ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), False,
                                                               active_em)
                active_em &= ds.pdf != 0.0
                em_weight *= self.transmittance(scene, si, ds.p, active_em)
                bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_em)
                mis_em = dr.select(ds.delta, 1.0, mis_weight(ds.pdf, bsdf_pdf))
                result[active_em] = result + throughput * bsdf_val * em_weight * mis_em
                # ---- BSDF sampling; a null sample is no bounce
                bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(),
                                              active)
                real = active & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
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
                rr_active = depth >= self.rr_depth
                rr_continue = sampler.next_1d() < rr_prob
                throughput[rr_active] = throughput * dr.rcp(rr_prob)
                active = (active | skip) & (depth < self.max_depth) & \
                    (~rr_active | rr_continue) & (t_max != 0.0)
            return dr.select(valid_ray, result, 0.0), valid_ray, []

    return HackPathIntegrator
