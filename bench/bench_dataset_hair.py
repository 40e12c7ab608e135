"""Dataset hair (issue 61), not a test: the sheet of sampled people, and the cost.

(a) ``--sheet PATH`` (256 colours): 12 samples of the dataset's default config (hair sampled at the
    default level of detail), chosen among the first indices of ``--seed`` so that every
    hair archetype and every lighting preset is in (the first index that brings a new
    archetype or preset, then the first others in order), rendered as the dataset renders
    them, into ``--keep`` (or a temporary folder); the RGB of each in a 4 x 3 grid, with
    its archetype, beard and preset written under it, saved to PATH; and
    ``dataset preview``'s sheet of the same samples (segmentation overlay: hair orange) to
    PATH with ``_preview`` before the suffix.
(b) ``--speed``: seconds per sample of the serial executor's pipeline (files on the writer
    thread, the next sample's inputs prefetched) without hair (``hair: none``) and with
    it (``hair: sampled`` at each ``--lod``), ``--n`` samples each after ``--warm`` warm-up
    samples, the sides one after the other in separate renderers (a scene with hair alive
    in the process would make the bald scenes' kernels recompile too), with the parts:
    the render call (``HeadScene.render``), the labels, the groom (grown on the prefetch
    thread, beside the render) and the scene built around each groom (posing included).
(c) ``--steady``: the default config (hair sampled) in a fresh process, as the serial
    executor runs it (each sample submitted with the next one's inputs prefetched),
    ``--warm`` samples first, then ``--n``: seconds per sample, the render call's, the
    labels', the scene update's (``HeadScene.set_camera``, where the sample's one
    ``params.update()`` rebuilds the acceleration structures, the groom's among them), the
    process's CPU seconds per sample and the render kernels compiled anew (Dr.Jit's kernel
    history: cache misses, and their compile seconds); ``--before PATH`` runs the same
    in another checkout right after, in its own process. ``--pool-grown``: this checkout
    once more with the measured samples' grooms grown during the warm-up (``hair.pool``:
    the first samples of a dataset grow their pooled grooms, a later stretch finds them).
    ``--bald``: the config with ``hair: none``. Besides the render call inside the
    pipeline, the render call alone: after the stream, each preset's scene as its last
    sample left it rendered 3 more times with nothing beside it (the median over the
    presets of each scene's median), with its CPU seconds: the denominator the issue's
    1.3x means, which other threads' work cannot inflate (inside the pipeline the render
    call also waits for the cores the other threads hold).

(d) ``--groom``: the groom alone, in a fresh process per checkout: ``grow`` of the hair of
    samples 0..``--n``-1 of ``--seed`` (the default config), then ``pose_groom`` of each on
    its sample's vertices; seconds and CPU seconds (all threads) of each, and a digest of
    every array grown and posed: two checkouts with the same digest grow and pose the same
    grooms bit for bit; ``--before PATH`` runs the other checkout right after.

(e) ``--cpu-parts``: where a sample's CPU seconds go (the process's, all threads: Dr.Jit's
    and Embree's included), every part run on the calling thread one at a time (no
    prefetch, files written in place), ``--n`` samples after the warm-up, in a fresh
    process (``--bald``: hair none): the render call (and its cores busy), the scene
    update (the acceleration structure rebuilt), the labels, the inputs (skin maps, groom
    grown or pooled, groom posed), the hair swap, the files. Since the render call alone
    keeps the cores busy, a pipeline of these parts cannot take less than their CPU
    seconds / the cores; printed as a ratio to the render call's wall time, for all the
    parts and for the render call with the scene update and the labels alone.

Usage: python bench/bench_dataset_hair.py --sheet docs/images/dataset_hair_sheet.png
       python bench/bench_dataset_hair.py --speed [--n 6] [--size 256] [--spp 25] [--lod 0.25]
       python bench/bench_dataset_hair.py --steady [--n 6] [--warm 2] [--before PATH]
           [--bald] [--pool-grown]
       python bench/bench_dataset_hair.py --groom [--n 40] [--before PATH]
       python bench/bench_dataset_hair.py --cpu-parts [--n 8] [--bald]
"""

from __future__ import annotations

import argparse
import builtins
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from method_timer import MethodTimer  # bench/ is sys.path[0] when run as a script
from provenance import write_result

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hack_render.dataset import labels as lab
from hack_render.dataset import worker as wk
from hack_render.dataset.config import load_config
from hack_render.dataset.preview import contact_sheet
from hack_render.dataset.runner import with_next
from hack_render.dataset.sampling import sample_spec
from hack_render.geometry import load_default_model
from hack_render.hair.style import ARCHETYPES
from hack_render.render.scene import HeadScene


def choose(cfg: dict, seed: int, count: int = 12, search: int = 400):
    """Indices whose hair and lighting cover every archetype and preset (see (a))."""
    aus = load_default_model().au_names
    specs = [sample_spec(cfg, seed, i, aus) for i in range(search)]
    seen_a, seen_p, chosen = set(), set(), []
    for i, s in enumerate(specs):
        a, p = s["hair"]["archetype"], s["lighting"]["preset"]
        if a not in seen_a or p not in seen_p:
            chosen.append(i)
            seen_a.add(a)
            seen_p.add(p)
        if len(seen_a) == len(ARCHETYPES) and len(seen_p) == len(cfg["lighting"]["presets"]):
            break
    rest = [i for i in range(search) if i not in chosen]
    chosen = sorted(chosen[:count] + rest[:max(0, count - len(chosen))])
    return chosen, specs


def sheet(path: Path, seed: int, keep: str | None, size: int) -> None:
    from PIL import Image, ImageDraw

    cfg = load_config(overrides={"render": {"resolution": size}})
    idx, specs = choose(cfg, seed)
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="hack-hair-sheet-"))
    r = wk.SampleRenderer(cfg, root, seed, background_writes=True)
    r.build_scenes()
    t0 = time.perf_counter()
    futures = []
    for i, upcoming in with_next(idx):
        if upcoming is not None:
            r.prefetch(upcoming)
        futures.append(r.submit(i))
    for f in futures:
        f.result()
    r.close()
    print(f"rendered {len(idx)} samples {idx} in {time.perf_counter() - t0:.0f} s")
    import imageio.v3 as iio

    tiles = []
    for i in idx:
        s = specs[i]
        rgb = iio.imread(wk.sample_dir(root, i) / "view_00" / "rgb.png")[..., :3]
        img = Image.new("RGB", (size, size + 16), (255, 255, 255))
        img.paste(Image.fromarray(rgb), (0, 0))
        h = s["hair"]
        text = f"{h['archetype']}, beard {h['beard']}, {s['lighting']['preset']}"
        ImageDraw.Draw(img).text((4, size + 2), text, fill=(0, 0, 0))
        tiles.append(np.asarray(img))
        print(f"  {i}: {text}; eumelanin {h['eumelanin']:.2f}, pheomelanin "
              f"{h['pheomelanin']:.2f}, greying {h['greying']:.2f}")
    cols, rows = 4, -(-len(tiles) // 4)
    th, tw = tiles[0].shape[:2]
    grid = np.full((rows * th, cols * tw, 3), 255, np.uint8)
    for k, t in enumerate(tiles):
        y, x = divmod(k, cols)
        grid[y * th:(y + 1) * th, x * tw:(x + 1) * tw] = t
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, grid)
    prev = contact_sheet(root, path.with_name(path.stem + "_preview" + path.suffix),
                         count=len(idx), columns=6)
    for p in (path, prev):  # 256 colours (docs-sized files: ~0.4 MB against 1.3 MB)
        Image.open(p).convert("RGB").quantize(256, Image.Quantize.MEDIANCUT).save(
            p, optimize=True)
    print(f"wrote {path} and {prev} (samples kept in {root})")


def speed(n: int, warm: int, size: int, spp: int, lods: list[float], seed: int) -> None:
    timer = MethodTimer()
    timer.wrap(HeadScene, "render")
    timer.wrap(lab, "label_images")
    timer.wrap(wk.SampleRenderer, "groom")
    timer.wrap(wk.SampleRenderer, "_build_scene", "scene built")
    sides = [("hair: none", "none")] + [(f"hair: sampled, lod {x:g}", {"lod": x}) for x in lods]
    print(f"load average (1 min) before: {os.getloadavg()[0]:.1f}")
    base = None
    for name, hair in sides:
        cfg = load_config(overrides={"render": {"resolution": size, "spp": spp},
                                     "hair": hair})
        with tempfile.TemporaryDirectory() as tmp:
            r = wk.SampleRenderer(cfg, tmp, seed, background_writes=True)
            r.build_scenes()
            for i in range(warm):
                r.render(i)
            timer.take()
            js = list(range(warm, warm + n))
            t0 = time.perf_counter()
            futures = []
            for j, upcoming in with_next(js):
                if upcoming is not None:
                    r.prefetch(upcoming)
                futures.append(r.submit(j))
            for f in futures:
                f.result()
            wall = (time.perf_counter() - t0) / n
            r.close()
            del r
        parts = {k: v / n for k, v in timer.take().items()}
        base = wall if base is None else base
        styles = ""
        if hair != "none":
            aus = load_default_model().au_names
            styles = ", ".join(sample_spec(cfg, seed, j, aus)["hair"]["archetype"] for j in js)
        print(f"  {name:24s}: {wall:6.2f} s/sample ({wall / base:.1f}x without hair); render "
              f"call {parts.get('render', 0):.2f} s, labels {parts.get('label_images', 0):.2f} s, "
              f"groom {parts.get('groom', 0):.2f} s (prefetch thread), scene built "
              f"{parts.get('scene built', 0):.2f} s" + (f"; styles {styles}" if styles else ""),
              flush=True)
    print(f"load average (1 min) after: {os.getloadavg()[0]:.1f} (2 cores shared with other "
          "jobs: ratios within one run, not the seconds)")
    print(json.dumps({"n": n, "size": size, "spp": spp, "lods": lods}))


#: (c)'s and (e)'s fresh process: a renderer of the config (``background``: files on the
#: writer thread), warmed up by ``warm`` samples and until every preset has rendered
RENDERER = """
import json, sys, tempfile, time
sys.path.insert(0, {bench!r})
from method_timer import MethodTimer
from hack_render.render.engine import ensure_variant
ensure_variant()
import drjit as dr
from hack_render.dataset import labels as lab
from hack_render.dataset import worker as wk
from hack_render.dataset.config import load_config
from hack_render.dataset.runner import with_next
from hack_render.render.scene import HeadScene
over = {{"render": {{"resolution": {size}, "spp": {spp}}}}}
if {bald}:
    over["hair"] = "none"
cfg = load_config(overrides=over)
r = wk.SampleRenderer(cfg, tempfile.mkdtemp(), {seed}, background_writes={background})
presets, i = set(), 0
while len(presets) < len(cfg["lighting"]["presets"]) or i < {warm}:
    presets.add(r.spec(i)["lighting"]["preset"])
    r.render(i)
    i += 1
"""

STEADY = RENDERER + """first = i
js = list(range(first, first + {n}))
if {grown}:  # a later stretch of a long dataset: the measured samples' pooled grooms grown
    for j in js:
        r.groom(r.spec(j)["hair"])
timer = MethodTimer()
timer.wrap(HeadScene, "render")
timer.wrap(lab, "label_images")
timer.wrap(HeadScene, "set_camera")
dr.set_flag(dr.JitFlag.KernelHistory, True)
dr.kernel_history_clear()
t0, c0 = time.perf_counter(), time.process_time()
futures = [r.submit(j, then=upcoming) for j, upcoming in with_next(js)]
for f in futures:
    f.result()
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
miss = [k for k in dr.kernel_history()
        if k.get("type") == dr.KernelType.JIT and not k.get("cache_hit")]
parts = timer.take()
r.close()
# the render call alone: each preset's scene as its last sample left it (mesh, camera,
# lights), rendered again with nothing else running, median of 3 a scene
alone, alone_cpu = [], []
for head in r.scenes.values():
    ts, cs = [], []
    for k in range(3):
        t, c = time.perf_counter(), time.process_time()
        head.render(seed=k, backdrop=False, sss=cfg["render"]["sss"])
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    alone.append(sorted(ts)[1])
    alone_cpu.append(sorted(cs)[1])
print(json.dumps({{"s_per_sample": wall / {n}, "cpu_per_sample": cpu / {n},
                  "render_call": parts.get("render", 0.0) / {n},
                  "render_alone": sorted(alone)[len(alone) // 2],
                  "render_alone_cpu": sorted(alone_cpu)[len(alone_cpu) // 2],
                  "labels": parts.get("label_images", 0.0) / {n},
                  "scene_update": parts.get("set_camera", 0.0) / {n},
                  "kernels_compiled": len(miss), "first": first,
                  "compile_s": sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0)
                                   for k in miss) / 1000.0}}))
"""


# one thread does everything, one part at a time: no prefetch, files written in place
CPU_PARTS = RENDERER + """cpu, wall = MethodTimer(clock=time.process_time), MethodTimer()
for owner, name in ((HeadScene, "render"), (HeadScene, "set_camera"), (lab, "label_images"),
                    (wk.SampleRenderer, "inputs"), (wk.SampleRenderer, "skin_maps"),
                    (wk.SampleRenderer, "groom"), (wk, "pose_groom"),
                    (wk.SampleRenderer, "scene_with_hair"), (wk, "write_exr"),
                    (wk, "_write_png"), (wk, "_write_rgb_png"), (wk, "write_json")):
    cpu.wrap(owner, name)
    wall.wrap(owner, name)
t0, c0 = time.perf_counter(), time.process_time()
for j in range(i, i + {n}):
    r.render(j)
t, c = (time.perf_counter() - t0) / {n}, (time.process_time() - c0) / {n}
r.close()
print(json.dumps({{"wall": t, "cpu": c, "first": i,
                  "parts_cpu": {{k: v / {n} for k, v in cpu.take().items()}},
                  "parts_wall": {{k: v / {n} for k, v in wall.take().items()}}}}))
"""


def cpu_parts(n: int, warm: int, size: int, spp: int, seed: int, bald: bool,
              out: str | None) -> None:
    """(e): where a sample's CPU seconds go (see the docstring)."""
    import subprocess

    here = str(Path(__file__).resolve().parents[1])
    code = CPU_PARTS.format(bench=str(Path(here) / "bench"), size=size, spp=spp, seed=seed,
                            warm=warm, n=n, bald=bald, background=False)
    d = json.loads(subprocess.run([sys.executable, "-c", code], cwd=here, check=True,
                                  capture_output=True, text=True).stdout.strip().splitlines()[-1])
    pc, pw = d["parts_cpu"], d["parts_wall"]
    cores = os.cpu_count() or 1
    files = sum(pc.get(k, 0.0) for k in ("write_exr", "_write_png", "_write_rgb_png", "write_json"))
    named = sum(pc.get(k, 0.0) for k in ("render", "set_camera", "label_images", "inputs",
                                         "scene_with_hair")) + files
    rw, rc = pw["render"], pc["render"]
    lines = [f"load average (1 min) before: {os.getloadavg()[0]:.1f}",
             (f"(e) CPU seconds a sample (all threads: Dr.Jit's and Embree's included), "
             f"{'bald (hair: none)' if bald else 'the default config (hair sampled)'}, {size} "
             f"px, {spp} spp, every part on the calling thread one at a time (no prefetch, "
             f"files written in place), samples {d['first']}..{d['first'] + n - 1} of seed "
             f"{seed}, a fresh process:"),
             (f"    total {d['cpu']:.3f} CPU s (wall {d['wall']:.3f} s); render call {rc:.3f} "
             f"(wall {rw:.3f}: {rc / rw:.2f} of {cores} cores busy); scene update (set_camera: "
             f"the acceleration structure rebuilt) {pc.get('set_camera', 0):.3f}; labels "
             f"{pc.get('label_images', 0):.3f}; inputs {pc.get('inputs', 0):.3f} (skin maps "
             f"{pc.get('skin_maps', 0):.3f}, groom grown or pooled {pc.get('groom', 0):.3f}, "
             f"groom posed {pc.get('pose_groom', 0):.3f}); the scene's hair swap "
             f"{pc.get('scene_with_hair', 0):.3f}; files {files:.3f} (EXR "
             f"{pc.get('write_exr', 0):.3f}); the rest {d['cpu'] - named:.3f}"),
             (f"    the render call keeps the cores busy, so a pipeline of these parts takes at "
             f"least its CPU seconds / {cores} cores: {d['cpu'] / cores:.3f} s = "
             f"{d['cpu'] / cores / rw:.2f}x the render call's wall; the render call, the scene "
             f"update and the labels alone (what every sample needs): "
             f"{(rc + pc.get('set_camera', 0) + pc.get('label_images', 0)) / cores / rw:.2f}x; "
             f"the render call and the scene update alone: "
             f"{(rc + pc.get('set_camera', 0)) / cores / rw:.2f}x (target <= 1.3x)"),
             f"load average (1 min) after: {os.getloadavg()[0]:.1f}"]
    for line in lines:
        print(line, flush=True)
    if out:
        res = {"title": "Where a dataset sample's CPU seconds go (issue 65)", **d,
               "cores": cores, "printed": lines}
        print(f"wrote {write_result(out, res)}")


GROOM = """
import dataclasses, hashlib, json, time
import numpy as np
import torch
from hack_render.dataset.config import load_config
from hack_render.dataset.sampling import model_kwargs, sample_spec
from hack_render.geometry import load_default_model
from hack_render.hair.groom import grow
from hack_render.hair.pose import pose_groom
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import HairStyle
model = load_default_model()
surface = HeadSurface.from_model(model)
cfg = load_config()
specs = [sample_spec(cfg, {seed}, i, model.au_names) for i in range({n})]
specs = [s for s in specs if s["hair"] is not None]
digest = hashlib.blake2b(digest_size=16)
grooms, t = [], {{"grow": [0.0, 0.0], "pose": [0.0, 0.0]}}
def timed(key, fn, *args):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    t[key][0] += time.perf_counter() - w
    t[key][1] += time.process_time() - c
    return out
for s in specs:
    g = timed("grow", grow, surface, HairStyle.from_dict(s["hair"]))
    for gr in g.groups:
        for f in dataclasses.fields(gr):
            a = getattr(gr, f.name)
            if isinstance(a, np.ndarray):
                digest.update(np.ascontiguousarray(a).tobytes())
    grooms.append(g)
for s, g in zip(specs, grooms):
    with torch.no_grad():
        v = model(**model_kwargs(model, s)).vertices[0].numpy().astype(np.float64)
    for a in timed("pose", pose_groom, g, v).values():
        digest.update(np.ascontiguousarray(a).tobytes())
print(json.dumps({{"grooms": len(specs), "strands": sum(g.num_strands for g in grooms),
                  "grow_s": t["grow"][0], "grow_cpu_s": t["grow"][1],
                  "pose_s": t["pose"][0], "pose_cpu_s": t["pose"][1],
                  "digest": digest.hexdigest()}}))
"""


def groom_cost(n: int, seed: int, before: str | None, out: str | None) -> None:
    """(d): see the module docstring."""
    import subprocess

    here = str(Path(__file__).resolve().parents[1])
    printed: list[str] = []
    results: dict = {"title": "Growing and posing the dataset's grooms (issue 65)", "runs": {}}
    for name, root in [("this", here)] + ([("before", before)] if before else []):
        env = dict(os.environ, PYTHONPATH=root)
        line = subprocess.run([sys.executable, "-c", GROOM.format(n=n, seed=seed)], cwd=root,
                              env=env, check=True, capture_output=True,
                              text=True).stdout.strip().splitlines()[-1]
        d = json.loads(line)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, check=False,
                                capture_output=True, text=True).stdout.strip()
        results["runs"][name] = dict(d, commit=commit)
        text = (f"  {name} ({commit}): {d['grooms']} grooms of samples 0..{n - 1} of seed {seed} "
                f"({d['strands']} strands): grow {d['grow_s']:.2f} s ({d['grow_cpu_s']:.2f} CPU "
                f"s), pose {d['pose_s']:.2f} s ({d['pose_cpu_s']:.2f} CPU s); digest "
                f"{d['digest']}")
        printed.append(text)
        print(text, flush=True)
    if before:
        same = results["runs"]["this"]["digest"] == results["runs"]["before"]["digest"]
        text = f"  the same grooms bit for bit: {same}"
        printed.append(text)
        print(text)
    if out:
        results["printed"] = printed
        print(f"wrote {write_result(out, results)}")


def steady(n: int, warm: int, size: int, spp: int, seed: int, before: str | None,
           out: str | None, grown: bool = False, bald: bool = False) -> None:
    import subprocess

    printed: list[str] = []

    def print(text: str, **kw) -> None:  # also kept for --out
        printed.append(text)
        builtins.print(text, **kw)

    here = str(Path(__file__).resolve().parents[1])
    print(f"load average (1 min) before: {os.getloadavg()[0]:.1f}")
    results: dict = {"title": "Datasets at render speed, bald (issue 65)" if bald else
                     "Datasets with hair at render speed (issue 65)", "runs": {}}
    what = ("the default config but hair: none (bald heads)" if bald else
            f"the default config (hair sampled, lod {load_config()['hair']['lod']:g})")
    print(f"(c) {what} at "
          f"{size} px, {spp} spp, as the serial executor runs it, {n} samples of seed {seed} "
          f"after at least {warm} warm-up samples and until every lighting preset has "
          f"rendered once, each checkout in a fresh process; the render call alone: each "
          f"preset's scene as its last sample left it, rendered again with nothing beside it "
          f"(median):")
    runs = [("this", here, False)] + ([("this, pool grown", here, True)] if grown else []) + \
        ([("before", before, False)] if before else [])
    for name, root, pregrown in runs:
        code = STEADY.format(bench=str(Path(here) / "bench"), size=size, spp=spp, seed=seed,
                             warm=warm, n=n, grown=pregrown, bald=bald, background=True)
        env = dict(os.environ, PYTHONPATH=root)
        line = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, check=True,
                              capture_output=True, text=True).stdout.strip().splitlines()[-1]
        d = json.loads(line)
        results["runs"][name] = d
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, check=False,
                                capture_output=True, text=True).stdout.strip()
        print(f"  {name} ({commit}), samples {d['first']}..{d['first'] + n - 1}: "
              f"{d['s_per_sample']:.2f} s/sample; render call "
              f"{d['render_call']:.2f} s (ratio {d['s_per_sample'] / d['render_call']:.2f}x, "
              f"target <= 1.3x); render call alone {d['render_alone']:.2f} s (ratio "
              f"{d['s_per_sample'] / d['render_alone']:.2f}x; its CPU "
              f"{d['render_alone_cpu']:.2f} s); labels {d['labels']:.2f} s; "
              f"scene update (in set_camera: "
              f"the sample's one acceleration-structure build) {d['scene_update']:.2f} s; "
              f"process CPU "
              f"{d['cpu_per_sample']:.2f} s/sample; kernels compiled anew "
              f"{d['kernels_compiled']} ({d['compile_s']:.1f} s)", flush=True)
    print(f"load average (1 min) after: {os.getloadavg()[0]:.1f}")
    if out:
        results["printed"] = printed
        builtins.print(f"wrote {write_result(out, results)}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sheet", default=None)
    ap.add_argument("--keep", default=None, help="(a): render the samples into this folder")
    ap.add_argument("--speed", action="store_true")
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--warm", type=int, default=2)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=25)
    ap.add_argument("--lod", type=float, action="append", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steady", action="store_true")
    ap.add_argument("--groom", action="store_true")
    ap.add_argument("--pool-grown", action="store_true",
                    help="(c): also run this checkout with the measured samples' pooled "
                    "grooms grown in the warm-up (a later stretch of a long dataset)")
    ap.add_argument("--bald", action="store_true", help="(c), (e): the config with hair: none")
    ap.add_argument("--cpu-parts", action="store_true")
    ap.add_argument("--before", default=None, help="(c), (d): another checkout to compare with")
    ap.add_argument("--out", default=None, help="(c), (d): also write what it prints, with commit")
    a = ap.parse_args()
    if a.sheet:
        sheet(Path(a.sheet), a.seed, a.keep, a.size)
    if a.steady:
        steady(a.n, a.warm, a.size, a.spp, a.seed, a.before, a.out, a.pool_grown, a.bald)
    if a.groom:
        groom_cost(a.n, a.seed, a.before, a.out)
    if a.cpu_parts:
        cpu_parts(a.n, a.warm, a.size, a.spp, a.seed, a.bald, a.out)
    if a.speed:
        speed(a.n, a.warm, a.size, a.spp, a.lod or [load_config()["hair"]["lod"]], a.seed)


if __name__ == "__main__":
    main()
