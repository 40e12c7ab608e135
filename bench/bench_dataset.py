"""Dataset benchmark (not a test): ratios measured in one run, printed.

(a) Labels cost: samples/minute of the dataset pipeline (sampling, geometry, skin maps,
    RGB, every AOV, soft masks, landmarks with visibility, all files) vs rendering the
    same scenes' RGB alone with bare Mitsuba calls (write vertex positions, textures and
    the sensor through ``mi.traverse``, then ``mi.render``), in the same process on the
    same inputs. Printed twice: the whole pipeline, and the pipeline without the inputs
    both sides share (geometry forward and skin maps, timed separately). Target <= 1.3x.
(b) Ray: samples/minute of ``--executor ray`` with 2 workers vs the serial executor on
    the same samples, each including its start-up (fresh output folders).
(c) Peak memory: this process's peak RSS; each Ray worker's peak RSS (VmHWM).
The first sample of every measurement compiles kernels and is excluded from (a).

Usage: python bench/bench_dataset.py [--n 6] [--size 256] [--spp 32] [--appearance alpha]
       [--ray-n 8] [--no-ray]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def ray_worker_peaks_mib() -> list[float]:
    """VmHWM of live Ray actor processes rendering samples (Linux /proc)."""
    peaks = []
    for p in Path("/proc").glob("[0-9]*"):
        try:
            if b"RayRenderer" not in (p / "cmdline").read_bytes():
                continue
            for line in (p / "status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    peaks.append(int(line.split()[1]) / 1024.0)
        except OSError:
            continue
    return peaks


def config(size: int, spp: int, appearance: str) -> dict:
    from hack_render.dataset.config import load_config

    return load_config(overrides={"render": {"resolution": size, "spp": spp},
                                  "appearance": {"source": appearance}})


def labels_benchmark(cfg: dict, n: int, out: Path) -> None:
    import mitsuba as mi
    import torch

    from hack_render.dataset.sampling import model_kwargs
    from hack_render.dataset.worker import SampleRenderer, camera_of
    from hack_render.render.emitters import camera_to_world

    r = SampleRenderer(cfg, out, seed=0)
    full, shared, bare = [], [], []
    for i in range(n + 1):
        t0 = time.perf_counter()
        r.render(i)
        full.append(time.perf_counter() - t0)
    # the same scenes' inputs, then RGB alone with bare Mitsuba calls
    for i in range(n + 1):
        spec = r.spec(i)
        t0 = time.perf_counter()
        with torch.no_grad():
            v = r.model(**model_kwargs(r.model, spec)).vertices[0].numpy().astype(np.float64)
        maps = r.skin_maps(spec["appearance"])
        shared.append(time.perf_counter() - t0)
        head = r.scene(spec["lighting"]["preset"])
        head.set_light_rotation(spec["lighting"]["rotation_deg"])
        from hack_render.render.parts import vertex_normals

        normals = vertex_normals(v, r.topology.faces)
        t0 = time.perf_counter()
        p = head.params
        for part in head.parts:
            p[f"{part.name}.vertex_positions"] = mi.Float(v[part.gather].ravel().astype(np.float32))
            p[f"{part.name}.vertex_normals"] = mi.Float(normals[part.gather].ravel().astype(np.float32))
        k = head._skin_key
        p[f"{k}.albedo.data"] = mi.TensorXf(maps.diffuse)
        p[f"{k}.specular.data"] = mi.TensorXf(maps.specular)
        p[f"{k}.roughness.data"] = mi.TensorXf(maps.roughness)
        if maps.normal is not None and f"{k}.normalmap.data" in p:
            p[f"{k}.normalmap.data"] = mi.TensorXf(maps.normal)
        for vi, view in enumerate(spec["cameras"]):
            cam = camera_of(view, cfg["render"]["resolution"], "bench")
            p["sensor.to_world"] = mi.Transform4f(camera_to_world(cam).tolist())
            p["sensor.x_fov"] = cam.fov_x_deg
            p.update()
            np.asarray(mi.render(head.scene, seed=spec["render_seed"] + vi))
        bare.append(time.perf_counter() - t0)
    f, s, b = (statistics.mean(x[1:]) for x in (full, shared, bare))
    print(f"(a) {n} samples at {cfg['render']['resolution']} px, {cfg['render']['spp']} spp, "
          f"appearance '{cfg['appearance']['source']}', soft masks "
          f"{cfg['render']['soft_mask_samples']}^2 rays/pixel ({head.variant}):")
    print(f"    all labels + files: {f:.2f} s/sample = {60 / f:.1f} samples/min")
    print(f"    bare Mitsuba RGB:   {b:.2f} s/sample = {60 / b:.1f} samples/min")
    print(f"    shared inputs (geometry + skin maps): {s:.2f} s/sample")
    print(f"    ratio, whole pipeline / bare RGB:              {f / b:.2f}x")
    print(f"    ratio, pipeline without shared inputs / bare RGB: {(f - s) / b:.2f}x "
          "(target <= 1.3x)")


def ray_benchmark(cfg: dict, n: int, root: Path) -> None:
    from hack_render.dataset.runner import Job, run

    t0 = time.perf_counter()
    run(Job(root / "serial", n, 0, cfg), "serial", progress=False)
    ts = time.perf_counter() - t0
    import threading

    peaks: list[float] = []
    stop = threading.Event()

    def watch():
        while not stop.is_set():
            got = ray_worker_peaks_mib()
            if got:
                peaks[:] = [max(a, b) for a, b in zip(got, peaks)] if len(peaks) == len(got) else got
            time.sleep(0.5)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    t0 = time.perf_counter()
    run(Job(root / "ray", n, 0, cfg), "ray", workers=2, progress=False)
    tr = time.perf_counter() - t0
    stop.set()
    th.join()
    same = all((root / "serial" / p.relative_to(root / "ray")).read_bytes() == p.read_bytes()
               for p in (root / "ray" / "samples").rglob("*") if p.is_file())
    print(f"(b) {n} samples incl. start-up: serial {ts:.1f} s ({60 * n / ts:.1f} samples/min), "
          f"ray x2 {tr:.1f} s ({60 * n / tr:.1f} samples/min): speed-up {ts / tr:.2f}x; "
          f"files identical: {same}")
    if peaks:
        print(f"    ray worker peak RSS: {', '.join(f'{p:.0f}' for p in peaks)} MiB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--appearance", default="alpha", choices=("seed", "alpha", "constant"))
    ap.add_argument("--ray-n", type=int, default=8)
    ap.add_argument("--no-ray", action="store_true")
    a = ap.parse_args()
    cfg = config(a.size, a.spp, a.appearance)
    with tempfile.TemporaryDirectory() as tmp:
        labels_benchmark(cfg, a.n, Path(tmp) / "a")
        print(f"(c) peak RSS of this process after (a): {peak_rss_mib():.0f} MiB")
        if not a.no_ray:
            try:
                import ray  # noqa: F401
            except ImportError:
                print("(b) skipped: ray is not installed (pip install 'hack-render[ray]')")
                return
            ray_benchmark(cfg, a.ray_n, Path(tmp))


if __name__ == "__main__":
    main()
