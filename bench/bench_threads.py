"""Thread policy benchmark (not a test): OpenMP wait policy x torch threads x other load.

Each configuration runs in a fresh child process (the wait policy is read once, when torch
loads its OpenMP runtime), as rounds that rotate the configurations' order so that the
machine's other load hits each alike; every child reports the median of ``--repeats``
calls of each workload after one warm-up call, and the table gives, per configuration,
the median over rounds with the range of the round medians.

Configurations: ``OMP_WAIT_POLICY`` unset ("default": libgomp's, idle threads spin a while
before they sleep; the child imports torch before the package, whose default is PASSIVE) or
PASSIVE (idle threads sleep; the package's default since issue 65), torch intra-op threads
1 or every core; each alone and beside ``--hogs`` CPU-bound processes (``while True:
pass``), started and stopped by this script.

Workloads (the library's CPU paths that use torch threads, and a render):

* ``fwd B=1 S=20`` / ``S=100``: ``HackModel.forward``, B = 1, 20 or 100 shape components,
  dense random psi, head pose, larynx (bench_geometry.py's inputs);
* ``smplx B=1 S=20``: smplx's ``lbs`` on the same arrays (when smplx is installed);
* ``fwd B=64``: B = 64 distinct identities;
* ``fit step``: the fitter's torch side of an iteration: a B = 1 forward + backward into
  beta, psi and theta, and A(alpha)'s maps at 128 px (the fitter's atlas level) +
  backward into alpha;
* ``render``: ``HeadScene.render`` at 128 px, 16 spp, studio rig (Dr.Jit threads: every
  core; after a forward, so torch's idle threads are what the render runs beside).

    python bench/bench_threads.py [--rounds 3] [--repeats 9] [--hogs 1]
                                  [--out bench/results/threads.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
WORKLOADS = ("fwd B=1 S=20", "fwd B=1 S=100", "smplx B=1 S=20", "fwd B=64", "fit step",
             "render")


def child(repeats: int, threads: int) -> dict:
    """Run in a fresh process: time every workload; returns {name: median seconds}.
    Imports torch first: its OpenMP runtime starts with the environment as given."""
    import torch

    sys.path.insert(0, str(HERE))
    from bench_geometry import smplx_arrays

    from appearance.model import AppearanceModel
    from hack_render.geometry import distribute_head_rotation, load_default_model
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes import cameras, lights

    torch.set_num_threads(threads)
    model = load_default_model()
    gen = torch.Generator().manual_seed(0)
    fns = {}

    def inputs(b, s):
        beta = torch.randn(b, s, generator=gen)
        psi = torch.rand(b, model.num_expressions, generator=gen)
        theta = distribute_head_rotation(0.3 * torch.randn(b, 3, generator=gen))
        go = 0.1 * torch.randn(b, 3, generator=gen)
        return {"beta": beta, "psi": psi, "theta": theta, "global_orient": go,
                "eta": 0.5 + torch.rand(b, generator=gen),
                "tau": 0.005 * torch.randn(b, generator=gen)}

    for name, b, s in (("fwd B=1 S=20", 1, 20), ("fwd B=1 S=100", 1, 100), ("fwd B=64", 64, 100)):
        kw = inputs(b, s)
        fns[name] = lambda kw=kw: model(**kw)
    try:
        from smplx.lbs import lbs as smplx_lbs

        sx = smplx_arrays(model)
        s = 20
        sx["shapedirs"] = torch.cat([sx["shapedirs"][..., :s],
                                     sx["shapedirs"][..., model.num_shape:]], -1).contiguous()
        kw = inputs(1, s)
        betas = torch.cat([kw["beta"], kw["psi"]], 1)
        pose = torch.cat([kw["global_orient"][:, None], kw["theta"]], 1).reshape(1, -1)
        fns["smplx B=1 S=20"] = lambda: smplx_lbs(betas, pose, **sx)
    except ImportError:
        pass
    app = AppearanceModel.load().downsampled(128)
    kw = {k: v.clone().requires_grad_(k in ("beta", "psi", "theta")) for k, v in inputs(1, 20).items()}
    alpha = torch.zeros(1, 20, requires_grad=True)

    def fit_step():
        with torch.enable_grad():
            model(**kw).vertices.sum().backward()
            m = app.maps(alpha)
            (m.diffuse.sum() + m.specular.sum() + m.roughness.sum() + m.normal.sum()).backward()

    topo = Topology.from_model(model)
    cam = cameras.orbit(128, 128, 85.0, 20.0, 5.0)
    with torch.no_grad():
        v0 = model().vertices[0].numpy()
    head = HeadScene(topo, v0, lights.preset("studio", 0.0, 0.0), cam,
                     RenderSettings(128, 128, 16, 8, 0))
    fwd = fns["fwd B=1 S=20"]

    def render():
        with torch.no_grad():
            fwd()  # torch's threads have just worked: the render runs beside them idling
        head.render(seed=1, backdrop=False)

    out = {}
    with torch.no_grad():
        for name, fn in fns.items():
            fn()
            ts = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                fn()
                ts.append(time.perf_counter() - t0)
            out[name] = statistics.median(ts)
    for name, fn, reps in (("fit step", fit_step, repeats), ("render", render, max(3, repeats // 3))):
        fn()
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        out[name] = statistics.median(ts)
    return out


def run_child(policy: str | None, threads: int, repeats: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    # unset: libgomp's default (idle threads spin a while, then sleep); the child imports
    # torch before the package, so the package's PASSIVE default does not apply there
    if policy != "default":
        env["OMP_WAIT_POLICY"] = policy
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    cmd = [sys.executable, __file__, "--child", "--repeats", str(repeats), "--threads", str(threads)]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900, check=False)
    if res.returncode:
        raise SystemExit(f"child failed ({policy}, {threads}):\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--hogs", type=int, default=1, help="CPU-bound processes of the loaded runs")
    ap.add_argument("--threads", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help="also write what it prints, with provenance, "
                    "e.g. bench/results/threads.json")
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.repeats, a.threads)))
        return
    sys.path.insert(0, str(HERE))
    from provenance import recorded

    with recorded(a.out, "Threads: OpenMP wait policy x torch threads x load (issue 65)"):
        run_table(a)


def run_table(a) -> None:
    """The parent's run: every configuration in child processes, rounds rotating."""
    cores = os.cpu_count() or 1
    configs = [(p, t) for p in ("default", "PASSIVE") for t in sorted({1, cores})]
    loads = ("alone", f"+{a.hogs} CPU-bound")
    table: dict = {f"{p} {t}t {ld}": {w: [] for w in WORKLOADS} for p, t in configs for ld in loads}
    load_avg = [os.getloadavg()[0]]
    for r in range(a.rounds):
        for li, ld in enumerate(loads):
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(a.hogs if li else 0)]
            try:
                k = (r + li) % len(configs)
                for p, t in configs[k:] + configs[:k]:
                    got = run_child(p, t, a.repeats)
                    for w, v in got.items():
                        table[f"{p} {t}t {ld}"][w].append(v)
                    print(f"round {r} {ld:14s} {p:7s} {t}t: " + ", ".join(
                        f"{w} {1e3 * v:.1f} ms" for w, v in got.items()), flush=True)
            finally:
                for h in hogs:
                    h.kill()
                    h.wait()
        load_avg.append(os.getloadavg()[0])
    print(f"\n{cores} cores; medians over {a.rounds} rounds [range of round medians], ms; "
          f"1-min load average {min(load_avg):.1f}..{max(load_avg):.1f} (other jobs included)")
    names = [w for w in WORKLOADS if any(table[c][w] for c in table)]
    print(f"{'configuration':30s}" + "".join(f"{w:>22s}" for w in names))
    summary = {}
    for c, rows in table.items():
        cells, summary[c] = [], {}
        for w in names:
            v = rows[w]
            med = statistics.median(v)
            summary[c][w] = {"median_ms": 1e3 * med, "min_ms": 1e3 * min(v), "max_ms": 1e3 * max(v)}
            cells.append(f"{1e3 * med:8.1f} [{1e3 * min(v):.0f}..{1e3 * max(v):.0f}]")
        print(f"{c:30s}" + "".join(f"{x:>22s}" for x in cells))
    if "smplx B=1 S=20" in names:
        print("\nforward / smplx at B=1, S=20 (same process): " + ", ".join(
            f"{c}: {summary[c]['fwd B=1 S=20']['median_ms'] / summary[c]['smplx B=1 S=20']['median_ms']:.2f}x"
            for c in table))


if __name__ == "__main__":
    main()
