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

Issue 65, "datasets at render speed" (``--speed``; the dataset's default config: procedural
subjects, ``appearance.source: seed``):

(d) Render speed: the steady state of the serial executor's pipeline (files on the writer
    thread, the next sample's inputs prefetched within a block; a block's first sample
    makes its own) with the subjects' skin maps projected (``appearance.maps: projected``, the
    default) and generated (``generated``, the full generator: the old path), blocks of
    ``--block`` samples of each alternating on the same sample indices, against the
    render call inside the same pipeline (``HeadScene.render``: the path tracer) and
    against the render call plus the scene's update (``params.update``: the acceleration
    structure rebuilt for the sample's mesh, camera and lights; what any renderer of a new
    mesh pays). Target: s/sample <= 1.3x the render call. Printed with the parts: skin
    maps, labels (``label_images``), the update; then a profile of the projected side:
    the main thread's parts beside the render call (``set_camera`` with the update,
    labels, landmark visibility, the rest), the prefetch thread's inputs, the writer
    thread's EXR and PNG encoding, and the process's CPU seconds per sample. The blocks
    count each block's first sample's inputs (made in the rendering thread) and its last
    sample's writes; a last stream of ``--n`` more projected samples runs as the serial
    executor does (every sample's inputs prefetched while the one before renders) and is
    timed from the first sample's files on disk to the last's: the executor's own steady
    state, against the render calls of the same samples; then the serial floor: ``--n`` / 2
    (at least 3) more samples of that stream with each label kernel's execution timed by
    Dr.Jit's kernel history, and (render call + scene update + label kernel) / render
    call: what the rendering thread waits for beside the render call with no Python
    around it (the update is Embree's rebuild, the label kernel runs on Dr.Jit's threads).
(e) Start-up and end to end: ``hack-render dataset --n --e2e-n`` in a fresh process, fresh
    folder, ``--e2e-rounds`` times, for each ``--e2e-hair`` (``none``: bald heads;
    ``default``: the default config as users run it, hair sampled): seconds from launching
    the process to the end of its imports, to the first sample's scene and inputs ready
    (start-up: everything before the first sample's labels and render; target <= 3 s), to
    the first sample complete, then seconds per later sample and the total; and the CPU
    seconds of the process (all threads) to the imports and to the start-up, which other
    jobs on the machine change much less than the seconds. ``--before PATH`` runs the same command with another checkout's code (e.g. the
    main branch) on ``PYTHONPATH``, alternating with this one.
(f) Skin tones: the dataset's first ``--tones`` subjects (their ids drawn as the dataset
    draws them), generated at the dataset's map size and projected: ITA, L* and b* of each
    subject's forehead albedo (``representative_albedo``: the median over the forehead
    texels), their percentiles under both paths and the per-subject differences; the
    projected distribution is the dataset's unless these differ.

Usage: python bench/bench_dataset.py [--n 16] [--block 4] [--seed 0] [--size 256] [--spp 32]
       [--appearance alpha]
       [--ray-n 16] [--no-ray] [--inline-writes]
       python bench/bench_dataset.py --speed [--n 8] [--block 2] [--size 256] [--spp 16]
       [--e2e-n 6] [--e2e-rounds 2] [--e2e-hair none default] [--before /work/main]
       [--tones 60] [--sections def]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from method_timer import MethodTimer  # bench/ is sys.path[0] when run as a script
from provenance import ROOT, recorded  # bench/ is sys.path[0] when run as a script


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

    # bald heads (hair: none), as measured before issue 61: a groom's scene is rebuilt
    # per sample, which the bare side does not do (hair: bench/bench_dataset_hair.py)
    return load_config(overrides={"render": {"resolution": size, "spp": spp},
                                  "appearance": {"source": appearance}, "hair": "none"})


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
        p[f"{part.name}.vertex_positions"] = mi.Float(part.positions(v).ravel().astype(np.float32))
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
                peaks[:] = [max(a, b) for a, b in zip(got, peaks)] \
                    if len(peaks) == len(got) else got
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


def speed_benchmark(size: int, spp: int, n: int, block: int, seed: int, root: Path) -> None:
    """(d): the pipeline's steady state with projected and generated skin maps, against
    the render call and the render call plus the scene update (see the docstring)."""
    from hack_render.dataset import labels as lab
    from hack_render.dataset import worker as wk
    from hack_render.dataset.config import load_config
    from hack_render.dataset.runner import with_next
    from hack_render.dataset.worker import SampleRenderer
    from hack_render.render.scene import HeadScene

    cfgs = {m: load_config(overrides={"render": {"resolution": size, "spp": spp},
                                      "appearance": {"maps": m}, "hair": "none"})
            for m in ("projected", "generated")}
    rs = {m: SampleRenderer(c, root / m, seed, background_writes=True) for m, c in cfgs.items()}
    for r in rs.values():
        r.build_scenes()
    timer = MethodTimer()
    timer.wrap(HeadScene, "render")
    timer.wrap(wk.SampleRenderer, "skin_maps")
    timer.wrap(lab, "label_images")
    any_scene = next(iter(rs["projected"].scenes.values()))
    timer.wrap(type(any_scene.params), "update", "params.update")  # mi.SceneParameters
    # the profile's other parts: the main thread's, the prefetch thread's, the writer's
    timer.wrap(HeadScene, "set_camera")
    timer.wrap(lab, "landmark_record")
    timer.wrap(wk.SampleRenderer, "inputs")
    timer.wrap(wk, "write_exr")
    timer.wrap(wk, "_write_png")
    triangles = sum(s.primitive_count() for s in any_scene.scene.shapes())
    # warm-up: every preset's kernels compiled with both renderers' scenes in the process
    presets, i = set(), 0
    want = set(cfgs["projected"]["lighting"]["presets"])
    while (presets < want and i < 64) or i < 2:
        presets.add(rs["projected"].spec(i)["lighting"]["preset"])
        for r in rs.values():
            r.render(i)
        i += 1
    timer.take()
    rows = {m: {"wall": 0.0} for m in rs}
    for j0 in range(i, i + n, block):
        js = list(range(j0, min(j0 + block, i + n)))
        for m, r in rs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            futures = []
            for j, upcoming in with_next(js):  # as the serial executor runs them
                futures.append(r.submit(j, then=upcoming))
            for f in futures:
                f.result()
            rows[m]["wall"] += time.perf_counter() - t0
            rows[m]["cpu"] = rows[m].get("cpu", 0.0) + time.process_time() - c0
            for k, v in timer.take().items():
                rows[m][k] = rows[m].get(k, 0.0) + v
    # the executor's own steady state: one stream of n more samples, every sample's
    # inputs prefetched while the previous one renders (runner.run_serial's loop), timed
    # from the first sample's files on disk to the last's (no block starts or ends)
    r = rs["projected"]
    stream = list(range(i + n, i + 2 * n))
    done: list[float] = []
    timer.take()
    r.prefetch(stream[0])
    c0 = time.process_time()
    futures = []
    for j, upcoming in with_next(stream):
        f = r.submit(j, then=upcoming)
        f.add_done_callback(lambda _f: done.append(time.perf_counter()))
        futures.append(f)
    for f in futures:
        f.result()
    cpu_stream = (time.process_time() - c0) / n
    parts = timer.take()
    done.sort()
    per = (done[-1] - done[0]) / (n - 1)
    # the render calls of the samples inside that interval (all but the first sample's)
    rc_stream = parts["render"] / n
    floor = serial_floor(r, lab, timer, list(range(i + 2 * n, i + 2 * n + floor_n(n))))
    for r in rs.values():
        r.close()
    print(f"(d) render speed: {n} samples at {size} px, {spp} spp, the default config but "
          f"hair: none (bald heads; with hair a scene is built per sample: (e)), appearance "
          f"'seed' (procedural subjects), one view, blocks of {block} alternating, background "
          f"writes, {i} warm-up samples excluded:")
    for m, row in rows.items():
        w, rc = row["wall"] / n, row["render"] / n
        up = row.get("params.update", 0.0) / n
        print(f"    skin maps {m:9s}: {w:.3f} s/sample; render call {rc:.3f} s "
              f"(ratio {w / rc:.2f}x, target <= 1.3x); render call + scene update "
              f"{rc + up:.3f} s (ratio {w / (rc + up):.2f}x); parts: skin maps "
              f"{row.get('skin_maps', 0) / n:.3f} s, "
              f"labels {row.get('label_images', 0) / n:.3f} s, update {up:.3f} s (skin maps: "
              "mostly on the prefetch thread, beside the render)")
    g, p_ = rows["generated"]["wall"], rows["projected"]["wall"]
    print(f"    projected / generated: {p_ / g:.2f}x the time per sample")
    print(f"    one stream of {n} more samples, skin maps projected, as the serial executor "
          f"runs them (each sample's inputs made while the one before renders; from the first "
          f"sample's files on disk to the last's): {per:.3f} s/sample; render call "
          f"{rc_stream:.3f} s (ratio {per / rc_stream:.2f}x, target <= 1.3x); render call + "
          f"scene update {rc_stream + parts.get('params.update', 0) / n:.3f} s; labels "
          f"{parts.get('label_images', 0) / n:.3f} s; process CPU {cpu_stream:.3f} s/sample "
          f"(the blocks above also count each block's first sample's inputs, made in the "
          f"rendering thread, and its last sample's file writes)")
    f_rc, f_up, f_lab, f_kernel = floor
    print(f"    the serial floor ({floor_n(n)} more samples of the same stream, each label kernel "
          f"timed by Dr.Jit's kernel history): render call {f_rc:.3f} s + scene update "
          f"{f_up:.3f} s + label kernel {f_kernel:.3f} s = {(f_rc + f_up + f_kernel) / f_rc:.2f}x "
          f"the render call: the rendering thread's own waits beside the render call, with no "
          f"Python, no file and no other thread's work (the labels' other {f_lab - f_kernel:.3f} s:"
          f" tracing, code generation, NumPy, the GIL)")
    row = {k: v / n for k, v in rows["projected"].items()}
    beside = row["wall"] - row["render"]
    main = row.get("set_camera", 0) + row.get("label_images", 0) + row.get("landmark_record", 0)
    print(f"    profile, skin maps projected (s/sample, wall in each part's own thread): "
          f"{beside:.3f} s beside the render call; main thread: set_camera "
          f"{row.get('set_camera', 0):.3f} (of which params.update {row.get('params.update', 0):.3f}"
          f": Mitsuba rebuilds the Embree BVH of all {triangles} triangles at its fixed "
          f"RTC_BUILD_QUALITY_HIGH), labels {row.get('label_images', 0):.3f}, landmark "
          f"visibility {row.get('landmark_record', 0):.3f}, the rest "
          f"{beside - main:.3f}; prefetch thread: inputs {row.get('inputs', 0):.3f} (skin maps "
          f"{row.get('skin_maps', 0):.3f}); writer thread: EXR {row.get('write_exr', 0):.3f}, "
          f"PNG {row.get('_write_png', 0):.3f}; process CPU {row['cpu']:.3f} s/sample "
          f"({row['cpu'] / row['wall']:.2f} cores busy: the other threads' work competes "
          f"with the render's kernels)")


def floor_n(n: int) -> int:
    return max(3, n // 2)


def serial_floor(r, lab, timer, indices: list[int]) -> tuple[float, float, float, float]:
    """(d)'s floor: ``indices`` run as the serial executor runs them, with each label
    kernel's execution time taken from Dr.Jit's kernel history (switched on inside
    ``label_images`` alone). Returns the mean render call, scene update, labels and label
    kernel seconds a sample: the scene update (Embree's rebuild) and the label kernel are
    what the rendering thread waits for beside the render call however little Python
    runs around them."""
    import drjit as dr

    from hack_render.dataset.runner import with_next

    kernel = [0.0]
    inner = lab.label_images  # the timer's wrapper

    def label_images(*args, **kw):
        dr.kernel_history_clear()
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            return inner(*args, **kw)
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)
            kernel[0] += sum(k.get("execution_time", 0.0) for k in dr.kernel_history()
                             if k.get("type") == dr.KernelType.JIT) / 1000.0  # ms
    lab.label_images = label_images
    try:
        timer.take()
        r.prefetch(indices[0])
        for f in [r.submit(j, then=u) for j, u in with_next(indices)]:
            f.result()
        parts = timer.take()
    finally:
        lab.label_images = inner
    m = len(indices)
    return (parts["render"] / m, parts.get("params.update", 0.0) / m,
            parts.get("label_images", 0.0) / m, kernel[0] / m)


E2E_DRIVER = r"""
import json, sys, time
T = {"launch": float(sys.argv[1])}
from hack_render.dataset import runner, worker
T["imports"] = time.time()
T["imports_cpu"] = time.process_time()  # every thread of the process
done = []
ready = worker.SampleRenderer.scene_with_hair  # the scene a sample renders in, ready
def scene_with_hair(self, *args):
    out = ready(self, *args)
    T.setdefault("scenes", time.time())
    T.setdefault("scenes_cpu", time.process_time())
    return out
worker.SampleRenderer.scene_with_hair = scene_with_hair
record = worker._write_record  # runs once a sample's files are all on disk
def stamped(*args):
    out = record(*args)
    done.append(time.time())
    return out
worker._write_record = stamped
from hack_render.cli import main
try:
    main(sys.argv[2:])
except SystemExit as err:
    if err.code:
        raise
T["end"] = time.time()
import hack_render
print(json.dumps({"T": T, "done": done, "code": hack_render.__file__}))
"""


def e2e_run(pythonpath: str, n: int, size: int, spp: int, out: Path, hair: str | None) -> dict:
    """One fresh process running ``hack-render dataset`` (see (e)); its stamps, in seconds
    from the launch. ``hair``: the config's ``hair`` (None: the default's)."""
    cfg = out.with_suffix(".yaml")
    doc = {"render": {"resolution": size, "spp": spp}}
    if hair is not None:
        doc["hair"] = hair
    cfg.write_text(json.dumps(doc))
    env = dict(os.environ, PYTHONPATH=pythonpath)
    launch = time.time()
    # cwd: a folder without the package (`python -c` puts the cwd before PYTHONPATH)
    res = subprocess.run([sys.executable, "-c", E2E_DRIVER, str(launch), "dataset", "--n", str(n),
                          "-o", str(out), "--config", str(cfg), "--quiet"], env=env,
                         cwd=str(out.parent), capture_output=True, text=True, timeout=3600,
                         check=False)
    if res.returncode:
        raise SystemExit(f"(e) run failed:\n{res.stderr[-3000:]}")
    d = json.loads(res.stdout.strip().splitlines()[-1])
    if not d["code"].startswith(pythonpath):
        raise SystemExit(f"(e) ran {d['code']}, expected the code under {pythonpath}")
    t, done = d["T"], d["done"]
    done.sort()
    return {"imports": t["imports"] - launch, "startup": t["scenes"] - launch,
            "imports_cpu": t["imports_cpu"], "startup_cpu": t["scenes_cpu"],
            "first": done[0] - launch,
            "later": (done[-1] - done[0]) / max(1, len(done) - 1), "total": t["end"] - launch}


def e2e_benchmark(n: int, size: int, spp: int, rounds: int, before: str | None, root: Path,
                  hair: str | None = None) -> None:
    """(e): start-up and end to end, this checkout (and ``before``'s), alternating."""
    sides = {"this": str(ROOT)}
    if before:
        sides["before"] = str(Path(before).resolve())
    runs: dict[str, list[dict]] = {k: [] for k in sides}
    tag = "default" if hair is None else f"hair_{hair}"
    for r in range(rounds):
        for k, path in (list(sides.items()) if r % 2 == 0 else list(sides.items())[::-1]):
            runs[k].append(e2e_run(path, n, size, spp, root / f"e2e_{tag}_{k}_{r}", hair))
    which = ("the default config: hair sampled, lod 0.5" if hair is None
             else f"the default config with hair: {hair}")
    print(f"(e) `hack-render dataset --n {n}` at {size} px, {spp} spp ({which}), fresh "
          f"process and folder, {rounds} round(s); seconds from the launch, median [range]; "
          "start-up: to the first sample's scene and inputs ready (its labels and render "
          "next):")
    for k, rs in runs.items():
        commit = _git_head(sides[k])

        def f(key, rs=rs):
            v = [x[key] for x in rs]
            return f"{statistics.median(v):5.2f} [{min(v):.2f}..{max(v):.2f}]"

        print(f"    {k} ({commit}): imports {f('imports')}, start-up "
              f"{f('startup')} (target <= 3 s), first sample done {f('first')}, then "
              f"{f('later')} s/sample, total {f('total')}; CPU seconds (all threads; "
              f"robust to other jobs' load): imports {f('imports_cpu')}, start-up "
              f"{f('startup_cpu')}")


def _git_head(path: str) -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], cwd=path,
                             capture_output=True, text=True, timeout=10, check=False)
        return out.stdout.strip() or "unknown"
    except OSError:
        return "unknown"


def tones_benchmark(cfg: dict, n: int, seed: int) -> None:
    """(f): the dataset's first ``n`` subjects, generated and projected at the map size."""
    from appearance.colour_space import linear_srgb_to_lab
    from appearance.generator import generate_subject, representative_albedo
    from appearance.projected import SubjectProjector
    from hack_render.dataset.sampling import STREAMS, sample_appearance

    h = cfg["appearance"]["height"]
    # the subjects sample_spec draws for samples 0..n-1 (sampling.py: one stream each)
    ids = [sample_appearance(cfg, np.random.default_rng([seed, i, STREAMS["appearance"]]))
           ["subject"] for i in range(n)]
    proj = SubjectProjector()
    gen_rgb, proj_rgb, t_gen, t_proj = [], [], [], []
    for s in ids:
        t0 = time.perf_counter()
        ts = generate_subject(s, h)
        t_gen.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        mp = proj.maps(s, h)
        t_proj.append(time.perf_counter() - t0)
        gen_rgb.append(representative_albedo(ts, h))
        proj_rgb.append(representative_albedo(type("T", (), {"diffuse": mp.diffuse[0].numpy()}), h))

    def stats(rgb):
        lab = linear_srgb_to_lab(np.asarray(rgb))
        ita = np.degrees(np.arctan2(lab[:, 0] - 50.0, lab[:, 2]))
        return {"ITA": ita, "L*": lab[:, 0], "b*": lab[:, 2]}

    a, b = stats(gen_rgb), stats(proj_rgb)
    q = (5, 25, 50, 75, 95)
    print(f"(f) skin tones of the dataset's first {n} subjects (seed {seed}) at {h} px maps: "
          f"forehead median albedo; percentiles {q}:")
    for k in a:
        pa = " ".join(f"{v:6.1f}" for v in np.percentile(a[k], q))
        pb = " ".join(f"{v:6.1f}" for v in np.percentile(b[k], q))
        d = np.abs(a[k] - b[k])
        print(f"    {k:3s} generated {pa} | projected {pb} | per subject |diff| median "
              f"{np.median(d):.2f}, 90th pct {np.percentile(d, 90):.2f}, max {d.max():.2f}; "
              f"mean {a[k].mean():.1f} vs {b[k].mean():.1f}, std {a[k].std():.1f} vs "
              f"{b[k].std():.1f}")
    print(f"    time per subject: generated {statistics.median(t_gen):.3f} s, projected "
          f"{statistics.median(t_proj):.3f} s (median; the projector's first call excluded "
          f"from neither)")


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
    ap.add_argument("--speed", action="store_true", help="(d), (e) and (f) instead of (a)-(c)")
    ap.add_argument("--sections", default="def", help="--speed: which of (d), (e), (f)")
    ap.add_argument("--e2e-n", type=int, default=6, help="(e): samples of each run")
    ap.add_argument("--e2e-rounds", type=int, default=2, help="(e): runs of each side")
    ap.add_argument("--e2e-hair", nargs="+", default=["none", "default"],
                    help="(e): the configs' hair, each a run: 'default' (sampled) or a "
                    "hair.style such as none")
    ap.add_argument("--before", default=None, help="(e): another checkout to compare with")
    ap.add_argument("--tones", type=int, default=60, help="(f): subjects (0: skip)")
    ap.add_argument("--out", default=None, help="also write what it prints, with commit, "
                    "date, machine and command, e.g. bench/results/dataset.json")
    a = ap.parse_args()
    if a.speed:
        from hack_render.dataset.config import load_config

        with tempfile.TemporaryDirectory() as tmp, recorded(a.out, "Datasets at render speed "
                                                            "(issue 65)"):
            print(f"load average (1 min) before: {os.getloadavg()[0]:.1f}")
            if "d" in a.sections:
                speed_benchmark(a.size, a.spp, a.n, a.block, a.seed, Path(tmp))
            for hair in (a.e2e_hair if a.e2e_rounds and "e" in a.sections else []):
                e2e_benchmark(a.e2e_n, a.size, a.spp, a.e2e_rounds, a.before, Path(tmp),
                              None if hair == "default" else hair)
            if a.tones and "f" in a.sections:
                tones_benchmark(load_config(overrides={"render": {"resolution": a.size}}),
                                a.tones, a.seed)
            print(f"load average (1 min) after: {os.getloadavg()[0]:.1f} (2 cores shared with "
                  "other jobs: ratios hold within one run, seconds do not)")
        return
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
