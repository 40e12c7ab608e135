"""The ``hack_skin`` BSDF: Lambert diffuse + dual-lobe GGX specular with skin Fresnel.

A Python ``mi.BSDF`` plugin (JIT variants trace it into the same kernels as the C++
plugins). Per shading point it reads four textures, all differentiable through
``mi.traverse`` (keys ``<bsdf>.albedo.data``, ``.specular.data``, ``.roughness.data``,
``.normalmap.data``):

- ``albedo``: diffuse reflectance rho, linear Rec.709 RGB.
- ``specular``: intensity s in [0, 1] scaling the specular lobe (0 turns it off).
- ``roughness``: perceptual roughness r; GGX alpha = max(r^2, 1e-3).
- ``normalmap`` (optional): unit tangent-space normals, OpenGL convention (+X along +u,
  +Y along +v), stored as raw vectors in [-1, 1] (not [0, 1]-encoded).

The model (with F(c) Schlick's Fresnel for F0 = ``f0``, 0.028 for skin, n = 1.4)::

    f(wi, wo) = rho/pi * (1 - s F(cos_i)) (1 - s F(cos_o))        (diffuse lobe)
              + s F(wi.h) sum_k w_k D_k(h) G_k(wi, wo) / (4 cos_i cos_o)   (specular)

Skin's specular is two GGX lobes (the oily film's sharp sheen over the rougher
stratum corneum; the "dual lobe" of d'Eon & Luebke's and of production skin shaders):
lobe k has perceptual roughness ``lobe_roughness[k]`` x r and weight ``w_k``
(``lobe_mix`` = w_0, w_1 = 1 - w_0). Defaults 0.75 x r and 1.3 x r mixed 0.85 : 0.15
(Unreal's subsurface-profile defaults); ``lobe_mix`` 1 with ``lobe_roughness`` (1, 1)
gives the single lobe of before.

Both lobes are symmetric in (wi, wo), so the BSDF is reciprocal; the diffuse lobe with
s = 0 is exactly Lambertian (white furnace = rho); the (1 - sF) factors take the energy
the specular lobe reflects away from the diffuse lobe, keeping the total below 1.
Normal mapping builds a perturbed frame from the interpolated normal and the UV tangent
(``dp_du``); directions below either the interpolated or the perturbed surface get zero,
which avoids light leaks the way Mitsuba's ``normalmap`` plugin does.
"""

from __future__ import annotations

NAME = "hack_skin"
#: Dual-lobe specular: perceptual roughness multipliers of the two lobes and the first's
#: weight (Unreal's subsurface-profile defaults: 0.75, 1.30, 0.85).
LOBE_ROUGHNESS = (0.75, 1.30)
LOBE_MIX = 0.85
#: Normal-incidence reflectance of skin (index of refraction about 1.4).
SKIN_F0 = 0.028
MIN_ALPHA = 1e-3


def make_class():
    """Define the plugin class against the active variant's ``mi.BSDF`` (registered by
    ``engine.register_plugins``)."""
    import drjit as dr
    import mitsuba as mi

    def schlick(f0, c):
        c = dr.clip(c, 0.0, 1.0)
        return f0 + (1.0 - f0) * dr.square(dr.square(1.0 - c)) * (1.0 - c)

    class SkinBSDF(mi.BSDF):
        """See the module docstring. Properties: albedo, specular, roughness (textures),
        normalmap (texture, optional), f0 (float, default 0.028)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.albedo = props["albedo"]
            self.specular = props["specular"]
            self.roughness = props["roughness"]
            self.normalmap = props["normalmap"] if "normalmap" in props else None
            self.f0 = float(props["f0"]) if "f0" in props else SKIN_F0
            self.mix = float(props["lobe_mix"]) if "lobe_mix" in props else LOBE_MIX
            self.lobe_r = (float(props["lobe_roughness_0"]) if "lobe_roughness_0" in props
                           else LOBE_ROUGHNESS[0],
                           float(props["lobe_roughness_1"]) if "lobe_roughness_1" in props
                           else LOBE_ROUGHNESS[1])
            if not (0.0 <= self.mix <= 1.0 and min(self.lobe_r) > 0.0):
                raise ValueError(f"hack_skin: expected 0 <= lobe_mix <= 1 and positive lobe "
                                 f"roughness multipliers, found {self.mix}, {self.lobe_r}.")
            # lobe weights (diffuse, specular): 1, 1 but for HeadScene.render(sss=True),
            # which renders the two apart; opaque, so changing them compiles nothing
            self.lobe_weights = (mi.Float(1.0), mi.Float(1.0))
            dr.make_opaque(*self.lobe_weights)
            sv = mi.BSDFFlags.SpatiallyVarying | mi.BSDFFlags.FrontSide
            diffuse = mi.BSDFFlags.DiffuseReflection | sv
            glossy = mi.BSDFFlags.GlossyReflection | sv
            self.m_components = [diffuse, glossy]
            self.m_flags = diffuse | glossy

        # --- shading frame ---------------------------------------------------------
        def _frame(self, si, active):
            """Perturbed shading frame (world space) from the tangent-space normal map."""
            n = si.sh_frame.n
            if self.normalmap is None:
                return mi.Frame3f(n)
            c = self.normalmap.eval(si, active)
            t = si.dp_du - n * dr.dot(n, si.dp_du)
            ok = dr.squared_norm(t) > 1e-20
            t = dr.normalize(t)
            b = dr.cross(n, t)
            # Mitsuba's texture v runs opposite to OpenGL's (we pass v' = 1 - v), so the
            # OpenGL +v tangent is -dp_dv; mirrored UV islands flip the bitangent.
            b = b * dr.select(dr.dot(b, si.dp_dv) > 0.0, -1.0, 1.0)
            nw = dr.normalize(t * c[0] + b * c[1] + n * c[2])
            nw = dr.select(ok & (dr.squared_norm(nw) > 0), nw, n)
            return mi.Frame3f(nw)

        def _params(self, si, active):
            """Specular intensity s and the two lobes' GGX alphas."""
            s = dr.clip(self.specular.eval_1(si, active), 0.0, 1.0)
            r = self.roughness.eval_1(si, active)
            alphas = tuple(dr.maximum(dr.square(k * r), MIN_ALPHA) for k in self.lobe_r)
            return s, alphas

        def _lobes(self, alphas):
            """[(weight, GGX distribution)] of the specular lobes (weight 0 ones left out)."""
            out = []
            for w, a in zip((self.mix, 1.0 - self.mix), alphas):
                if w > 0.0:
                    out.append((w, mi.MicrofacetDistribution(mi.MicrofacetType.GGX, a, True)))
            return out

        def _lobe_prob(self, si, s, cos_i, active):
            """Probability of sampling the specular lobe, from the lobes' albedos."""
            rho = dr.mean(self.albedo.eval(si, active))
            ws = s * schlick(self.f0, cos_i)
            wd = (1.0 - ws) * rho
            p = ws / dr.maximum(ws + wd, 1e-8)
            return dr.select(ws > 0.0, dr.clip(p, 0.15, 0.9), 0.0)

        def _pick_prob(self, si, s, cos_i, has_d, has_s, active):
            """Probability of sampling the specular lobe, given the enabled components
            and the lobe weights (a lobe weighted 0 is never sampled)."""
            if not has_s:
                return mi.Float(0.0)
            kd, ks = self.lobe_weights
            p_s = dr.select(ks > 0.0, self._lobe_prob(si, s, cos_i, active), 0.0)
            only_s = dr.select(p_s > 0.0, 1.0, 0.0)
            return only_s if not has_d else dr.select(kd > 0.0, p_s, only_s)

        def _local(self, si, frame, wo):
            """(wi, wo) in the perturbed frame, and whether both lie above both surfaces."""
            wi_p = frame.to_local(si.to_world(si.wi))
            wo_p = frame.to_local(si.to_world(wo))
            ok = ((mi.Frame3f.cos_theta(si.wi) > 0.0) & (mi.Frame3f.cos_theta(wo) > 0.0)
                  & (mi.Frame3f.cos_theta(wi_p) > 0.0) & (mi.Frame3f.cos_theta(wo_p) > 0.0))
            return wi_p, wo_p, ok

        def _eval_pdf(self, ctx, si, wo, active):
            frame = self._frame(si, active)
            wi, wo_p, ok = self._local(si, frame, wo)
            active = active & ok
            s, alphas = self._params(si, active)
            cos_i = mi.Frame3f.cos_theta(wi)
            cos_o = mi.Frame3f.cos_theta(wo_p)
            has_d = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            has_s = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)

            value = mi.Color3f(0.0)
            kd, ks = self.lobe_weights
            if has_d:
                rho = self.albedo.eval(si, active)
                att = (1.0 - s * schlick(self.f0, cos_i)) * (1.0 - s * schlick(self.f0, cos_o))
                value += rho * (kd * att * cos_o * dr.inv_pi)
            h = dr.normalize(wi + wo_p)
            jac = 1.0 / dr.maximum(4.0 * dr.dot(wo_p, h), 1e-8)
            pdf_s, dg = mi.Float(0.0), mi.Float(0.0)
            for w, distr in self._lobes(alphas):
                pdf_s += w * distr.pdf(wi, h) * jac
                if has_s:
                    dg += w * distr.eval(h) * distr.G(wi, wo_p, h)
            if has_s:
                spec = s * schlick(self.f0, dr.dot(wi, h)) * dg / dr.maximum(4.0 * cos_i, 1e-8)
                value += mi.Color3f(ks * spec)
            p_s = self._pick_prob(si, s, cos_i, has_d, has_s, active)
            pdf = p_s * pdf_s + (1.0 - p_s) * mi.warp.square_to_cosine_hemisphere_pdf(wo_p)
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

        # --- BSDF interface ----------------------------------------------------------
        def eval(self, ctx, si, wo, active=True):
            return self._eval_pdf(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            frame = self._frame(si, active)
            wi = frame.to_local(si.to_world(si.wi))
            s, alphas = self._params(si, active)
            has_d = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            has_s = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1)
            p_s = self._pick_prob(si, s, mi.Frame3f.cos_theta(wi), has_d, has_s, active)
            pick_s = sample1 < p_s
            # which specular lobe: sample1 reused, rescaled within [0, p_s)
            u = sample1 / dr.maximum(p_s, 1e-8)
            lobes = self._lobes(alphas)
            m, _ = lobes[0][1].sample(wi, sample2)
            if len(lobes) > 1:
                m1, _ = lobes[1][1].sample(wi, sample2)
                m = dr.select(u < lobes[0][0], m, m1)
            wo_s = mi.reflect(wi, m)
            wo_d = mi.warp.square_to_cosine_hemisphere(sample2)
            wo_p = dr.select(pick_s, wo_s, wo_d)

            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = si.to_local(frame.to_world(wo_p))
            bs.eta = 1.0
            bs.sampled_component = dr.select(pick_s, mi.UInt32(1), mi.UInt32(0))
            bs.sampled_type = dr.select(pick_s, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                        mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
            value, pdf = self._eval_pdf(ctx, si, bs.wo, active)
            bs.pdf = pdf
            ok = active & (pdf > 0.0)
            weight = dr.select(ok, value / dr.maximum(pdf, 1e-20), 0.0)
            return bs, weight

        def eval_diffuse_reflectance(self, si, active=True):
            return self.albedo.eval(si, active)

        def traverse(self, callback):
            flags = mi.ParamFlags.Differentiable
            callback.put("albedo", self.albedo, flags)
            callback.put("specular", self.specular, flags)
            callback.put("roughness", self.roughness, flags)
            if self.normalmap is not None:
                callback.put("normalmap", self.normalmap, flags)

        def parameters_changed(self, keys):
            pass  # textures are evaluated at render time; nothing is cached here

        def to_string(self):
            return (f"SkinBSDF[f0={self.f0}, lobes={self.lobe_r} mixed {self.mix}, "
                    f"normalmap={self.normalmap is not None}]")

    return SkinBSDF

