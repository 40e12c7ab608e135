"""Render benchmarks (not tests): ratios measured in one run, printed.

(a) Material cost: one frame of the default head at 512^2, 64 spp, with our ``hack_skin``
    material vs the same mesh (written to OBJ, loaded by Mitsuba's ``obj`` plugin) with a
    plain ``diffuse`` BSDF; same lights, camera, integrator and spp. Target <= 1.5x.
(b) Turntable reuse: frames 2..N of a turntable (vertices and camera updated through
    ``mi.traverse``) vs one fresh render (scene build + first render after flushing
    Dr.Jit's in-memory kernel cache). Target <= 0.5x.
(c) Equal quality (``--only quality``): PSNR (linear) and SSIM (tone-mapped sRGB) of the
    studio portrait against a high-spp reference, for the ``independent`` and
    ``multijitter`` samplers over a range of spp and for multijitter + OIDN denoising;
    CPU seconds per image (process time, all threads: Dr.Jit's and OIDN's). The time the
    independent sampler needs to reach the denoised image's PSNR is interpolated on its
    PSNR-log(spp) curve.

(d) End to end (``--only e2e``): ``hack-render render`` of a 256 px image at 16 spp
    (no denoiser, and the defaults) as a user runs it, CPU seconds of the child process
    (user + system) and wall seconds, medians of 3, and a breakdown of one in-process run
    by phase (CPU seconds), with the pose's cost by NumPy (``geometry/posing.py``, what
    `render` runs) against torch's import, model load and forward in the same run. As on a
    user's machine, Python caches this package's bytecode (the child runs without
    ``PYTHONDONTWRITEBYTECODE``, which some sandboxes set: an editable install's modules
    are then compiled from source on every run, about 0.17 CPU s).

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

(f) Turntable frame cost before and after (``--only frames``): CPU seconds per frame
    (process time, after the first) of the README's turntable settings (256 px, --spp 32,
    studio, look-around + swallow) with the previous renderer (independent sampler,
    single-lobe specular, no bust cap, no denoiser) and the current one (multijitter 35
    spp, dual lobe, bust cap, OIDN), in one run.

(g) Against Blender Cycles (``--only cycles``): the default head as ``hack-render render``
    builds it (``--alpha 0.8,-0.6,0.4``, portrait camera, studio rig, 256 px, depth 8)
    rendered by ``HeadScene.render`` (the default ``auto`` sampler, with and without OIDN) and by Cycles
    (CPU, with and without its OIDN) in a bpy interpreter of its own
    (``bench/cycles_scene.py``; ``--blender-python`` or ``HACK_RENDER_BPY_PYTHON``), on
    the same parts (``obj_io.write_mesh``), normals, skin maps (``texture_io``), camera,
    area lights and environment. Each image is scored against its own renderer's
    high-spp reference (PSNR on linear RGB with peak 1, SSIM on the tone-mapped sRGB
    image), CPU seconds of the render call (process time, all threads), the two renderers
    interleaved rung by rung; time at equal PSNR is interpolated on each renderer's
    PSNR-log(time) curve: both noisy, both denoised, each at its best (noisy or denoised)
    and, as a diagnostic, ours with a box pixel filter + OIDN (against a box-filter
    reference of its own). Writes ``bench/results/render_cycles.json`` (``--out``) and
    ``docs/images/cycles_side_by_side.png``.

(h) Integrators (``--only integrator``): hack_path, volpath and path on the README's still at
    256 px and an eye close-up at 192 px, equal time, each against its own high-spp
    reference (:func:`integrator_benchmark`); ``bench/results/render_integrator.json``.

(i) Samplers (``--only samplers``): multijitter against the orthogonal array sampler (what
    ``auto`` picks near 49, 121, 169, ... spp) on the Cycles comparison's still (portrait)
    and a three-quarter view with the README's pose, 256 px, volpath, depth 8: PSNR over
    the image (linear RGB, peak 1) against a 2,048-spp multijitter reference, CPU seconds
    (median of 2 seeds), and the CPU time multijitter needs for each orthogonal rung's
    PSNR (log-log interpolated); ``bench/results/render_samplers.json``.

(j) Hair (``--only hair``, issue 61): the ``render`` command's defaults (256 px, 49 spp
    asked, auto sampler, hack_path, screen-space SSS, OIDN denoised, box filter) on the
    portrait camera and the studio rig, with a full head of hair (a groom of ``--h-styles``
    at lod 1: >= 50k scalp strands, brows, lashes; posed once, outside the timing) against
    the same render bald: CPU and wall seconds of ``render(sss=True)`` + ``denoise`` (median
    of ``--repeats`` after a warm-up that compiles the kernels; one scene alive at a time:
    per style the hair, the hair as before (4 melanin buckets in every group, no roulette
    on hair) and bald again, each ratio against the mean of the bald runs around it)
    and their ratios (target <= 2.0x); also the groom's growing and the scene's
    building (posing) once; ``bench/results/render_hair.json``. ``--h-quality``: the short
    groom's image before the roulette on hair, with it, and with a budget of one hair event,
    dark brown and blonde, against a 512-spp reference (PSNR and mean over the hair
    pixels, :func:`hair_quality`); ``bench/results/render_hair_quality.json``.

Usage: python bench/bench_render.py [--size 512] [--spp 64] [--frames 8] [--tt-size 256]
       python bench/bench_render.py --only quality [--q-size 128] [--q-ref-spp 4096]
       python bench/bench_render.py --only e2e
       python bench/bench_render.py --only sss
       python bench/bench_render.py --only integrator [--i-ref-spp 1024]
       python bench/bench_render.py --only samplers
       python bench/bench_render.py --only hair [--h-styles short,long] [--repeats 2]
       python bench/bench_render.py --only hair --h-quality
       python bench/bench_render.py --only cycles --blender-python /work/bpy-venv/bin/python
"""

from __future__ import annotations

import argparse
import gc
import os
import resource
import statistics
import tempfile
import time
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from provenance import recorded, write_result  # bench/ is sys.path[0] when run as a script


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timed(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def material_benchmark(size: int, spp: int, repeats: int) -> None:
    import mitsuba as mi

    from hack_render.geometry import load_default_model
    from hack_render.geometry.obj_io import write_mesh
    from hack_render.render import emitters, materials
    from scenes import cameras, lights

    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].numpy()
    cam = cameras.preset("portrait", size, size)[0]
    rig = lights.preset("studio")
    maps = materials.SkinMaps.constant(256)
    with tempfile.TemporaryDirectory() as tmp:
        obj = Path(tmp) / "head.obj"
        write_mesh(obj, v, model.faces.numpy(), model.uvs.numpy(), model.uv_faces.numpy())

        def scene(bsdf: dict):
            d = {"type": "scene", "integrator": {"type": "path", "max_depth": 8},
                 "sensor": emitters.sensor_dict(cam, spp),
                 "head": {"type": "obj", "filename": str(obj), "bsdf": bsdf}}
            d.update(emitters.emitter_dicts(rig, None))
            return mi.load_dict(d)

        diffuse = scene({"type": "diffuse", "reflectance": materials.bitmap(maps.diffuse)})
        skin = scene(materials.skin_bsdf(maps, jit=True))
        results = {}
        for name, sc in (("diffuse", diffuse), ("hack_skin", skin)):
            # np.asarray waits for the (asynchronously launched) kernels to finish
            first = timed(lambda sc=sc: np.asarray(mi.render(sc, seed=0)), 1)[0]
            rest = timed(lambda sc=sc: np.asarray(mi.render(sc, seed=1)), repeats)
            results[name] = statistics.median(rest)
            print(f"  {name:10s} first (compile) {first:6.2f} s, then median of {repeats}: "
                  f"{results[name]:6.2f} s")
    ratio = results["hack_skin"] / results["diffuse"]
    print(f"(a) {size}^2 {spp} spp: hack_skin / diffuse = {ratio:.2f}x (target <= 1.5x); "
          f"peak RSS so far {peak_rss_mib():.0f} MiB")


def cold_fresh_render(size: int, spp: int, frames: int) -> float:
    """A fresh render in a new process with an empty Dr.Jit disk kernel cache (~/.drjit)."""
    import os
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as home:
        env = dict(os.environ, HOME=home)
        out = subprocess.run([sys.executable, __file__, "--cold-only", "--tt-size", str(size),
                              "--tt-spp", str(spp), "--frames", str(frames)], env=env,
                             capture_output=True, text=True, check=True).stdout
    return float(out.split("COLD")[1].split()[0])


def turntable_benchmark(size: int, spp: int, frames: int, cold_only: bool = False) -> None:
    import drjit as dr

    from hack_render.geometry import load_default_model
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render import turntable as tt
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes import cameras, lights

    model = load_default_model()
    topo = Topology.from_model(model)

    def verts(i):
        ang = torch.deg2rad(torch.tensor(tt.head_angles_deg(i / frames)))
        with torch.no_grad():
            return model(theta=distribute_head_rotation(ang.float())[None],
                         tau=torch.tensor([tt.swallow_tau(i / frames)])).vertices[0].numpy()

    def cam(i):
        return cameras.orbit(size, size, 85.0, 360.0 * i / frames, 5.0)

    settings = RenderSettings(size, size, spp)
    dr.flush_kernel_cache()
    t0 = time.perf_counter()
    head = HeadScene(topo, verts(0), lights.preset("studio"), cam(0), settings)
    head.render(seed=0)
    fresh = time.perf_counter() - t0
    if cold_only:
        print(f"COLD {fresh:.4f}")
        return
    times = []
    for i in range(1, frames):
        t0 = time.perf_counter()
        head.set_vertices(verts(i))
        head.set_camera(cam(i))
        head.render(seed=i)
        times.append(time.perf_counter() - t0)
    later = statistics.mean(times)
    print(f"  fresh render (build + first frame): {fresh:.2f} s; frames 2..{frames}: "
          f"mean {later:.2f} s, max {max(times):.2f} s")
    cold = cold_fresh_render(size, spp, frames)
    print(f"  fresh render in a new process with an empty kernel cache: {cold:.2f} s")
    print(f"(b) {size}^2 {spp} spp: later frame / fresh render = {later / fresh:.2f}x with "
          f"warm disk kernel cache, {later / cold:.2f}x vs a cold start (target <= 0.5x); "
          f"peak RSS {peak_rss_mib():.0f} MiB")


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


E2E_PHASES = """
import time, sys
t = [time.process_time()]
def lap(): t.append(time.process_time())
import mitsuba, drjit; lap()
from hack_render.render.engine import ensure_variant; ensure_variant(); lap()
from hack_render.geometry import default_model_path
from hack_render.geometry.posing import PosingModel
from hack_render.render.parts import Topology
m = PosingModel.from_file(default_model_path())
v = m.vertices(theta=[[0.0, 0.01, 0.0]] * 8).astype("float64")
topo = Topology.from_model(m); lap()
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights
cam = cameras.preset("portrait", 256, 256)[0]
head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(256, 256, 16)); lap()
img = head.render(); lap()
from hack_render.io.image import write_png
write_png(sys.argv[1], img[..., :3]); lap()
# what the pose cost before geometry/posing.py: torch's import, its model and forward
import torch; lap()
from hack_render.geometry import load_default_model
tm = load_default_model()
with torch.no_grad(): tv = tm(theta=torch.tensor([[[0.0, 0.01, 0.0]] * 8])).vertices[0]
lap()
names = ["import mitsuba + drjit", "variant + plugins",
         "model map + pose (NumPy, geometry/posing.py)", "scene build",
         "render 16 spp (kernels from disk cache)", "tone map + PNG write",
         "for comparison: import torch", "for comparison: torch model load + forward"]
for n, a, b in zip(names, t, t[1:]):
    print(f"    {n:48s} {b - a:5.2f} CPU s")
pose_np = t[3] - t[2]
pose_torch = t[8] - t[6]
print(f"    posing: NumPy / torch (import, load, forward) = {pose_np:.2f} / {pose_torch:.2f} "
      f"CPU s = {pose_np / pose_torch:.2f}x; max vertex difference "
      f"{abs(tv.double().numpy() - v).max():.1e} m")
"""


def e2e_benchmark(repeats: int = 3) -> None:
    import os
    import subprocess
    import sys

    # a user's Python writes the bytecode cache on the first run and reads it after;
    # PYTHONDONTWRITEBYTECODE (set by some sandboxes) compiles this package's modules
    # from source on every run instead (installed packages ship their bytecode)
    user_env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    with tempfile.TemporaryDirectory() as tmp:
        base = ["hack-render", "render", "-o", f"{tmp}/a.png", "--resolution", "256",
                "--spp", "16"]
        off = ["--denoise", "off"]
        # warm the disk caches (kernels, model file, posed mesh, bytecode)
        subprocess.run(base + off, check=True, capture_output=True, env=user_env)
        subprocess.run(base, check=True, capture_output=True, env=user_env)
        # the default (subsurface scattering) and without; the posed mesh from the disk
        # cache (render/posed_cache.py, warm after the first call) or a new pose each run
        # (a head rotation not rendered before: the model evaluated, its unpacked file
        # mapped from geometry/model_file.py's cache), and a new pose with both caches
        # off (HACK_RENDER_NO_CACHE=1: the model file unpacked from the .npz)
        runs, fresh = 0, (time.time_ns() // 1000) % 10 ** 6 / 10 ** 7  # < 0.1 degree
        # (and the command's defaults as a user runs it: OIDN on, where installed)
        for extra, mode in ((off, "cached"), (off + ["--no-sss"], "cached"), ([], "cached"),
                            (off, "new"), (off + ["--no-sss"], "new"), ([], "new"),
                            (off, "off"), (off + ["--no-sss"], "off")):
            cpu, wall = [], []
            env = dict(user_env, **({"HACK_RENDER_NO_CACHE": "1"} if mode == "off" else {}))
            for _ in range(repeats):
                runs += 1
                # a rotation no earlier run rendered (the posed-mesh cache outlives runs)
                pose = [] if mode == "cached" else \
                    ["--head-rotation", f"0,{runs * 0.37 + fresh:.6f},0"]
                r0, w0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
                subprocess.run(base + extra + pose, check=True, capture_output=True, env=env)
                r1, w1 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
                cpu.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
                wall.append(w1 - w0)
            what = {"cached": "posed mesh cached", "new": "a new pose (model file cached)",
                    "off": "a new pose, caches off"}[mode]
            flags = " ".join(extra) or "the defaults (--denoise auto, SSS)"
            print(f"(d) {' '.join(base[:2])} 256 px, 16 spp, {flags}, "
                  f"{what}: median {statistics.median(cpu):.2f} CPU s (user + system), "
                  f"{statistics.median(wall):.2f} s wall, of {repeats} runs")
        print("  one in-process run by phase (plain render, mesh computed, model file "
              "cached):")
        out = subprocess.run([sys.executable, "-c", E2E_PHASES, f"{tmp}/b.png"], check=True,
                             capture_output=True, text=True, env=user_env)
        print(out.stdout.rstrip())


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


def frame_cost_benchmark(size: int = 256, spp: int = 32, frames: int = 6) -> None:
    from hack_render.geometry import load_default_model
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render import skin_bsdf
    from hack_render.render import turntable as tt
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    model = load_default_model()
    topo = Topology.from_model(model)
    maps = skin_maps([0.8, -0.6, 0.4])

    def verts(i):
        ang = torch.deg2rad(torch.tensor(tt.head_angles_deg(i / 36)))
        with torch.no_grad():
            return model(theta=distribute_head_rotation(ang.float())[None],
                         tau=torch.tensor([tt.swallow_tau(i / 36)])).vertices[0].numpy()

    lobes = (skin_bsdf.LOBE_MIX, skin_bsdf.LOBE_ROUGHNESS)
    for name, sampler, single, cap, denoise, sss in (
            ("before: independent 32 spp, one lobe, no cap", "independent", True, False, False,
             False),
            ("after: multijitter 35 spp, dual lobe, cap", "multijitter", False, True, False,
             False),
            ("after, + OIDN", "multijitter", False, True, True, False),
            ("after, + OIDN + SSS (the default now)", "multijitter", False, True, True, True)):
        skin_bsdf.LOBE_MIX, skin_bsdf.LOBE_ROUGHNESS = (1.0, (1.0, 1.0)) if single else lobes
        head = HeadScene(topo, verts(0), lights.preset("studio"),
                         cameras.orbit(size, size, 85.0, 0.0, 5.0),
                         RenderSettings(size, size, spp, sampler=sampler), maps,
                         bust_cap=cap)
        cpu = []
        for i in range(frames):
            t0 = time.process_time()
            head.set_vertices(verts(i), update=False)
            head.set_camera(cameras.orbit(size, size, 85.0, 10.0 * i, 5.0))
            head.render(seed=i, denoise=denoise, sss=sss)
            cpu.append(time.process_time() - t0)
        print(f"(f) {name:48s} {statistics.mean(cpu[1:]):.2f} CPU s per frame "
              f"(mean of frames 2..{frames})")
    skin_bsdf.LOBE_MIX, skin_bsdf.LOBE_ROUGHNESS = lobes


#: Where the Cycles section finds Blender's Python when --blender-python is not given.
BPY_ENV = "HACK_RENDER_BPY_PYTHON"
BPY_HINT = ("python3 -m venv /work/bpy-venv && /work/bpy-venv/bin/pip install 'bpy>=4.2,<5' "
            "(its own environment: bpy pins numpy < 2)")


def blender_python(path: str | None) -> tuple[str, str]:
    """(interpreter, bpy version) of the Python that has bpy; exits 2 with the fix when
    there is none."""
    import os
    import shutil
    import subprocess
    import sys

    cand = path or os.environ.get(BPY_ENV)
    exe = (shutil.which(cand) or (cand if Path(cand).is_file() else None)) if cand else None
    why = (f"--blender-python / ${BPY_ENV}: expected a Python interpreter with bpy, found "
           f"{'nothing set' if not cand else repr(cand) + ' missing'}.")
    if exe:
        try:
            out = subprocess.run([exe, "-c", "import bpy; print(bpy.app.version_string)"],
                                 check=False, capture_output=True, text=True, timeout=300)
            if out.returncode == 0:
                return exe, out.stdout.strip().splitlines()[-1]
            why = (f"--blender-python {exe}: 'import bpy' failed ("
                   f"{(out.stderr.strip().splitlines() or ['no message'])[-1]}).")
        except (OSError, subprocess.TimeoutExpired) as err:
            why = f"--blender-python {exe}: could not run it ({err})."
    print(f"error: {why} Make one: {BPY_HINT}; then pass --blender-python "
          f"/work/bpy-venv/bin/python or set {BPY_ENV}.", file=sys.stderr)
    raise SystemExit(2)


def _cycles_material(d: dict) -> dict:
    """A part's Mitsuba BSDF dict (``materials.fixed_bsdfs``, ``iris_bsdf``) as the few
    numbers the Cycles script builds a Principled (or Diffuse) BSDF from."""
    import math

    opacity = 1.0
    if d["type"] == "mask":
        opacity, d = float(d["opacity"]["value"]), d["bsdf"]
    if d["type"] == "twosided":  # Cycles shades both sides anyway
        d = d["bsdf"]
    if d["type"] == "diffuse":
        return {"kind": "diffuse", "base": list(d["reflectance"]["value"])}
    if d["type"] == "roughplastic":  # diffuse base under a GGX coat: alpha = roughness^2
        return {"kind": "principled", "base": list(d["diffuse_reflectance"]["value"]),
                "roughness": math.sqrt(d["alpha"]), "ior": d["int_ior"], "opacity": opacity}
    if d["type"] == "principled":  # the iris: Mitsuba's specular s is F0 = 0.08 s
        f0 = math.sqrt(0.08 * d["specular"])
        alpha_coat = 0.1 + (0.001 - 0.1) * d["clearcoat_gloss"]  # Disney's coat alpha
        return {"kind": "principled", "vertex_color": "vertex_color",
                "roughness": d["roughness"], "ior": (1 + f0) / (1 - f0),
                "coat": 0.25 * d["clearcoat"],  # Disney weights its coat lobe by 1/4
                "coat_roughness": math.sqrt(alpha_coat), "opacity": opacity}
    raise ValueError(f"no Cycles material for {d['type']!r}")


def write_cycles_scene(folder: Path, head, vertices: np.ndarray, maps) -> Path:
    """The scene of ``head`` (a HeadScene) for ``cycles_scene.py``: every render part as
    an OBJ (``obj_io.write_mesh``) with the renderer's normals (and iris colours) beside
    it, the skin maps as a texture set, and camera, lights and environment in
    ``scene.json`` (Blender world matrices: no axis conversion, Y stays up)."""
    import json

    from appearance.texture_io import write_texture_set
    from hack_render.geometry.obj_io import write_mesh
    from hack_render.io.image import rgb_channels, write_exr
    from hack_render.render import emitters, materials, skin_bsdf
    from hack_render.render.parts import vertex_normals

    rig, cam, settings = head.lights, head.camera, head.settings
    if rig.env_map is not None or rig.env_file is not None:
        raise SystemExit("cycles: only rigs with a constant environment (or none) are built")
    v = np.asarray(vertices, np.float64)
    normals = vertex_normals(v, head.topology.faces)
    fixed = materials.fixed_bsdfs()
    parts = []
    for part in head.parts:
        uv = part.texcoords.astype(np.float64).copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # Mitsuba's bitmaps take v down, Blender's up
        write_mesh(folder / f"{part.name}.obj", part.positions(v), part.faces, uv, part.faces)
        extra = {"positions": part.positions(v), "normals": normals[part.gather]}
        if part.name.startswith("skin"):
            spec = {"kind": "skin"}
        elif part.name == "iris":
            spec = _cycles_material(materials.iris_bsdf())
            extra["colors"] = materials.iris_vertex_colors(v[part.gather], head.eye_axes)
        else:
            spec = _cycles_material(fixed[part.name])
            if part.name == "eyelashes" and head.lash_opacity is not None:
                # the strand texture the mask BSDF reads, in the same (Mitsuba) rows as
                # the skin maps, so the flipped v reads it as Mitsuba does
                a = np.repeat(np.asarray(head.lash_opacity, np.float32)[..., None], 3, -1)
                write_exr(folder / "lash_opacity.exr", rgb_channels(a))
                spec["opacity_map"] = "lash_opacity.exr"
        np.savez(folder / f"{part.name}.npz", **extra)
        parts.append({"name": part.name, "obj": f"{part.name}.obj", "extra": f"{part.name}.npz",
                      "flat": bool(part.flat), "material": spec})
    tex = {"diffuse": maps.diffuse, "specular": maps.specular, "roughness": maps.roughness}
    if maps.normal is not None:
        tex["normal"] = maps.normal
    write_texture_set(folder / "skin", tex)
    lights = []
    for light in rig.area:
        m = emitters.area_light_transform(light, rig.rotation_deg)  # [-1, 1]^2, faces +Z
        a, b, c = m[:3, 0], m[:3, 1], m[:3, 2]
        world = np.eye(4)  # Blender's area light: centred, size along x / y, emits along -Z
        world[:3, :3] = np.stack([a / np.linalg.norm(a), -b / np.linalg.norm(b),
                                  -c / np.linalg.norm(c)], axis=1)
        world[:3, 3] = m[:3, 3]
        lights.append({"matrix": world.tolist(),
                       "size": [2 * float(np.linalg.norm(a)), 2 * float(np.linalg.norm(b))],
                       "radiance": [float(x) * rig.scale for x in light.radiance]})
    cam_world = np.eye(4)  # OpenCV (x right, y down, z forward) -> Blender (x right, y up)
    cam_world[:3, :3] = cam.R.T @ np.diag([1.0, -1.0, -1.0])
    cam_world[:3, 3] = cam.center
    desc = {"width": settings.width, "height": settings.height,
            "max_depth": settings.max_depth,
            # Cycles' Gaussian of width w has sigma w / 4: 2 px matches Mitsuba's
            # gaussian (sigma 0.5 px)
            "filter_width": 2.0, "denoise_quality": "BALANCED",  # as render/denoise.py
            "camera": {"matrix": cam_world.tolist(), "fov_x_deg": cam.fov_x_deg},
            "lights": lights,
            "environment": None if rig.env_constant is None else
            [float(x) * rig.scale for x in rig.env_constant],
            "skin": {"ior": 1.4, "lobe_roughness": list(skin_bsdf.LOBE_ROUGHNESS),
                     "lobe_mix": skin_bsdf.LOBE_MIX},
            "textures": {k: f"skin/{k}.exr" for k in tex}, "parts": parts}
    path = folder / "scene.json"
    path.write_text(json.dumps(desc, indent=1))
    return path


class CyclesWorker:
    """``cycles_scene.py`` in Blender's Python, kept running: one render per request."""

    def __init__(self, python: str, scene_dir: Path, log: Path):
        import os
        import subprocess

        read, write = os.pipe()
        self.log = log
        with open(log, "w") as out:
            self.proc = subprocess.Popen(
                [python, str(Path(__file__).with_name("cycles_scene.py")), str(scene_dir),
                 str(write)], stdin=subprocess.PIPE, stdout=out, stderr=subprocess.STDOUT,
                text=True, pass_fds=(write,))
        os.close(write)
        self.replies = os.fdopen(read)
        self.ready = self._reply()

    def _reply(self) -> dict:
        import json

        line = self.replies.readline()
        if not line:
            tail = "\n".join(self.log.read_text().splitlines()[-15:])
            raise SystemExit(f"cycles: Blender's Python stopped (rc {self.proc.wait()}):\n{tail}")
        return json.loads(line)

    def render(self, spp: int, seed: int, denoise: bool, out: Path) -> tuple[dict, np.ndarray]:
        import json

        from hack_render.io.image import read_exr

        self.proc.stdin.write(json.dumps({"spp": spp, "seed": seed, "denoise": denoise,
                                          "out": str(out)}) + "\n")
        self.proc.stdin.flush()
        reply = self._reply()
        ch = read_exr(out)
        return reply, np.stack([ch[c] for c in "RGBA"], axis=-1)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


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


def side_by_side(path: Path, panels: list[list[tuple[np.ndarray, str]]]) -> None:
    """A grid of tone-mapped (sRGB 8-bit) panels, a caption under each."""
    from PIL import Image, ImageDraw

    h, w = panels[0][0][0].shape[:2]
    cap = 30
    grid = Image.new("RGB", (w * len(panels[0]), (h + cap) * len(panels)), (255, 255, 255))
    draw = ImageDraw.Draw(grid)
    for i, row in enumerate(panels):
        for j, (img, text) in enumerate(row):
            grid.paste(Image.fromarray(img), (j * w, i * (h + cap)))
            for k, line in enumerate(text.split("\n")[:2]):
                draw.text((j * w + 4, i * (h + cap) + h + 2 + 13 * k), line, fill=(0, 0, 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    grid.save(tmp)
    tmp.replace(path)


def compare_curves(o: list[dict], c: list[dict], say) -> dict:
    """Time at equal PSNR (every whole dB both ladders span) and PSNR at equal time (half
    octaves of CPU seconds both span) of two ladders, ``o`` ours and ``c`` Cycles'."""
    lo = max(min(r["psnr"] for r in o), min(r["psnr"] for r in c))
    hi = min(max(r["psnr"] for r in o), max(r["psnr"] for r in c))
    eq = []
    for level in np.arange(np.ceil(lo), np.floor(hi) + 1e-9, 1.0):
        to, tc = time_at_psnr(o, level), time_at_psnr(c, level)
        if to and tc:
            eq.append({"psnr": float(level), "ours_cpu_s": to, "cycles_cpu_s": tc,
                       "ratio": to / tc})
    et = []
    for t in 2.0 ** (np.arange(-6, 13) / 2.0):
        po, pc = psnr_at_time(o, t), psnr_at_time(c, t)
        if po is not None and pc is not None:
            et.append({"cpu_s": float(t), "ours_psnr": po, "cycles_psnr": pc})
    out: dict = {"equal_psnr": eq, "equal_time": et}
    say("  time at equal PSNR (ours / Cycles, CPU s; target <= 0.5x):")
    for e in eq:
        say(f"    {e['psnr']:5.1f} dB: {e['ours_cpu_s']:6.2f} / {e['cycles_cpu_s']:6.2f} "
            f"= {e['ratio']:.2f}x")
    if eq:
        out["ratio_geomean"] = float(np.exp(np.mean([np.log(e["ratio"]) for e in eq])))
        out["ratio_range"] = [min(e["ratio"] for e in eq), max(e["ratio"] for e in eq)]
        say(f"    geometric mean {out['ratio_geomean']:.2f}x (range {out['ratio_range'][0]:.2f}"
            f"-{out['ratio_range'][1]:.2f}x) over {eq[0]['psnr']:.0f}-{eq[-1]['psnr']:.0f} dB")
    else:
        say("    the two ladders share no PSNR range")
    say("  PSNR at equal time (ours / Cycles, dB):")
    for e in et:
        say(f"    {e['cpu_s']:6.2f} CPU s: {e['ours_psnr']:6.2f} / {e['cycles_psnr']:6.2f} "
            f"({e['ours_psnr'] - e['cycles_psnr']:+.2f} dB)")
    return out


def lower_envelope(*ladders: list[dict]) -> list[dict]:
    """The rungs of several ladders that no cheaper rung beats in PSNR (each renderer's
    best setting at every time: noisy or denoised, whichever wins there)."""
    out, best = [], -np.inf
    for r in sorted((r for lad in ladders for r in lad), key=lambda r: r["cpu_s"]):
        if r["psnr"] > best:
            out.append(r)
            best = r["psnr"]
    return out


def transcript() -> tuple:
    """(say, printed): ``say(text)`` prints ``text`` at once and keeps its lines in the list
    ``printed``, for the result file."""
    printed: list[str] = []

    def say(text: str) -> None:
        print(text, flush=True)
        printed.extend(text.splitlines())

    return say, printed


def cycles_comparison_scene(size: int) -> SimpleNamespace:
    """The scene of both Cycles comparisons (``--only cycles``, bench_hair_cycles.py):
    ``hack-render render --alpha 0.8,-0.6,0.4 --resolution SIZE``, the default head at
    rest (portrait camera, studio rig, depth 8). Returns ``model``, ``v`` (V, 3) float64
    posed vertices (metres), ``topo``, skin ``maps``, light ``rig`` and ``cam``; Mitsuba's
    log and Python's warnings are quietened (the ladders print tables)."""
    import warnings

    import mitsuba as mi

    from hack_render.geometry.limits import LimitPolicy
    from hack_render.geometry.loading import posed_model
    from hack_render.render.parts import Topology
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    mi.set_log_level(mi.LogLevel.Error)
    warnings.simplefilter("ignore")
    model, _, verts = posed_model(None, None, None, None, None, None, LimitPolicy("warn"),
                                  None)
    return SimpleNamespace(model=model, v=verts.astype(np.float64),
                           topo=Topology.from_model(model), maps=skin_maps([0.8, -0.6, 0.4]),
                           rig=lights.preset("studio"),
                           cam=cameras.preset("portrait", size, size)[0])


def start_cycles(bpy_python: str, scene_dir: Path, say) -> CyclesWorker:
    """A :class:`CyclesWorker` on the scene written to ``scene_dir``; says what its start
    cost."""
    t0 = time.perf_counter()
    worker = CyclesWorker(bpy_python, scene_dir, scene_dir / "cycles.log")
    say(f"Cycles scene built in {time.perf_counter() - t0:.1f} s wall "
        f"({worker.ready['build_cpu_s']:.1f} CPU s import + sync; warm-up 1 spp "
        f"{worker.ready['warmup_cpu_s']:.2f} CPU s)")
    return worker


def timed_render(name: str, head, worker: CyclesWorker, spp: int, seed: int, denoise: bool,
                 out: Path) -> tuple[np.ndarray, float, float, int]:
    """One render of a ladder's rung: Cycles' (``name == "cycles"``: ``worker`` renders
    into ``out``, and reports its times) or ours (``head``, a ``HeadScene`` built and
    compiled beforehand). Returns (the (H, W, 4) linear RGBA image, CPU seconds (process
    time, all threads), wall seconds, the effective spp)."""
    if name == "cycles":
        rep, img = worker.render(spp, seed, denoise, out)
        return img, rep["cpu_s"], rep["wall_s"], rep["spp"]
    c0, w0 = time.process_time(), time.perf_counter()
    img = head.render(seed=seed, backdrop=False, denoise=denoise)
    return img, time.process_time() - c0, time.perf_counter() - w0, head.settings.effective_spp


def rung_row(name: str, head, worker: CyclesWorker, spp: int, denoise: bool, repeats: int,
             out: Path, score) -> tuple[dict, np.ndarray]:
    """A ladder's rung: ``repeats`` renders (seeds 1, 2, ...) by :func:`timed_render`,
    each scored by ``score(image) -> {name: value}``. Returns the row (renderer, denoise,
    effective spp, median CPU and wall seconds, each render's CPU seconds, each score's
    mean over the renders) and the last (H, W, 4) image."""
    cpu, wall, scores = [], [], []
    for r in range(repeats):
        img, c, w, eff = timed_render(name, head, worker, spp, 1 + r, denoise, out)
        cpu.append(c)
        wall.append(w)
        scores.append(score(img))
    row = {"renderer": name, "denoise": denoise, "spp": eff,
           "cpu_s": statistics.median(cpu), "cpu_each_s": cpu,
           "wall_s": statistics.median(wall)}
    row.update({k: float(np.mean([sc[k] for sc in scores])) for k in scores[0]})
    return row, img


def cycles_benchmark(bpy_python: str, bpy_version: str, size: int, ladder, dn_ladder,
                     ref_spp: int, repeats: int, still: Path | None,
                     out: str | None) -> None:
    import os

    from skimage.metrics import structural_similarity

    from hack_render.io.image import to_srgb8
    from hack_render.render.scene import HeadScene, RenderSettings, composite

    say, printed = transcript()
    # hack-render render --alpha 0.8,-0.6,0.4 --resolution SIZE (portrait, studio, depth 8)
    sc = cycles_comparison_scene(size)
    v, topo, maps, rig, cam = sc.v, sc.topo, sc.maps, sc.rig, sc.cam
    # "ours_box": a diagnostic, our renderer with a box pixel filter (each sample in one
    # pixel, as Cycles' filter importance sampling), denoised, against its own reference
    filters = {"ours": "gaussian", "ours_box": "box"}

    def ours(spp: int, name: str = "ours") -> HeadScene:
        return HeadScene(topo, v, rig, cam, RenderSettings(size, size, spp,
                                                           pixel_filter=filters[name]), maps)

    # ours: the default integrator (volpath: shadow rays pass the lash cards' transparent
    # parts, as Cycles' transparent shadows do)
    say(f"scene: default head, alpha 0.8,-0.6,0.4, portrait, studio, {size} px, depth 8, "
        f"ours {RenderSettings().integrator}; "
        f"{os.cpu_count()} CPUs; Cycles {bpy_version} (CPU) in {bpy_python}")
    rows: list[dict] = []
    images: dict[tuple, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        head = ours(1)
        bg = head.backdrop()
        write_cycles_scene(tmp, head, v, maps)
        worker = start_cycles(bpy_python, tmp, say)
        try:
            refs = {}
            for name in ("ours", "cycles", "ours_box"):
                c0 = time.process_time()
                if name == "cycles":
                    rep, img = worker.render(ref_spp, 12345, False, tmp / "ref.exr")
                    cpu, spp = rep["cpu_s"], rep["spp"]
                else:
                    h = ours(ref_spp, name)
                    img = h.render(seed=12345, backdrop=False)
                    cpu, spp = time.process_time() - c0, h.settings.effective_spp
                    del h
                refs[name] = composite(img, bg)[..., :3]
                images[(name, "ref")] = refs[name]
                say(f"reference {name}: {spp} spp, {cpu:.0f} CPU s; mean linear RGB "
                    f"{np.round(refs[name].mean((0, 1)), 4).tolist()}")
            ref8 = {k: to_srgb8(r, 0.0, "aces") for k, r in refs.items()}

            def score(name: str, img: np.ndarray) -> dict[str, float]:
                rgb = composite(img, bg)[..., :3]
                mse = float(np.mean((rgb - refs[name]) ** 2))
                ssim = structural_similarity(to_srgb8(rgb, 0.0, "aces"), ref8[name],
                                             channel_axis=-1)
                return {"psnr": 10.0 * np.log10(1.0 / mse), "ssim": float(ssim)}

            say("renderer  denoise   spp   CPU s  wall s   PSNR dB   SSIM")
            for denoise, spps in ((False, ladder), (True, dn_ladder)):
                for spp in spps:  # interleaved: our rung, then Cycles' rung
                    for name in ("ours", "cycles") + (("ours_box",) if denoise else ()):
                        if name != "cycles":
                            h = ours(spp, name)
                            # Dr.Jit compiles the first render of a scene, and once more
                            # the first with another seed (the seed becomes opaque): both
                            # before timing
                            for seed in (1000, 1001):
                                h.render(seed=seed, backdrop=False, denoise=denoise)
                        row, img = rung_row(name, h, worker, spp, denoise, repeats,
                                            tmp / "img.exr", partial(score, name))
                        eff = row["spp"]
                        images[(name, eff, denoise)] = composite(img, bg)[..., :3]
                        rows.append(row)
                        say(f"{name:9s} {'OIDN' if denoise else '-':7s} {eff:5d} "
                            f"{row['cpu_s']:7.2f} {row['wall_s']:7.2f} {row['psnr']:8.2f} "
                            f"{row['ssim']:7.4f}")
                        h = None
        finally:
            worker.close()

    def ladder_of(name: str, denoise: bool) -> list[dict]:
        return [r for r in rows if r["renderer"] == name and r["denoise"] == denoise]

    summary = {}
    for tag, o, c, what in (
            ("noisy", ladder_of("ours", False), ladder_of("cycles", False),
             "both noisy"),
            ("oidn", ladder_of("ours", True), ladder_of("cycles", True),
             "both denoised by OIDN"),
            ("best", lower_envelope(ladder_of("ours", False), ladder_of("ours", True)),
             lower_envelope(ladder_of("cycles", False), ladder_of("cycles", True)),
             "each at its best, noisy or denoised, at each time"),
            ("oidn_box_diagnostic", ladder_of("ours_box", True), ladder_of("cycles", True),
             ("diagnostic: ours with a box pixel filter + OIDN (against its box-filter "
              "reference) against Cycles + OIDN"))):
        say(f"{tag}: {what}")
        summary[tag] = compare_curves(o, c, say)

    if still is not None:
        def near(name, denoise, seconds):
            return min(ladder_of(name, denoise),
                       key=lambda r: abs(np.log(r["cpu_s"] / seconds)))

        def caption(r):
            return (f"{'ours' if r['renderer'] == 'ours' else 'Cycles'} {r['spp']} spp"
                    f"{' + OIDN' if r['denoise'] else ''}\n{r['cpu_s']:.2f} CPU s, "
                    f"{r['psnr']:.1f} dB")

        panels = [[], []]
        for denoise, cyc_spp in ((False, 16), (True, 16)):
            rc = min(ladder_of("cycles", denoise), key=lambda r: abs(r["spp"] - cyc_spp))
            ro = near("ours", denoise, rc["cpu_s"])
            for i, r in enumerate((ro, rc)):
                panels[i].append((to_srgb8(images[(r["renderer"], r["spp"], denoise)], 0.0,
                                           "aces"), caption(r)))
        for i, name in enumerate(("ours", "cycles")):
            panels[i].append((to_srgb8(images[(name, "ref")], 0.0, "aces"),
                              (f"{'ours' if name == 'ours' else 'Cycles'} reference\n"
                               f"{ref_spp} spp")))
        side_by_side(still, panels)
        say(f"wrote {still}")
    if out:
        write_result(out, {"title": "Rendering: against Blender Cycles, equal noise and time",
                           "settings": {"size": size, "ref_spp": ref_spp, "repeats": repeats,
                                        "ladder": list(ladder), "denoise_ladder": list(dn_ladder),
                                        "bpy": bpy_version},
                           "rows": rows, "summary": summary, "printed": printed})


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


def turntable_ratio_benchmark(size: int, spp: int, frames: int, modes: list[list[str]]) -> None:
    """Issue 65: a later frame of ``hack-render turntable`` against its render call.

    Runs the command in this process (defaults: SSS on, OIDN when installed) with the scene's
    methods timed: per later frame (frames 2..N; the first compiles), the frame's wall time
    (from one frame's camera change to the next's) against the render call
    (``HeadScene.render``, the path tracer with SSS) plus the denoiser (``HeadScene.denoise``:
    OIDN and its albedo/normal passes; the command calls it beside the render), and the
    parts: the camera change with its scene update (the cornea moves the iris for each
    camera: the acceleration structure is rebuilt), the mesh update of animated frames.
    Target: a later frame <= 1.1x its render call.
    """
    from hack_render.cli import main as cli_main
    from hack_render.render import scene as sc

    names = ("render", "denoise", "set_camera", "set_vertices")
    for extra in modes:
        events: list[tuple[str, float, float]] = []
        saved = {n: getattr(sc.HeadScene, n) for n in names}

        def timed(name, orig, sink):
            def run(self, *args, **kwargs):
                t0 = time.perf_counter()
                out = orig(self, *args, **kwargs)
                sink.append((name, t0, time.perf_counter()))
                return out
            return run

        for n in names:
            setattr(sc.HeadScene, n, timed(n, saved[n], events))
        try:
            with tempfile.TemporaryDirectory() as tmp:
                try:
                    cli_main(["turntable", "-o", str(Path(tmp) / "tt"), "--frames", str(frames),
                              "--resolution", str(size), "--spp", str(spp), "--formats",
                              "frames", "--quiet", *extra])
                except SystemExit as err:
                    if err.code:
                        raise
        finally:
            for n, f in saved.items():
                setattr(sc.HeadScene, n, f)
        # a frame: from its camera change (set_vertices first when animated) to the next's
        starts = [t for n, t, _ in events if n == ("set_vertices" if "--look-around" in extra
                                                   else "set_camera")]
        rows = []
        for k in range(1, len(starts) - 1):  # frames 2..N-1: each has a next start
            a, b = starts[k], starts[k + 1]
            part = {n: sum(e - s for m, s, e in events if m == n and a <= s < b) for n in names}
            rows.append({"wall": b - a, **part})
        med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        call = med["render"] + med["denoise"]
        ratios = [r["wall"] / (r["render"] + r["denoise"]) for r in rows]
        print(f"(t) turntable {' '.join(extra) or '(orbit)'}: {size} px, {spp} spp, frames 2..{frames - 1} "
              f"(median s): frame {med['wall']:.3f}; render call {med['render']:.3f} + denoise "
              f"{med['denoise']:.3f} = {call:.3f}; ratio {med['wall'] / call:.2f}x "
              f"[{min(ratios):.2f}..{max(ratios):.2f}] (target <= 1.1x); of the rest: camera "
              f"change + update {med['set_camera']:.3f}, mesh update {med['set_vertices']:.3f}")


def hair_benchmark(size: int = 256, spp: int = 49, styles=("short", "long"),
                   repeats: int = 2) -> None:
    """(j): see the module's notes."""
    from hack_render.geometry import default_model_path
    from hack_render.geometry.posing import PosingModel
    from hack_render.hair.groom import grow
    from hack_render.hair.regions import HeadSurface
    from hack_render.hair.style import HairStyle
    from hack_render.render import hair_shapes
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    posing = PosingModel.from_file(default_model_path())
    v = posing.vertices().astype(np.float64)
    topo, surf = Topology.from_model(posing), HeadSurface.from_model(posing)
    rig = lights.preset("studio")
    cam = cameras.preset("portrait", size, size)[0]
    settings = RenderSettings(size, size, spp, pixel_filter="box")  # the command's, denoised
    maps = skin_maps(None, None, None)

    def measure(groom, before=False) -> tuple[float, float, float]:
        """Build the scene, render once (compiling), then the median CPU and wall seconds
        of ``repeats`` renders + denoise, and the build's seconds; the scene is alone in
        the process (Dr.Jit traces a BSDF call over every BSDF alive, so another scene's
        materials would slow this one). ``before``: as the renderer was before (4 melanin
        buckets in every group, no roulette on hair)."""
        saved = hair_shapes.GROUP_BUCKETS
        if before:
            hair_shapes.GROUP_BUCKETS = {g.name: 4
                                         for g in groom.groups}
        try:
            w0 = time.perf_counter()
            head = HeadScene(topo, v, rig, cam, settings, maps, hair=groom)
            built = time.perf_counter() - w0
        finally:
            hair_shapes.GROUP_BUCKETS = saved
        if before:  # read by the first render(sss=True)
            head.integrator_extra.pop("hair_rr", None)
        head.denoise(head.render(backdrop=False, sss=True))  # compiles the kernels
        cpu, wall = [], []
        for i in range(repeats):
            c0, w0 = time.process_time(), time.perf_counter()
            head.denoise(head.render(seed=i + 1, backdrop=False, sss=True))
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        del head
        gc.collect()
        return statistics.median(cpu), statistics.median(wall), built

    print(f"(j) hair: {size} px, {settings.effective_spp} spp ({settings.sampler_label}), "
          f"{settings.integrator}, SSS, denoised; median of {repeats} after a warm-up, one "
          f"scene at a time, bald before and after each style; load average (1 min) "
          f"{os.getloadavg()[0]:.1f}")
    bald_cpu, bald_wall, bald_build = measure(None)
    print(f"  bald: {bald_cpu:.2f} CPU s, {bald_wall:.2f} s wall (scene {bald_build:.2f} s)")
    for name in styles:
        t0 = time.perf_counter()
        groom = grow(surf, HairStyle.archetype_style(name, lod=1.0))
        grown = time.perf_counter() - t0
        cpu, wall, built = measure(groom)
        cpu0, wall0, _ = measure(groom, before=True)
        b_cpu, b_wall, _ = measure(None)
        bc, bw = (bald_cpu + b_cpu) / 2, (bald_wall + b_wall) / 2  # the bald runs around it
        bald_cpu, bald_wall = b_cpu, b_wall
        counts = ", ".join(f"{g.name} {g.num_strands} x {g.points_per_strand}"
                           for g in groom.groups)
        print(f"  {name} ({counts}): {cpu:.2f} CPU s, {wall:.2f} s wall: "
              f"{cpu / bc:.2f}x CPU, {wall / bw:.2f}x wall the bald render "
              f"({bc:.2f} CPU s, the mean of the bald runs before and after; target <= "
              f"2.0x); as before (4 melanin buckets in every group, no roulette on hair): "
              f"{cpu0:.2f} CPU s, {cpu0 / bc:.2f}x CPU, {wall0 / bw:.2f}x wall; grown in "
              f"{grown:.1f} s, scene built (posed) in {built:.1f} s")
    print(f"  load average (1 min) {os.getloadavg()[0]:.1f} after")


def hair_quality(size: int = 256, spp: int = 49, ref_spp: int = 512,
                 colours=("dark-brown", "blonde")) -> None:
    """(j) ``--h-quality``: the short groom (lod 1) in each colour, rendered as the bench
    renders it (``render(sss=True)`` + denoise) as before (4 melanin buckets in every group,
    no roulette on hair), now, and with a budget of one hair event (``hair_depth`` 1: a path ends at its first
    strand), against a ``ref_spp`` render before it (not denoised): PSNR (linear RGB, peak 1)
    over the pixels whose centre sees hair and the mean there, relative to the reference."""
    from hack_render.geometry import default_model_path
    from hack_render.geometry.posing import PosingModel
    from hack_render.hair.groom import grow
    from hack_render.hair.regions import HeadSurface
    from hack_render.hair.style import HairStyle
    from hack_render.render import hair_shapes
    from hack_render.render.parts import REGIONS, Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    posing = PosingModel.from_file(default_model_path())
    v = posing.vertices().astype(np.float64)
    topo, surf = Topology.from_model(posing), HeadSurface.from_model(posing)
    rig = lights.preset("studio")
    cam = cameras.preset("portrait", size, size)[0]
    maps = skin_maps(None, None, None)
    variants = {"before": {"hair_rr": False},
                "now": {},
                "budget of 1 hair event": {"hair_rr": False, "hair_depth": 1}}

    def head_of(groom, n, extra):
        saved = hair_shapes.GROUP_BUCKETS
        if extra.get("hair_rr") is False:  # as before: 4 buckets in every group
            hair_shapes.GROUP_BUCKETS = {g.name: 4
                                         for g in groom.groups}
        try:
            head = HeadScene(topo, v, rig, cam,
                             RenderSettings(size, size, n, pixel_filter="box"), maps, hair=groom)
        finally:
            hair_shapes.GROUP_BUCKETS = saved
        head.integrator_extra.update(extra)  # read by the first render(sss=True)
        return head

    print(f"(j) hair quality: {size} px, {spp} spp, denoised, against {ref_spp} spp as "
          f"before; load average (1 min) {os.getloadavg()[0]:.1f}")
    for colour in colours:
        groom = grow(surf, HairStyle.archetype_style("short", lod=1.0).with_colour(colour))
        ref_head = head_of(groom, ref_spp, {"hair_rr": False})
        ref = ref_head.render(seed=99, backdrop=False, sss=True)[..., :3]
        hair = ref_head.aovs()["segmentation"] == REGIONS.index("hair")
        del ref_head
        for name, extra in variants.items():
            head = head_of(groom, spp, extra)
            raw = head.render(seed=1, backdrop=False, sss=True)
            den = head.denoise(raw)[..., :3]
            del head

            def psnr(img, hair=hair, ref=ref):
                return 10 * np.log10(1.0 / np.mean((img[hair] - ref[hair]) ** 2))

            print(f"  {colour}, {name}: hair PSNR {psnr(raw[..., :3]):.2f} dB noisy, "
                  f"{psnr(den):.2f} dB denoised; hair mean "
                  f"{den[hair].mean() / ref[hair].mean():.3f}"
                  f"x the reference's ({hair.sum()} hair pixels)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--tt-size", type=int, default=256)
    ap.add_argument("--tt-spp", type=int, default=32)
    ap.add_argument("--tt-hair", default=None, help="--only turntable: the turntable's "
                    "--hair (e.g. short, as the README's command; default: none, bald)")
    ap.add_argument("--variant", default=None)
    ap.add_argument("--cold-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--only", choices=("all", "quality", "e2e", "sss", "frames", "cycles",
                                       "integrator", "samplers", "turntable", "hair"),
                    default="all")
    ap.add_argument("--blender-python", default=None, help="cycles: a Python with bpy "
                    f"(default ${BPY_ENV})")
    ap.add_argument("--c-size", type=int, default=256)
    ap.add_argument("--c-ref-spp", type=int, default=4096)
    ap.add_argument("--c-ladder", default="4,8,16,32,64,128,256")
    ap.add_argument("--c-denoise-ladder", default="4,8,16,32,64")
    ap.add_argument("--c-repeats", type=int, default=2)
    ap.add_argument("--c-still", default="docs/images/cycles_side_by_side.png",
                    help="cycles: the side-by-side still ('' for none)")
    ap.add_argument("--i-ref-spp", type=int, default=1024)
    ap.add_argument("--h-styles", default="short,long", help="hair: archetypes at lod 1")
    ap.add_argument("--h-quality", action="store_true",
                    help="hair: the image against a reference instead of the timings")
    ap.add_argument("--q-size", type=int, default=128)
    ap.add_argument("--q-ref-spp", type=int, default=4096)
    ap.add_argument("--out", default=None, help="also write what it prints, with commit, "
                    "date, machine and command, e.g. bench/results/render.json")
    args = ap.parse_args()
    if args.only == "cycles":  # refused before anything heavy when bpy is missing
        exe, version = blender_python(args.blender_python)
    from hack_render.render.engine import ensure_variant

    variant = ensure_variant(args.variant)
    if args.cold_only:
        turntable_benchmark(args.tt_size, args.tt_spp, args.frames, True)
        return
    if args.only == "frames":
        with recorded(args.out, "Rendering: turntable frame cost before and after"):
            print(f"variant: {variant}")
            frame_cost_benchmark()
        return
    if args.only == "turntable":
        with recorded(args.out, "Rendering: a later turntable frame against its render call "
                      "(issue 65)"):
            print(f"variant: {variant}; load average (1 min) {os.getloadavg()[0]:.1f} before")
            hair = ["--hair", args.tt_hair] if args.tt_hair else []
            turntable_ratio_benchmark(args.tt_size, args.tt_spp, args.frames,
                                      [hair, ["--look-around", "--swallow", *hair]])
            print(f"load average (1 min) {os.getloadavg()[0]:.1f} after (2 cores shared with "
                  "other jobs: ratios hold within one run, seconds do not)")
        return
    if args.only == "hair":
        with recorded(args.out, "Rendering: a full head of hair, its image against a "
                      "reference (issue 61)" if args.h_quality else "Rendering: a full head "
                      "of hair against the bald head (issue 61)"):
            print(f"variant: {variant}")
            if args.h_quality:
                hair_quality()
            else:
                hair_benchmark(styles=[x for x in args.h_styles.split(",") if x],
                               repeats=args.repeats)
        return
    if args.only == "sss":
        with recorded(args.out, "Rendering: subsurface scattering, volumetric and "
                      "screen-space"):
            print(f"variant: {variant}")
            sss_benchmark()
            sss_screen_benchmark()
        return
    if args.only == "integrator":
        print(f"variant: {variant}")
        res = integrator_benchmark(ref_spp=args.i_ref_spp)
        write_result(args.out or "bench/results/render_integrator.json",
                     {"title": "Rendering: hack_path, volpath and path, equal time",
                      "variant": variant, **res})
        return
    if args.only == "samplers":
        print(f"variant: {variant}")
        res = samplers_benchmark()
        write_result(args.out or "bench/results/render_samplers.json",
                     {"title": "Rendering: multijitter against orthogonal arrays",
                      "variant": variant, **res})
        return
    if args.only == "e2e":
        with recorded(args.out, "Rendering: end-to-end `hack-render render`"):
            e2e_benchmark(args.repeats)
        return
    if args.only == "cycles":
        print(f"variant: {variant}")
        cycles_benchmark(exe, version, args.c_size,
                         [int(x) for x in args.c_ladder.split(",")],
                         [int(x) for x in args.c_denoise_ladder.split(",") if x],
                         args.c_ref_spp, args.c_repeats,
                         Path(args.c_still) if args.c_still else None, args.out)
        return
    if args.only == "quality":
        with recorded(args.out, "Rendering: equal-quality time"):
            print(f"variant: {variant}")
            quality_benchmark(args.q_size, args.q_ref_spp, args.repeats)
        return
    with recorded(args.out, "Rendering"):
        print(f"variant: {variant}")
        turntable_benchmark(args.tt_size, args.tt_spp, args.frames, False)
        material_benchmark(args.size, args.spp, args.repeats)


if __name__ == "__main__":
    main()
