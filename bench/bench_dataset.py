"""Dataset benchmark (not a test): ratios measured in one run, printed.

(a) Labels cost: samples/minute of the dataset pipeline (sampling, geometry, skin maps,
    RGB, every AOV, soft masks, landmarks with visibility, all files) vs rendering the
    same scenes' RGB alone with bare Mitsuba calls (write vertex positions and normals,
    textures, light transforms and the sensor through ``mi.traverse``, one update per
    view, then ``mi.render``), in the same process on the same inputs, interleaved in
    blocks of ``--block`` samples (so that other load on the machine hits both sides
    alike). The pipeline runs a block as the serial executor does: each sample's files
    are written on a background thread while the next sample renders, and the block ends
    when every file of its last sample is on disk. Printed twice: the whole pipeline, and
    the pipeline without the inputs both sides share (geometry forward, skin maps, vertex
    normals; timed on the bare side). Target <= 1.3x.
(b) Ray: samples/minute of ``--executor ray`` with 2 actors (one Dr.Jit thread each) vs
    the serial executor (Dr.Jit on every core, and on one thread for reference) on the
    same samples, fresh output folders: total time including start-up, and the steady
    state from each worker's first finished sample to the last.
(c) Peak memory: this process's peak RSS; each Ray worker's peak RSS (VmHWM).
(a) first renders samples until every lighting preset has been seen (kernel compilation,
excluded); ``--inline-writes`` writes the files in the rendering thread instead. (b)
includes start-up on both sides.

Usage: python bench/bench_dataset.py [--n 16] [--block 4] [--seed 0] [--size 256] [--spp 32] [--appearance alpha]
       [--ray-n 16] [--no-ray] [--inline-writes]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from provenance import recorded  # bench/ is sys.path[0] when run as a script


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


def _bare_rgb(r, spec: dict, cfg: dict) -> tuple[float, float]:
    """RGB of one sample with bare Mitsuba calls on the renderer's scene: (shared inputs
    time, bare time). Geometry and skin maps are the shared inputs; vertex normals are
    computed outside the timed part too, so the bare side is only Mitsuba."""
    import mitsuba as mi
    import torch

    from hack_render.dataset.sampling import model_kwargs
    from hack_render.dataset.worker import camera_of
    from hack_render.render.emitters import camera_to_world
    from hack_render.render.parts import vertex_normals

    t0 = time.perf_counter()
    with torch.no_grad():
        v = r.model(**model_kwargs(r.model, spec)).vertices[0].numpy().astype(np.float64)
    maps = r.skin_maps(spec["appearance"])
    head = r.scene(spec["lighting"]["preset"])
    normals = vertex_normals(v, r.topology.faces)
    shared = time.perf_counter() - t0
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
    head.set_light_rotation(spec["lighting"]["rotation_deg"], update=False)  # param writes
    for vi, view in enumerate(spec["cameras"]):
        cam = camera_of(view, cfg["render"]["resolution"], "bench")
        p["sensor.to_world"] = mi.Transform4f(camera_to_world(cam).tolist())
        p["sensor.x_fov"] = cam.fov_x_deg
        p.update()
        np.asarray(mi.render(head.scene, seed=spec["render_seed"] + vi))
    return shared, time.perf_counter() - t0


def labels_benchmark(cfg: dict, n: int, out: Path, seed: int,
                     background_writes: bool = True, block: int = 4) -> None:
    """Interleaved in blocks: ``block`` samples through the pipeline as the serial executor
    runs them (files written on a background thread while the next sample renders; the
    block ends when every file is on disk), then the same samples' bare RGB."""
    from hack_render.dataset.worker import SampleRenderer

    r = SampleRenderer(cfg, out, seed, background_writes=background_writes)
    r.build_scenes()
    presets, i = set(), 0
    # warm-up: every preset's kernels compiled (both sides share them), excluded
    while len(presets) < len(cfg["lighting"]["presets"]) and i < 64 or i < 2:
        presets.add(r.spec(i)["lighting"]["preset"])
        r.render(i)
        _bare_rgb(r, r.spec(i), cfg)
        i += 1
    full, shared, bare = [], [], []
    for j0 in range(i, i + n, block):
        js = list(range(j0, min(j0 + block, i + n)))
        t0 = time.perf_counter()
        futures = [r.submit(j) for j in js]
        for f in futures:
            f.result()
        full.append(time.perf_counter() - t0)
        sb = [_bare_rgb(r, r.spec(j), cfg) for j in js]
        shared.append(sum(x for x, _ in sb))
        bare.append(sum(y for _, y in sb))
    r.close()
    f, s, b = (sum(x) / n for x in (full, shared, bare))
    per = [(x - y) / z for x, y, z in zip(full, shared, bare)]
    print(f"(a) {n} samples at {cfg['render']['resolution']} px, {cfg['render']['spp']} spp, "
          f"appearance '{cfg['appearance']['source']}', soft masks "
          f"{cfg['render']['soft_mask_samples']}^2 rays/pixel, {cfg['camera']['views']} view(s) "
          f"({r.scene(next(iter(presets))).variant}, {i} warm-up samples excluded; blocks of "
          f"{block}, {'background' if background_writes else 'inline'} writes):")
    print(f"    all labels + files: {f:.3f} s/sample = {60 / f:.1f} samples/min")
    print(f"    bare Mitsuba RGB:   {b:.3f} s/sample = {60 / b:.1f} samples/min")
    print(f"    shared inputs (geometry, skin maps, vertex normals): {s:.3f} s/sample")
    print(f"    ratio, whole pipeline / bare RGB:              {f / b:.2f}x")
    print(f"    ratio, pipeline without shared inputs / bare RGB: {(f - s) / b:.2f}x "
          f"(per-block median {statistics.median(per):.2f}x; target <= 1.3x)")


def _timed_run(job, executor: str, **kw) -> tuple[float, float]:
    """(total seconds incl. start-up, steady-state samples/min): the steady state runs
    from each worker's first finished sample (start-up, kernel loading) to the last."""
    from hack_render.dataset import runner

    stamps: list[float] = []
    append = runner._append_manifest

    def stamped(job_, rec):
        stamps.append(time.perf_counter())
        append(job_, rec)

    runner._append_manifest = stamped
    try:
        t0 = time.perf_counter()
        runner.run(job, executor, progress=False, **kw)
        total = time.perf_counter() - t0
    finally:
        runner._append_manifest = append
    skip = kw.get("workers") or 1
    steady = (len(stamps) - skip) / (stamps[-1] - stamps[skip - 1]) * 60
    return total, steady


def ray_benchmark(cfg: dict, n: int, root: Path) -> None:
    """Serial (Dr.Jit on every core, then on one) vs Ray with 2 single-thread actors."""
    import threading

    import drjit as dr

    from hack_render.dataset.runner import Job
    from hack_render.render.engine import ensure_variant, set_thread_count

    ensure_variant(cfg["render"]["variant"])
    cores = dr.thread_count()
    ts, ss = _timed_run(Job(root / "serial", n, 0, cfg), "serial")
    set_thread_count(1)
    ts1, ss1 = _timed_run(Job(root / "serial1", n, 0, cfg), "serial")
    set_thread_count(cores)
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
    tr, sr = _timed_run(Job(root / "ray", n, 0, cfg), "ray", workers=2)
    stop.set()
    th.join()
    differ = [str(p.relative_to(root)) for d in ("ray", "serial1")
              for p in sorted((root / d / "samples").rglob("*")) if p.is_file()
              and (root / "serial" / p.relative_to(root / d)).read_bytes() != p.read_bytes()]
    same = "yes" if not differ else f"no, {len(differ)} files differ: {', '.join(differ[:6])}"
    print(f"(b) {n} samples, {cores} cores; total incl. start-up / steady state (after each "
          "worker's first sample):")
    print(f"    serial, {cores} Dr.Jit threads: {ts:5.1f} s / {ss:5.1f} samples/min")
    print(f"    serial, 1 Dr.Jit thread:  {ts1:5.1f} s / {ss1:5.1f} samples/min "
          f"(Dr.Jit's own threading gives {ss / ss1:.2f}x)")
    print(f"    ray, 2 actors x 1 thread:  {tr:5.1f} s / {sr:5.1f} samples/min")
    print(f"    ray speed-up over serial: {ts / tr:.2f}x incl. start-up, {sr / ss:.2f}x steady "
          f"state; files identical to serial: {same}")
    if peaks:
        print(f"    ray worker peak RSS: {', '.join(f'{p:.0f}' for p in peaks)} MiB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--block", type=int, default=4,
                    help="(a): samples per pipelined block (the executor's steady state)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--appearance", default="alpha", choices=("seed", "alpha", "constant"))
    ap.add_argument("--ray-n", type=int, default=16)
    ap.add_argument("--no-ray", action="store_true")
    ap.add_argument("--no-labels", action="store_true", help="skip (a)")
    ap.add_argument("--inline-writes", action="store_true",
                    help="(a): write files in the rendering thread (no background writer)")
    ap.add_argument("--out", default=None, help="also write what it prints, with commit, "
                    "date, machine and command, e.g. bench/results/dataset.json")
    a = ap.parse_args()
    cfg = config(a.size, a.spp, a.appearance)
    with tempfile.TemporaryDirectory() as tmp, recorded(a.out, "Datasets"):
        if not a.no_labels:
            labels_benchmark(cfg, a.n, Path(tmp) / "a", a.seed, not a.inline_writes, a.block)
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
