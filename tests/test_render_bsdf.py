"""hack_skin BSDF: white furnace, energy bound, reciprocity, sampling consistency, and a
rendered furnace (a textured sphere in a uniform environment)."""

import numpy as np
import pytest

from hack_render.render.engine import ensure_variant, is_jit

ensure_variant()
if not is_jit():
    pytest.skip("hack_skin needs a JIT variant (llvm_ad_rgb or cuda_ad_rgb)", allow_module_level=True)

import drjit as dr
import mitsuba as mi

from hack_render.render.materials import bitmap

N = 200_000


def skin(albedo=1.0, spec=0.0, rough=0.5, normal=None, **lobes):
    d = {"type": "hack_skin", "albedo": bitmap(np.full((4, 8, 3), albedo)),
         "specular": bitmap(np.full((4, 8, 1), spec)), "roughness": bitmap(np.full((4, 8, 1), rough)),
         **lobes}
    if normal is not None:
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        d["normalmap"] = bitmap(np.broadcast_to(n, (4, 8, 3)))
    return mi.load_dict(d)


def interaction(wi, n=N):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Normal3f(0, 0, 1)
    si.dp_du = mi.Vector3f(1, 0, 0)
    si.dp_dv = mi.Vector3f(0, -1, 0)  # Mitsuba's v runs opposite to OpenGL's
    si.uv = mi.Point2f(0.5, 0.5)
    si.wi = wi
    return si


def sampler(seed):
    s = mi.load_dict({"type": "independent"})
    s.seed(seed, N)
    return s


def albedo_estimate(bsdf, theta, seed=0):
    """Directional albedo by BSDF sampling: mean of the sample weights (red channel)."""
    wi = mi.Vector3f(float(np.sin(theta)), 0.0, float(np.cos(theta)))
    s = sampler(seed)
    _, w = bsdf.sample(mi.BSDFContext(), interaction(wi), s.next_1d(), s.next_2d())
    return float(dr.mean(w.x)[0]), float(dr.mean(dr.square(w.x))[0])


@pytest.mark.parametrize("theta", [0.0, 0.6, 1.2, 1.5])
def test_01_white_furnace_diffuse_lobe_is_one(theta):
    mean, _ = albedo_estimate(skin(1.0, 0.0), theta)
    assert abs(mean - 1.0) < 0.02


@pytest.mark.parametrize("rough", [0.05, 0.3, 0.8])
@pytest.mark.parametrize("theta", [0.0, 0.8, 1.4])
def test_02_energy_at_most_one_with_full_specular(rough, theta):
    mean, second = albedo_estimate(skin(1.0, 1.0, rough), theta, seed=1)
    sigma = np.sqrt(max(second - mean ** 2, 0.0) / N)
    assert mean <= 1.0 + 4 * sigma
    assert mean > 0.5  # the specular lobe takes energy but does not swallow the diffuse one


def test_03_specular_raises_reflection_at_grazing_angles():
    # Fresnel: the specular share grows towards grazing incidence
    def spec_only(theta):
        b = skin(0.0, 1.0, 0.3)
        return albedo_estimate(b, theta)[0]
    assert spec_only(1.4) > 3 * spec_only(0.0) > 0.0


@pytest.mark.parametrize("normal", [None, (0.3, -0.2, 0.93)])
def test_04_reciprocity(normal):
    b = skin(0.7, 0.8, 0.35, normal)
    rng = np.random.default_rng(4)
    n = 4096

    def dirs():
        d = rng.normal(size=(n, 3))
        d[:, 2] = np.abs(d[:, 2]) + 0.05
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    a, c = dirs(), dirs()
    va, vc = mi.Vector3f(a.T.astype(np.float32)), mi.Vector3f(c.T.astype(np.float32))
    ctx = mi.BSDFContext()
    if normal is None:
        cos_a, cos_c = a[:, 2], c[:, 2]
    else:
        nn = np.asarray(normal) / np.linalg.norm(normal)
        cos_a, cos_c = a @ nn, c @ nn
    f_ac = np.asarray(b.eval(ctx, interaction(va, n), vc)).T[:, 0] / np.maximum(cos_c, 1e-9)
    f_ca = np.asarray(b.eval(ctx, interaction(vc, n), va)).T[:, 0] / np.maximum(cos_a, 1e-9)
    ok = (cos_a > 0.05) & (cos_c > 0.05)
    assert ok.sum() > n // 4
    np.testing.assert_allclose(f_ac[ok], f_ca[ok], rtol=2e-3, atol=1e-6)


def test_05_sampling_matches_evaluation():
    """BSDF sampling and uniform hemisphere sampling estimate the same albedo."""
    b = skin(0.8, 1.0, 0.4)
    wi = mi.Vector3f(float(np.sin(0.7)), 0.0, float(np.cos(0.7)))
    s = sampler(7)
    _, w = b.sample(mi.BSDFContext(), interaction(wi), s.next_1d(), s.next_2d())
    wo = mi.warp.square_to_uniform_hemisphere(s.next_2d())
    v, pdf = b.eval_pdf(mi.BSDFContext(), interaction(wi), wo)
    by_sampling = float(dr.mean(w.x)[0])
    by_uniform = float(dr.mean(v.x)[0]) * 2 * np.pi
    assert abs(by_sampling - by_uniform) < 0.01
    # the pdf integrates to one over the hemisphere
    assert abs(float(dr.mean(pdf)[0]) * 2 * np.pi - 1.0) < 0.02


def test_07_dual_lobe_is_the_mixture_of_its_single_lobes():
    """The default specular (0.85 of a lobe at 0.75 r, 0.15 at 1.3 r) evaluates to that
    mixture of single-lobe BSDFs (mix 1) at the scaled roughness, and the single-lobe
    setting reproduces the one-lobe model; sampling the dual lobe matches evaluation."""
    r, n = 0.5, 20_000
    s = sampler(3)
    wi = mi.Vector3f(float(np.sin(0.5)), 0.0, float(np.cos(0.5)))
    wo = mi.warp.square_to_cosine_hemisphere(s.next_2d())
    ctx = mi.BSDFContext()
    ctx.component = 1  # the specular lobe only
    ctx.type_mask = +mi.BSDFFlags.GlossyReflection

    def f(b):
        return np.asarray(b.eval(ctx, interaction(wi, N), wo).x)[:n]

    dual = f(skin(0.5, 1.0, r))
    single = {k: f(skin(0.5, 1.0, r * k, lobe_mix=1.0, lobe_roughness_0=1.0))
              for k in (0.75, 1.3)}
    np.testing.assert_allclose(dual, 0.85 * single[0.75] + 0.15 * single[1.3], rtol=2e-4,
                               atol=1e-6)
    # the dual lobe is sharper at the peak and wider in the tail than one lobe at r
    one = f(skin(0.5, 1.0, r, lobe_mix=1.0, lobe_roughness_0=1.0))
    assert dual.max() > 1.2 * one.max()
    b = skin(0.8, 1.0, 0.4)
    wi2 = mi.Vector3f(float(np.sin(0.7)), 0.0, float(np.cos(0.7)))
    s2 = sampler(9)
    _, w = b.sample(mi.BSDFContext(), interaction(wi2), s2.next_1d(), s2.next_2d())
    wo2 = mi.warp.square_to_uniform_hemisphere(s2.next_2d())
    v, pdf = b.eval_pdf(mi.BSDFContext(), interaction(wi2), wo2)
    assert abs(float(dr.mean(w.x)[0]) - float(dr.mean(v.x)[0]) * 2 * np.pi) < 0.01
    assert abs(float(dr.mean(pdf)[0]) * 2 * np.pi - 1.0) < 0.02
    with pytest.raises(Exception, match="lobe_mix"):
        skin(lobe_mix=1.5)


def test_08_lobe_weights_split_the_bsdf_exactly():
    """HeadScene.render(sss=True) renders the skin's diffuse and specular lobes apart with
    the lobe weights (1, 0) and (0, 1): the two evaluate to the whole BSDF, each lobe's
    sampling matches its evaluation, and a lobe weighted 0 is never sampled."""
    b = skin(0.8, 1.0, 0.4)
    wi = mi.Vector3f(float(np.sin(0.7)), 0.0, float(np.cos(0.7)))
    s = sampler(11)
    wo = mi.warp.square_to_uniform_hemisphere(s.next_2d())
    ctx = mi.BSDFContext()

    def weights(d, sp):
        w = (mi.Float(d), mi.Float(sp))
        dr.make_opaque(*w)
        b.lobe_weights = w

    def ev():
        v, p = b.eval_pdf(ctx, interaction(wi), wo)
        return np.asarray(v.x), np.asarray(p)

    whole, _ = ev()
    weights(1.0, 0.0)
    diffuse, pdf_d = ev()
    _, w_d = b.sample(ctx, interaction(wi), s.next_1d(), s.next_2d())
    bs_d, _ = b.sample(ctx, interaction(wi), s.next_1d(), s.next_2d())
    weights(0.0, 1.0)
    specular, pdf_s = ev()
    bs_s, w_s = b.sample(ctx, interaction(wi), s.next_1d(), s.next_2d())
    weights(1.0, 1.0)
    np.testing.assert_allclose(diffuse + specular, whole, rtol=1e-5, atol=1e-7)
    assert diffuse.min() > 0 and specular.max() > 0
    # each lobe's sampling estimates its own albedo (uniform hemisphere estimate)
    assert abs(float(dr.mean(w_d.x)[0]) - diffuse.mean() * 2 * np.pi) < 0.01
    assert abs(float(dr.mean(w_s.x)[0]) - specular.mean() * 2 * np.pi) < 0.01
    for pdf in (pdf_d, pdf_s):
        assert abs(pdf.mean() * 2 * np.pi - 1.0) < 0.02
    # the lobe weighted 0 is never the sampled component
    assert np.all(np.asarray(bs_d.sampled_component) == 0)
    assert np.all(np.asarray(bs_s.sampled_component) == 1)


def uv_sphere(n_lat=24, n_lon=48, r=0.5):
    """A closed UV sphere with per-vertex texture coordinates (seam duplicated)."""
    lat = np.linspace(0, np.pi, n_lat + 1)
    lon = np.linspace(0, 2 * np.pi, n_lon + 1)
    th, ph = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([r * np.sin(th) * np.cos(ph), r * np.cos(th), r * np.sin(th) * np.sin(ph)], -1)
    uv = np.stack([ph / (2 * np.pi), th / np.pi], -1)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b_, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.concatenate([np.stack([a, d, b_], -1).reshape(-1, 3), np.stack([d, c, b_], -1).reshape(-1, 3)])
    return v.reshape(-1, 3), uv.reshape(-1, 2), f


def test_06_rendered_furnace_sphere_is_invisible():
    """Albedo 1, specular 0, uniform unit environment: every pixel has radiance 1."""
    v, uv, f = uv_sphere()
    mesh = mi.Mesh("sphere", len(v), len(f), has_vertex_normals=True, has_vertex_texcoords=True)
    p = mi.traverse(mesh)
    p["vertex_positions"] = mi.Float(v.ravel().astype(np.float32))
    p["vertex_texcoords"] = mi.Float(uv.ravel().astype(np.float32))
    p["faces"] = mi.UInt32(f.ravel().astype(np.uint32))
    p.update()
    mesh.recompute_vertex_normals()
    mesh.set_bsdf(skin(1.0, 0.0, 0.5))
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 64, "rr_depth": 1000},
        "sphere": mesh, "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 2.5], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 16}}})
    img = np.asarray(mi.render(scene, seed=3))
    centre = img[6:18, 6:18, :3]
    assert abs(centre.mean() - 1.0) < 0.02
