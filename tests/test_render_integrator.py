"""The integrator of final renders (``RenderSettings.integrator``): hack_path
(render/integrator.py) and volpath, whose shadow rays see through the lash cards'
transparent parts, against path, whose shadow rays stop at every card; same image in the
mean, less noise under the lashes; the card's transmission exact on a small scene."""

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.render.engine import ensure_variant

ensure_variant()

from hack_render.render.parts import REGIONS
from hack_render.render.scene import DEFAULT_INTEGRATOR, INTEGRATORS, HeadScene, RenderSettings
from scenes import cameras, lights


def eye_closeup(res: int) -> cameras.Camera:
    """A close-up of the left eye (model +x), from a little above: ~40 mm across."""
    R, t = cameras.look_at([0.036, 0.040, 0.200], [0.034, 0.033, 0.092])
    return cameras.Camera(cameras.intrinsics(res, res, 90.0), R, t, res, res, "eye")


def seed_noise(a: np.ndarray, b: np.ndarray, sel: np.ndarray) -> float:
    """Relative noise of one render over the pixels ``sel``: the std of the difference
    of two seeds' (H, W, 4) images over their mean, / sqrt(2) (one image's share)."""
    d = (a[..., :3] - b[..., :3])[sel]
    return float(np.std(d) / np.sqrt(2.0) / np.mean(a[..., :3][sel]))


def test_01_integrator_is_validated_and_used(head_model):
    """A name other than hack_path, volpath or path is refused, naming the choices; the
    scene's Mitsuba integrator is the one asked for; hack_path is the default."""
    assert DEFAULT_INTEGRATOR == "hack_path" and RenderSettings().integrator == "hack_path"
    for bad in ("prb", "bdpt", "", None):
        with pytest.raises(HackError,
                           match="integrator: expected one of hack_path, volpath, path"):
            RenderSettings(integrator=bad)
    topo, v = head_model
    cam = cameras.preset("portrait", 16, 16, None)[0]
    kinds = {}
    for name in INTEGRATORS:
        head = HeadScene(topo, v, lights.preset("studio"), cam,
                         RenderSettings(16, 16, 1, integrator=name))
        kinds[name] = str(head.scene.integrator()).split("[")[0]
    # Mitsuba 3.9 names volpath's class VolumetricSimplePathIntegrator
    assert kinds["path"] == "PathIntegrator" and kinds["volpath"].startswith("Volumetric"), \
        kinds
    assert kinds["hack_path"] == "HackPathIntegrator", kinds


def test_02_integrators_agree_in_the_mean(head_model):
    """The three integrators estimate the same image: on the studio portrait at 64 px the
    means of two seeds each agree with path's within 2 % (measured: 0.7 %), and the alpha
    (the subject's coverage: camera rays pass through the lash cards' null part alike)
    agrees to 1e-3."""
    topo, v = head_model
    cam = cameras.preset("portrait", 64, 64, None)[0]
    img = {}
    for name in INTEGRATORS:
        head = HeadScene(topo, v, lights.preset("studio"), cam,
                         RenderSettings(64, 64, 32, integrator=name))
        img[name] = [head.render(seed=s, backdrop=False) for s in (0, 1)]
    for s in (0, 1):
        p = img["path"][s]
        for name in ("volpath", "hack_path"):
            vp = img[name][s]
            assert abs(vp[..., :3].mean() / p[..., :3].mean() - 1.0) < 0.02, (name, s)
            assert abs(vp[..., 3].mean() - p[..., 3].mean()) < 1e-3, (name, s)


def test_03_less_noise_under_the_lashes(head_model):
    """Eye close-up at 96 px, 16 spp: the sclera, most of it in the lash cards' shadow
    from the lights' side, is lit by next-event estimation through the cards with
    hack_path and volpath, and by BSDF-sampled paths alone with path. Its relative noise
    (two seeds) is under half of path's (measured here: 0.13 against 0.54), and the means
    agree: the sclera's within 10 % (path's own noise: ~3 %), the whole close-up's within
    3 %."""
    topo, v = head_model
    cam = eye_closeup(96)
    noise, mean = {}, {}
    for name in INTEGRATORS:
        head = HeadScene(topo, v, lights.preset("studio"), cam,
                         RenderSettings(96, 96, 16, integrator=name))
        sclera = head.region_hits()["region"] == REGIONS.index("sclera")
        assert sclera.sum() > 200
        a, b = (head.render(seed=s, backdrop=False) for s in (0, 1))
        noise[name] = seed_noise(a, b, sclera)
        mean[name] = (float((a + b)[..., :3][sclera].mean()), float((a + b)[..., :3].mean()))
    for name in ("volpath", "hack_path"):
        assert noise[name] < 0.5 * noise["path"], noise
        assert abs(mean[name][0] / mean["path"][0] - 1.0) < 0.1, mean
        assert abs(mean[name][1] / mean["path"][1] - 1.0) < 0.03, mean
    # same light transport, same noise (measured: within 5 %)
    assert abs(noise["hack_path"] / noise["volpath"] - 1.0) < 0.25, noise


def card_scene(integrator: str, opacities: tuple[float, ...], emitter_in_view: bool = False,
               area: bool = False):
    """A diffuse plane (z = 0, reflectance 0.5) lit by a point light at (0, 0, 1); a
    ``mask`` card 0.1 wide (opacity ``o``, over a diffuse BSDF) per entry of
    ``opacities`` at z = 0.5, 0.55, ... over the plane's centre, whose shadow covers what
    the camera sees: a 32 px, 3 degree view of the centre from (1, 0, 1), its rays clear
    of the cards. ``emitter_in_view`` adds an area light (a rectangle facing the camera's
    side, +z) across the camera's rays at (0.5, 0, 0.5). ``area``: the light is a disc
    4 cm across facing down instead (so BSDF-sampled paths through the cards reach it
    too, and multiple importance sampling must not count them twice)."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    d = {"type": "scene",
         "integrator": {"type": integrator, "max_depth": 4, "hide_emitters": True},
         "sensor": {"type": "perspective", "fov": 3.0,
                    "to_world": T().look_at(origin=[1, 0, 1], target=[0, 0, 0], up=[0, 0, 1]),
                    "film": {"type": "hdrfilm", "width": 32, "height": 32,
                             "pixel_format": "rgba", "rfilter": {"type": "box"}},
                    "sampler": {"type": "independent", "sample_count": 64}},
         "plane": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {
             "type": "rgb", "value": 0.5}}},
         "light": {"type": "point", "position": [0.0, 0.0, 1.0],
                   "intensity": {"type": "rgb", "value": 1.0}}}
    if area:  # the same power towards the plane: radiance = I / (pi r^2)
        d["light"] = {"type": "disk", "to_world": T().translate([0.0, 0.0, 1.0]).rotate(
            [1, 0, 0], 180).scale(0.02), "emitter": {"type": "area", "radiance": {
                "type": "rgb", "value": 1.0 / (np.pi * 0.02 ** 2)}}}
    for i, o in enumerate(opacities):
        d[f"card{i}"] = {"type": "rectangle",
                         "to_world": T().translate([0.0, 0.0, 0.5 + 0.05 * i]).scale(0.05),
                         "bsdf": {"type": "mask", "opacity": {"type": "uniform", "value": o},
                                  "bsdf": {"type": "diffuse"}}}
    if emitter_in_view:
        d["panel"] = {"type": "rectangle", "to_world": T().translate([0.5, 0.0, 0.5]).scale(0.2),
                      "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 3.0}}}
    return mi.load_dict(d)


@pytest.mark.parametrize("opacities", [(0.3,), (0.3, 0.6), (1.0,)])
@pytest.mark.parametrize("area", [False, True])
def test_04_shadow_rays_pass_cards_by_their_transparency(opacities, area):
    """The point light reaches the plane's centre through every card, weighted by each
    card's 1 - opacity: the plane (the cards are out of view) is lit to within 1 % of
    prod(1 - o) times its unshadowed radiance by hack_path and volpath (depth 4: the light
    that bounces off the cards' undersides is below 1 %; 2 % with the area light, its
    noise: paths through the cards reach the disc by BSDF sampling too, and multiple
    importance sampling must keep the last real bounce's density across the cards), and
    not at all by path (point light); an opaque card blocks all three."""
    import mitsuba as mi

    def centre(name, ops):
        img = np.asarray(mi.render(card_scene(name, ops, area=area), seed=0,
                                   spp=256 if area else 64))
        return float(img[..., :3].mean())

    open_ = centre("hack_path", ())
    # reflectance / pi x irradiance 1 / 1^2
    assert abs(open_ / (0.5 / np.pi) - 1.0) < (0.02 if area else 0.01), open_
    want = open_ * float(np.prod([1.0 - o for o in opacities]))
    for name in ("hack_path", "volpath"):
        got = centre(name, opacities)
        assert abs(got - want) <= (0.02 if area else 0.01) * open_, (name, got, want)
    if not area:
        assert centre("path", opacities) < 1e-6


def test_05_camera_rays_pass_hidden_area_lights():
    """With hide_emitters, camera rays pass an area light's rectangle and see what is
    behind it (the plane, which the one-sided panel, facing away from it, does not
    light), as volpath does: the two images agree with the open scene's radiance within
    2 % (light sampling picks the panel half the time: 0.4 % noise) and their alpha is 1."""
    import mitsuba as mi

    imgs = {name: np.asarray(mi.render(card_scene(name, (), emitter_in_view=True), seed=1))
            for name in ("hack_path", "volpath")}
    for img in imgs.values():
        assert np.all(img[..., 3] > 0.999)
        assert abs(img[..., :3].mean() / (0.5 / np.pi) - 1.0) < 0.02
