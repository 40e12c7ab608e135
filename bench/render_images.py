"""Render benchmarks of image quality and cost per sample (sections of bench/bench_render.py).

(c) Equal quality (``--only quality``): PSNR (linear) and SSIM (tone-mapped sRGB) of the
    studio portrait against a high-spp reference, for the ``independent`` and
    ``multijitter`` samplers over a range of spp and for multijitter + OIDN denoising;
    CPU seconds per image (process time, all threads: Dr.Jit's and OIDN's). The time the
    independent sampler needs to reach the denoised image's PSNR is interpolated on its
    PSNR-log(spp) curve.

(e) Subsurface scattering by volumetric path tracing (``--only sss``): a skin-sized
    sphere (radius 9 cm) with a rough dielectric boundary (n = 1.4) around a homogeneous
    medium whose coefficients come from ``appearance/skin_optics.py`` (dermis with 5 %
    blood, reduced scattering, at 610 / 550 / 465 nm for R, G, B), rendered by
    ``volpath`` against the same sphere with ``hack_skin`` (albedo: the same model's
    two-layer Kubelka-Munk albedo) under the studio rig: CPU seconds at equal spp.

(e2) Screen-space subsurface scattering (``--only sss``, after (e)): what final renders
    use (``HeadScene.render(sss=True)``): CPU seconds against the plain render at equal
    spp, with and without OIDN; PSNR of each against its own 1,024-spp reference; how
    well its two passes add up per pixel class; ``docs/images/sss_side_by_side.png``.

(h) Integrators (``--only integrator``): hack_path, volpath and path on the README's still at
    256 px and an eye close-up at 192 px, equal time, each against its own high-spp
    reference (:func:`integrator_benchmark`); ``bench/results/render_integrator.json``.

(i) Samplers (``--only samplers``): multijitter against the orthogonal array sampler (what
    ``auto`` picks near 49, 121, 169, ... spp) on the Cycles comparison's still (portrait)
    and a three-quarter view with the README's pose, 256 px, volpath, depth 8: PSNR over
    the image (linear RGB, peak 1) against a 2,048-spp multijitter reference, CPU seconds
    (median of 2 seeds), and the CPU time multijitter needs for each orthogonal rung's
    PSNR (log-log interpolated); ``bench/results/render_samplers.json``.

Run through ``bench/bench_render.py`` (``--only quality, sss, integrator or samplers``), which imports this module.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch


def time_at_psnr(rows: list[dict], level: float) -> float | None:
    """CPU seconds a renderer's ladder needs for ``level`` dB: walking its rungs in time
    order, the first segment that rises through the level, log(time) linear in PSNR
    there; None when the cheapest rung is already above it or no rung reaches it."""
    from itertools import pairwise

    pts = sorted((r["cpu_s"], r["psnr"]) for r in rows)
    if pts[0][1] >= level:
        return None
    for (t0, p0), (t1, p1) in pairwise(pts):
        if p0 < level <= p1:
            f = (level - p0) / (p1 - p0)
            return float(np.exp(np.log(t0) + f * (np.log(t1) - np.log(t0))))
    return None


def psnr_at_time(rows: list[dict], seconds: float) -> float | None:
    """A renderer's PSNR at ``seconds`` CPU s: linear in log(time) between rungs."""
    pts = sorted((r["cpu_s"], r["psnr"]) for r in rows)
    lt = [float(np.log(t)) for t, _ in pts]
    s = float(np.log(seconds))
    if not lt[0] <= s <= lt[-1]:
        return None
    return float(np.interp(s, lt, [p for _, p in pts]))


def quality_benchmark(size: int, ref_spp: int, repeats: int = 2) -> None:
    import warnings

    import mitsuba as mi
    from skimage.metrics import structural_similarity

    from hack_render.geometry import load_default_model
    from hack_render.io.image import to_srgb8
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    mi.set_log_level(mi.LogLevel.Error)
    warnings.simplefilter("ignore")
    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    topo = Topology.from_model(model)
    maps = skin_maps([0.8, -0.6, 0.4])
    cam = cameras.orbit(size, size, 85.0, 20.0, 5.0)

    def scene(spp, sampler, pixel_filter="gaussian"):
        return HeadScene(topo, v, lights.preset("studio"), cam,
                         RenderSettings(size, size, spp, sampler=sampler,
                                        pixel_filter=pixel_filter), maps)

    # each pixel filter against its own reference (the box filter's image is a little
    # sharper, so it is never scored against the Gaussian's)
    refs = {}
    for pf in ("gaussian", "box"):
        t0 = time.process_time()
        ref = scene(ref_spp, "multijitter", pf).render(seed=12345)[..., :3]
        refs[pf] = (ref, to_srgb8(ref, 0.0, "aces"))
        print(f"  reference: {size}^2, {ref_spp} spp multijitter, {pf} pixel filter, "
              f"{time.process_time() - t0:.0f} CPU s")

    def score(img, pf):
        ref, ref8 = refs[pf]
        mse = float(np.mean((img[..., :3] - ref) ** 2))
        psnr = 10 * np.log10(float(ref.max()) ** 2 / mse)
        ssim = structural_similarity(to_srgb8(img[..., :3], 0.0, "aces"), ref8,
                                     channel_axis=-1)
        return psnr, float(ssim)

    rows = {}
    for sampler, spps, denoise, pf in (
            ("independent", (16, 32, 64, 128, 256, 512), False, "gaussian"),
            ("multijitter", (16, 32, 64, 128, 256), False, "gaussian"),
            ("multijitter", (4, 8, 16, 32), True, "gaussian"),
            ("multijitter", (4, 8, 16, 32), True, "box")):
        for spp in spps:
            head = scene(spp, sampler, pf)
            head.render(seed=0, denoise=denoise)  # compile
            cpu, res = [], []
            for r in range(repeats):
                t0 = time.process_time()
                img = head.render(seed=1 + r, denoise=denoise)
                cpu.append(time.process_time() - t0)
                res.append(score(img, pf))
            psnr, ssim = np.mean(res, axis=0)
            name = (f"{sampler} {head.settings.effective_spp} spp" + (" + OIDN" if denoise else "")
                    + (" (box filter)" if pf == "box" else ""))
            rows[name] = (statistics.median(cpu), psnr, ssim, sampler, denoise,
                          head.settings.effective_spp)
            print(f"  {name:32s} {rows[name][0]:6.2f} CPU s  PSNR {psnr:5.2f} dB  "
                  f"SSIM {ssim:.4f}")
    ind = sorted((r[5], r[0], r[1]) for r in rows.values() if r[3] == "independent")
    spp_i, cpu_i, psnr_i = (np.array(x, float) for x in zip(*ind))

    def independent_at(psnr):
        """(spp, CPU s) of the independent sampler at this PSNR (log-log interpolation;
        extrapolated past its last point along its last segment)."""
        k = np.clip(np.searchsorted(psnr_i, psnr) - 1, 0, len(psnr_i) - 2)
        f = (psnr - psnr_i[k]) / (psnr_i[k + 1] - psnr_i[k])
        spp = np.exp(np.log(spp_i[k]) + f * (np.log(spp_i[k + 1]) - np.log(spp_i[k])))
        cpu = np.exp(np.log(cpu_i[k]) + f * (np.log(cpu_i[k + 1]) - np.log(cpu_i[k])))
        return spp, cpu

    for name, (cpu, psnr, _ssim, sampler, denoise, _spp) in rows.items():
        if sampler == "multijitter" and (denoise or _spp in (16, 32)):
            spp_eq, cpu_eq = independent_at(psnr)
            print(f"(c) {name}: {cpu:.2f} CPU s for {psnr:.2f} dB; the independent sampler "
                  f"needs ~{spp_eq:.0f} spp, ~{cpu_eq:.2f} CPU s: {cpu / cpu_eq:.2f}x the time "
                  "at equal PSNR")
def sss_benchmark(size: int = 96, spp: int = 16, max_depth: int = 512) -> None:
    import mitsuba as mi

    from appearance.skin_optics import (
        WAVELENGTHS,
        dermis_absorption,
        reduced_scattering,
        skin_albedo,
    )
    from hack_render.io.image import write_png
    from hack_render.render import emitters, materials
    from scenes import cameras, lights

    wl = np.array([610.0, 550.0, 465.0])
    mu_a = dermis_absorption(0.05, wl) * 1e3  # 1/mm -> 1/m
    mu_s = reduced_scattering(wl)[1] * 1e3  # dermis, reduced (isotropic phase)
    albedo_rgb = skin_albedo(0.05, 0.05, 0.7).tolist()
    print(f"  medium: sigma_a {np.round(mu_a, 1).tolist()} 1/m, sigma_s' "
          f"{np.round(mu_s, 0).tolist()} 1/m (mean free path {1e3 / mu_s.mean():.2f} mm); "
          f"hack_skin albedo {np.round(albedo_rgb, 3).tolist()} ({len(WAVELENGTHS)}-band model)")
    cam = cameras.look_at(np.array([0.0, 0.0, 0.6]), np.zeros(3))
    K = cameras.intrinsics(size, size, 85.0)
    camera = cameras.Camera(K, cam[0], cam[1], size, size, "sss")
    rig = lights.preset("studio")
    sphere = {"type": "sphere", "radius": 0.09}
    maps = materials.SkinMaps.constant(4, albedo=albedo_rgb)
    sss = dict(sphere, bsdf={"type": "roughdielectric", "alpha": 0.3, "int_ior": 1.4},
               interior={"type": "homogeneous", "albedo": {"type": "rgb", "value": (
                   mu_s / (mu_s + mu_a)).tolist()}, "sigma_t": {"type": "rgb", "value": (
                       (mu_s + mu_a) / (mu_s + mu_a).max()).tolist()},
                   "scale": float((mu_s + mu_a).max())})
    surf = dict(sphere, bsdf=materials.skin_bsdf(maps, jit=True))
    results = {}
    for name, shape, integ in (("hack_skin (path, depth 8)", surf,
                                {"type": "path", "max_depth": 8, "hide_emitters": True}),
                               (f"volpath SSS (depth {max_depth})", sss,
                                {"type": "volpath", "max_depth": max_depth,
                                 "rr_depth": max_depth, "hide_emitters": True})):
        d = {"type": "scene", "integrator": integ, "head": shape,
             "sensor": emitters.sensor_dict(camera, spp, sampler="multijitter")}
        d.update(emitters.emitter_dicts(rig, None))
        scene = mi.load_dict(d)
        np.asarray(mi.render(scene, seed=0))
        t0 = time.process_time()
        img = np.asarray(mi.render(scene, seed=1))
        results[name] = (time.process_time() - t0, img)
        print(f"  {name:28s} {results[name][0]:7.2f} CPU s, mean radiance "
              f"{np.round(img[..., :3][img[..., 3] > 0.99].mean(0), 3).tolist()}")
        write_png(f"/tmp/sss_{name.split()[0]}.png", img[..., :3])
    (a, _), (b, _) = results.values()
    print(f"(e) {size}^2 {spp} spp: volumetric SSS / hack_skin = {b / a:.0f}x the CPU time")


def sss_screen_benchmark(size: int = 256, spp: int = 32, ref_spp: int = 1024,
                         still: str | None = "docs/images/sss_side_by_side.png") -> None:
    """(e2) The screen-space subsurface scattering of final renders (``render(sss=True)``,
    hack_render/render/sss.py) on the default head, three-quarter view, window light:
    CPU seconds against the plain render at the same spp (denoiser off and on); each
    image's PSNR against its own high-spp reference; how well the parts add up
    (unscattered, against a plain render, per pixel class: the one-pass skin split and
    the two lobe-weighted passes); a side-by-side still at 768 px."""
    from hack_render.geometry import load_default_model
    from hack_render.io.image import to_srgb8
    from hack_render.render import sss
    from hack_render.render.footprint import sss_features
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    topo, maps = Topology.from_model(model), skin_maps([0.8, -0.6, 0.4])

    def scene(res, n):
        cam = cameras.preset("three_quarter", res, res, 85.0)[0]
        return HeadScene(topo, v, lights.preset("window"), cam, RenderSettings(res, res, n),
                         maps)

    head = scene(size, spp)
    refs = {}
    for flag in (False, True):
        head.settings = RenderSettings(size, size, ref_spp)
        refs[flag] = head.render(seed=99, backdrop=False, sss=flag)
        head.settings = RenderSettings(size, size, spp)
    mask = refs[False][..., 3] > 0.5

    def psnr(img, ref):
        err = float(((img[..., :3] - ref[..., :3]) ** 2)[mask].mean())
        return 10.0 * np.log10(1.0 / err)

    print(f"(e2) screen-space SSS, {size}^2 three-quarter, window light, "
          f"{head.settings.effective_spp} spp ({head.settings.mitsuba_sampler}; each image "
          f"against its own {ref_spp}-spp reference):")
    for flag in (False, True):
        head.render(seed=0, backdrop=False, sss=flag)  # compile
        for den in (False, True):
            cpu, img = [], None
            for rep in range(3):
                t0 = time.process_time()
                img = head.render(seed=1 + rep, backdrop=False, sss=flag, denoise=den)
                cpu.append(time.process_time() - t0)
            print(f"  {'sss' if flag else 'plain':5s} {'+ OIDN' if den else '      '} "
                  f"{statistics.median(cpu):5.2f} CPU s (median of 3)  "
                  f"PSNR {psnr(img, refs[flag]):5.2f} dB")
    # the parts add up, unscattered, against a plain render: hack_path's one-pass skin
    # split (what render(sss=True) uses), and the two lobe-weighted passes of the other
    # integrators
    one = head.render(seed=5, backdrop=False)
    split = head.render_passes(5, False, integrator=sss.split_integrator(head))
    d, s = sss.lobe_passes(head, seed=5)
    f = sss_features(head, head.skin_bsdf, head.see_through_cards)
    focal = float(head.camera.K[0, 0])
    m, cover = f["skin"], one[..., 3] > 0.99
    for label, rgb in (
            ("one pass, skin split", sss.combine_split(split[..., :3], split[..., 4:7], f,
                                                       focal, scale=0.0)),
            ("two lobe passes", sss.combine(d[..., :3], s[..., :3], f, focal, scale=0.0))):
        for name, sel in (("skin", m > 0.99), ("other materials", (m < 0.01) & cover),
                          ("mixed (lashes over skin)", (m >= 0.01) & (m <= 0.99) & cover)):
            ratio = rgb[sel].sum() / one[..., :3][sel].sum()
            print(f"  {label}, unscattered / plain render, {name:25s} {ratio:.4f} "
                  f"({int(sel.sum())} px)")
    print(f"  profile mean radius (mm, R G B): "
          f"{np.round(sss.SKIN.mean_radius_mm(), 3).tolist()} ({sss.SKIN.source})")
    if still:
        import imageio.v3 as iio

        big = scene(768, 64)
        a = big.render(seed=3, denoise=True)
        b = big.render(seed=3, denoise=True, sss=True)
        crop = (slice(150, 630), slice(170, 650))
        iio.imwrite(still, np.concatenate([to_srgb8(a[crop][..., :3], 0.0, "aces"),
                                           to_srgb8(b[crop][..., :3], 0.0, "aces")], 1))
        print(f"  wrote {still} (left: plain, right: sss; 768 px, 64 spp + OIDN, cropped)")


def integrator_benchmark(ladder=(4, 8, 16, 32, 64, 128), ref_spp: int = 1024,
                         repeats: int = 2) -> dict:
    """(h) hack_path and volpath against path, and hack_path against volpath
    (``RenderSettings.integrator``) on (a) the README's still
    (alpha 0.8,-0.6,0.4, AU12 0.5, head rotation 5,-20,0, three-quarter camera, studio) at
    256 px and (b) a close-up of the left eye at 192 px: each rung's PSNR (linear RGB,
    peak 1) over the subject (reference alpha > 0.5) and over the eyes (sclera, iris and
    lash pixels, dilated 3 px) against a ``ref_spp`` reference of the same integrator;
    CPU seconds (process time) of ``render``, median of ``repeats`` seeds; CPU time each
    needs for the other's PSNR at each rung (log(time) interpolated)."""
    from scipy.ndimage import binary_dilation

    from hack_render.geometry.limits import LimitPolicy
    from hack_render.geometry.loading import posed_model
    from hack_render.render.parts import REGIONS, Topology
    from hack_render.render.scene import INTEGRATORS, HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    model, _, v = posed_model(None, None, "AU12=0.5", "5,-20,0", None, None,
                              LimitPolicy("warn"), None)
    topo, maps = Topology.from_model(model), skin_maps([0.8, -0.6, 0.4])
    R, t = cameras.look_at([0.036, 0.040, 0.200], [0.034, 0.033, 0.092])
    views = {"head 256 px": cameras.preset("three_quarter", 256, 256)[0],
             "eye close-up 192 px": cameras.Camera(cameras.intrinsics(192, 192, 90.0), R, t,
                                                   192, 192, "eye")}
    with torch.no_grad():  # the close-up: the head at rest, looking ahead
        v_rest = model().vertices[0].numpy()
    result, printed = {}, []

    def say(text: str) -> None:  # printed, and kept for the result file
        printed.append(text)
        print(text, flush=True)

    for view, cam in views.items():
        verts = v if view.startswith("head") else v_rest
        say(f"  {view} (each integrator against its own {ref_spp}-spp reference):")
        rows = {}
        for name in INTEGRATORS:
            def scene(spp, name=name, cam=cam, verts=verts):
                return HeadScene(topo, verts, lights.preset("studio"), cam,
                                 RenderSettings(cam.width, cam.height, spp, integrator=name),
                                 maps)
            ref_head = scene(ref_spp)
            ref = ref_head.render(seed=99, backdrop=False)
            reg = ref_head.region_hits(see_through=())["region"]
            eye = binary_dilation(np.isin(reg, [REGIONS.index(r) for r in
                                                ("sclera", "iris", "eyelashes")]), iterations=3)
            masks = {"psnr": ref[..., 3] > 0.5, "psnr_eye": eye}
            rows[name] = []
            for spp in ladder:
                head = scene(spp)
                head.render(seed=0, backdrop=False)  # compile
                cpu, scores = [], []
                for r in range(repeats):
                    t0 = time.process_time()
                    img = head.render(seed=1 + r, backdrop=False)
                    cpu.append(time.process_time() - t0)
                    err = (img[..., :3] - ref[..., :3]) ** 2
                    scores.append([10 * np.log10(1.0 / float(err[m].mean()))
                                   for m in masks.values()])
                row = {"spp": spp, "cpu_s": statistics.median(cpu),
                       **dict(zip(masks, np.mean(scores, axis=0).tolist()))}
                rows[name].append(row)
                say(f"    {name:9s} {spp:4d} spp {row['cpu_s']:6.2f} CPU s  PSNR subject "
                      f"{row['psnr']:5.2f} dB, eyes {row['psnr_eye']:5.2f} dB")
        ratio = {}
        for name in INTEGRATORS[:-1] if INTEGRATORS[-1] == "path" else ():
            ratio[name] = statistics.median(b["cpu_s"] / a["cpu_s"]
                                            for a, b in zip(rows["path"], rows[name]))
            say(f"    CPU time {name} / path at equal spp: {ratio[name]:.2f} (median over "
                "rungs)")
        # equal PSNR, either way round: each see-through integrator against path, and
        # hack_path against volpath
        for key in ("psnr", "psnr_eye"):
            for x, y in (("path", "volpath"), ("path", "hack_path"),
                         ("volpath", "hack_path")):
                for src, dst in ((x, y), (y, x)):
                    for a in rows[src]:
                        tv = time_at_psnr([{"cpu_s": r["cpu_s"], "psnr": r[key]}
                                           for r in rows[dst]], a[key])
                        if tv is not None:
                            speed = a["cpu_s"] / tv if src == x else tv / a["cpu_s"]
                            say(f"    {key}: {src} {a['spp']} spp ({a[key]:.2f} dB, "
                                f"{a['cpu_s']:.2f} CPU s) = {dst} in {tv:.2f} CPU s "
                                f"({y} {speed:.2f}x faster than {x})")
        result[view] = {"rows": rows, "cpu_ratio": ratio}
    return {"printed": printed, "views": result}


def samplers_benchmark(ref_spp: int = 2048, repeats: int = 2) -> dict:
    """(i) multijitter against the orthogonal array sampler (see the module docstring)."""
    from hack_render.geometry.limits import LimitPolicy
    from hack_render.geometry.loading import posed_model
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings, composite
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    printed: list[str] = []

    def say(text: str) -> None:
        printed.append(text)
        print(text, flush=True)

    maps = skin_maps([0.8, -0.6, 0.4])
    ladders = {"multijitter": (9, 16, 25, 49, 64, 121, 169, 256),
               "orthogonal": (9, 25, 49, 121, 169)}
    views = {}
    for view, pose, cam in (
            ("portrait (the Cycles still)", (None, None), "portrait"),
            ("three-quarter (README pose)", ("AU12=0.5", "5,-20,0"), "three_quarter")):
        model, _, v = posed_model(None, None, pose[0], pose[1], None, None,
                                  LimitPolicy("warn"), None)
        topo = Topology.from_model(model)
        camera = cameras.preset(cam, 256, 256)[0]

        def scene(spp, sampler, topo=topo, v=v, camera=camera):
            return HeadScene(topo, v.astype(np.float64), lights.preset("studio"), camera,
                             RenderSettings(256, 256, spp, sampler=sampler), maps)

        bg = scene(1, "multijitter").backdrop()
        c0 = time.process_time()
        ref = composite(scene(ref_spp, "multijitter").render(seed=777, backdrop=False),
                        bg)[..., :3]
        say(f"  {view}: reference {ref_spp} multijitter spp, "
            f"{time.process_time() - c0:.0f} CPU s")
        rows: dict[str, list] = {}
        for sampler, ladder in ladders.items():
            rows[sampler] = []
            for spp in ladder:
                head = scene(spp, sampler)
                for seed in (1000, 1001):  # compile, then the opaque seed
                    head.render(seed=seed, backdrop=False)
                cpu, ps = [], []
                for r in range(repeats):
                    t0 = time.process_time()
                    img = head.render(seed=1 + r, backdrop=False)
                    cpu.append(time.process_time() - t0)
                    rgb = composite(img, bg)[..., :3]
                    ps.append(10 * np.log10(1.0 / float(np.mean((rgb - ref) ** 2))))
                row = {"spp": head.settings.effective_spp, "cpu_s": statistics.median(cpu),
                       "psnr": float(np.mean(ps))}
                rows[sampler].append(row)
                say(f"    {sampler:12s} {row['spp']:4d} spp {row['cpu_s']:6.2f} CPU s "
                    f"{row['psnr']:6.2f} dB")
        for o in rows["orthogonal"]:
            tm = time_at_psnr(rows["multijitter"], o["psnr"])
            o["multijitter_cpu_s_at_psnr"] = tm
            if tm is not None:
                say(f"    orthogonal {o['spp']} spp ({o['psnr']:.2f} dB): multijitter needs "
                    f"{tm:.2f} CPU s, {tm / o['cpu_s']:.2f}x the time")
        views[view] = rows
    return {"printed": printed, "ref_spp": ref_spp, "views": views}
