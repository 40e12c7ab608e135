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
    (no denoiser) as a user runs it, CPU seconds of the child process (user + system,
    median of 3), and a breakdown of one in-process run by phase (CPU seconds).

(e) Subsurface scattering by volumetric path tracing (``--only sss``): a skin-sized
    sphere (radius 9 cm) with a rough dielectric boundary (n = 1.4) around a homogeneous
    medium whose coefficients come from ``appearance/skin_optics.py`` (dermis with 5 %
    blood, reduced scattering, at 610 / 550 / 465 nm for R, G, B), rendered by
    ``volpath`` against the same sphere with ``hack_skin`` (albedo: the same model's
    two-layer Kubelka-Munk albedo) under the studio rig: CPU seconds at equal spp.

(f) Turntable frame cost before and after (``--only frames``): CPU seconds per frame
    (process time, after the first) of the README's turntable settings (256 px, --spp 32,
    studio, look-around + swallow) with the previous renderer (independent sampler,
    single-lobe specular, no bust cap, no denoiser) and the current one (multijitter 35
    spp, dual lobe, bust cap, OIDN), in one run.

Usage: python bench/bench_render.py [--size 512] [--spp 64] [--frames 8] [--tt-size 256]
       python bench/bench_render.py --only quality [--q-size 128] [--q-ref-spp 4096]
       python bench/bench_render.py --only e2e
       python bench/bench_render.py --only sss
"""

from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from provenance import recorded  # bench/ is sys.path[0] when run as a script


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
    from hack_render.render.image_io import to_srgb8
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

    def scene(spp, sampler):
        return HeadScene(topo, v, lights.preset("studio"), cam,
                         RenderSettings(size, size, spp, sampler=sampler), maps)

    t0 = time.process_time()
    ref = scene(ref_spp, "multijitter").render(seed=12345)[..., :3]
    print(f"  reference: {size}^2, {ref_spp} spp multijitter, {time.process_time() - t0:.0f} "
          "CPU s")
    ref8 = to_srgb8(ref, 0.0, "aces")

    def score(img):
        mse = float(np.mean((img[..., :3] - ref) ** 2))
        psnr = 10 * np.log10(float(ref.max()) ** 2 / mse)
        ssim = structural_similarity(to_srgb8(img[..., :3], 0.0, "aces"), ref8,
                                     channel_axis=-1)
        return psnr, float(ssim)

    rows = {}
    for sampler, spps, denoise in (("independent", (16, 32, 64, 128, 256, 512), False),
                                   ("multijitter", (16, 32, 64, 128, 256), False),
                                   ("multijitter", (4, 8, 16, 32), True)):
        for spp in spps:
            head = scene(spp, sampler)
            head.render(seed=0, denoise=denoise)  # compile
            cpu, res = [], []
            for r in range(repeats):
                t0 = time.process_time()
                img = head.render(seed=1 + r, denoise=denoise)
                cpu.append(time.process_time() - t0)
                res.append(score(img))
            psnr, ssim = np.mean(res, axis=0)
            name = f"{sampler} {head.settings.effective_spp} spp" + (" + OIDN" if denoise else "")
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
import torch; lap()
import mitsuba, drjit; lap()
from hack_render.render.engine import ensure_variant; ensure_variant(); lap()
from hack_render.geometry import load_default_model
from hack_render.render.parts import Topology
m = load_default_model()
with torch.no_grad(): v = m().vertices[0].double().numpy()
topo = Topology.from_model(m); lap()
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights
cam = cameras.preset("portrait", 256, 256)[0]
head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(256, 256, 16)); lap()
img = head.render(); lap()
from hack_render.render.image_io import write_png
write_png(sys.argv[1], img[..., :3]); lap()
names = ["import torch", "import mitsuba + drjit", "variant + plugins",
         "model load + forward", "scene build", "render 16 spp (kernels from disk cache)",
         "tone map + PNG write"]
for n, a, b in zip(names, t, t[1:]):
    print(f"    {n:40s} {b - a:5.2f} CPU s")
"""


def e2e_benchmark(repeats: int = 3) -> None:
    import os
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        cmd = ["hack-render", "render", "-o", f"{tmp}/a.png", "--resolution", "256",
               "--spp", "16", "--denoise", "off"]
        subprocess.run(cmd, check=True, capture_output=True)  # warm the disk caches
        cpu = []
        for _ in range(repeats):
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run(cmd, check=True, capture_output=True)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
        print(f"(d) {' '.join(cmd[:2])} 256 px, 16 spp, --denoise off: median "
              f"{statistics.median(cpu):.2f} CPU s (user + system) of {repeats} runs")
        print("  one in-process run by phase:")
        out = subprocess.run([sys.executable, "-c", E2E_PHASES, f"{tmp}/b.png"], check=True,
                             capture_output=True, text=True, env=dict(os.environ))
        print(out.stdout.rstrip())


def sss_benchmark(size: int = 96, spp: int = 16, max_depth: int = 512) -> None:
    import mitsuba as mi

    from appearance.skin_optics import (
        WAVELENGTHS,
        dermis_absorption,
        reduced_scattering,
        skin_albedo,
    )
    from hack_render.render import emitters, materials
    from hack_render.render.image_io import write_png
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
    for name, sampler, single, cap, denoise in (
            ("before: independent 32 spp, one lobe, no cap", "independent", True, False, False),
            ("after: multijitter 35 spp, dual lobe, cap", "multijitter", False, True, False),
            ("after, + OIDN", "multijitter", False, True, True)):
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
            head.render(seed=i, denoise=denoise)
            cpu.append(time.process_time() - t0)
        print(f"(f) {name:48s} {statistics.mean(cpu[1:]):.2f} CPU s per frame "
              f"(mean of frames 2..{frames})")
    skin_bsdf.LOBE_MIX, skin_bsdf.LOBE_ROUGHNESS = lobes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--tt-size", type=int, default=256)
    ap.add_argument("--tt-spp", type=int, default=32)
    ap.add_argument("--variant", default=None)
    ap.add_argument("--cold-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--only", choices=("all", "quality", "e2e", "sss", "frames"),
                    default="all")
    ap.add_argument("--q-size", type=int, default=128)
    ap.add_argument("--q-ref-spp", type=int, default=4096)
    ap.add_argument("--out", default=None, help="also write what it prints, with commit, "
                    "date, machine and command, e.g. bench/results/render.json")
    args = ap.parse_args()
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
    if args.only == "sss":
        with recorded(args.out, "Rendering: volumetric subsurface scattering cost"):
            print(f"variant: {variant}")
            sss_benchmark()
        return
    if args.only == "e2e":
        with recorded(args.out, "Rendering: end-to-end `hack-render render`"):
            e2e_benchmark(args.repeats)
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
