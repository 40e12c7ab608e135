"""Render benchmarks (not tests): ratios measured in one run, printed.

(a) Material cost: one frame of the default head at 512^2, 64 spp, with our ``hack_skin``
    material vs the same mesh (written to OBJ, loaded by Mitsuba's ``obj`` plugin) with a
    plain ``diffuse`` BSDF; same lights, camera, integrator and spp. Target <= 1.5x.
(b) Turntable reuse: frames 2..N of a turntable (vertices and camera updated through
    ``mi.traverse``) vs one fresh render (scene build + first render after flushing
    Dr.Jit's in-memory kernel cache). Target <= 0.5x.
(d) End to end (``--only e2e``): ``hack-render render`` of a 256 px image at 16 spp
    (no denoiser, and the defaults) as a user runs it, CPU seconds of the child process
    (user + system) and wall seconds, medians of 3, and a breakdown of one in-process run
    by phase (CPU seconds), with the pose's cost by NumPy (``geometry/posing.py``, what
    `render` runs) against torch's import, model load and forward in the same run. As on a
    user's machine, Python caches this package's bytecode (the child runs without
    ``PYTHONDONTWRITEBYTECODE``, which some sandboxes set: an editable install's modules
    are then compiled from source on every run, about 0.17 CPU s).

(f) Turntable frame cost before and after (``--only frames``): CPU seconds per frame
    (process time, after the first) of the README's turntable settings (256 px, --spp 32,
    studio, look-around + swallow) with the previous renderer (independent sampler,
    single-lobe specular, no bust cap, no denoiser) and the current one (multijitter 35
    spp, dual lobe, bust cap, OIDN), in one run.

The other sections live beside this file and run from here: ``render_images.py`` ((c) equal
quality, (e) and (e2) subsurface scattering, (h) integrators, (i) samplers), ``render_cycles.py``
((g) against Blender Cycles) and ``render_hair.py`` ((j) hair).

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
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from provenance import recorded, write_result  # bench/ is sys.path[0] when run as a script
from render_cycles import BPY_ENV, blender_python, cycles_benchmark
from render_hair import hair_benchmark, hair_quality
from render_images import (
    integrator_benchmark,
    quality_benchmark,
    samplers_benchmark,
    sss_benchmark,
    sss_screen_benchmark,
)


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
