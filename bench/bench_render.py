"""Render benchmarks (not tests): ratios measured in one run, printed.

(a) Material cost: one frame of the default head at 512^2, 64 spp, with our ``hack_skin``
    material vs the same mesh (written to OBJ, loaded by Mitsuba's ``obj`` plugin) with a
    plain ``diffuse`` BSDF; same lights, camera, integrator and spp. Target <= 1.5x.
(b) Turntable reuse: frames 2..N of a turntable (vertices and camera updated through
    ``mi.traverse``) vs one fresh render (scene build + first render after flushing
    Dr.Jit's in-memory kernel cache). Target <= 0.5x.

Usage: python bench/bench_render.py [--size 512] [--spp 64] [--frames 8] [--tt-size 256]
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
            first = timed(lambda: np.asarray(mi.render(sc, seed=0)), 1)[0]
            rest = timed(lambda: np.asarray(mi.render(sc, seed=1)), repeats)
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
    ap.add_argument("--out", default=None, help="also write what it prints, with commit, "
                    "date, machine and command, e.g. bench/results/render.json")
    args = ap.parse_args()
    from hack_render.render.engine import ensure_variant

    variant = ensure_variant(args.variant)
    if args.cold_only:
        turntable_benchmark(args.tt_size, args.tt_spp, args.frames, True)
        return
    with recorded(args.out, "Rendering"):
        print(f"variant: {variant}")
        turntable_benchmark(args.tt_size, args.tt_spp, args.frames, False)
        material_benchmark(args.size, args.spp, args.repeats)


if __name__ == "__main__":
    main()
