"""Benchmarks of the appearance model (ratios measured in one run; not a test).

    python bench/bench_appearance.py [--model PATH] [--batch 1] [--build-subjects 300]
                                     [--build-height 128] [--skip-build]

1. maps(alpha) at the model's resolution against one matrix product that reads the same
   basis bytes (alpha @ basis, same dtype, same process, same thread count): the ratio is
   the overhead of the gather (dilation), clamps and normal normalisation. Target <= 2x.
2. Build time and peak memory of ``build_model`` for N procedural subjects (default 300)
   at a given atlas height, in a child process so its peak RSS is its own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _timeit(fn, repeat: int = 20) -> float:
    fn()
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def bench_maps(model_path, batch: int) -> dict:
    from appearance.model import AppearanceModel

    m = AppearanceModel.load(model_path)
    alpha = m.sample_alpha(batch, seed=0)
    basis, mean = m.basis, m.mean
    with torch.no_grad():
        t_maps = _timeit(lambda: m.maps(alpha))
        t_mm = _timeit(lambda: torch.addmm(mean.unsqueeze(0), alpha, basis))
    return {"height": m.height, "components": m.n_components, "batch": batch,
            "basis_mb": round(basis.numel() * basis.element_size() / 2 ** 20, 2),
            "maps_ms": round(1e3 * t_maps, 3), "matmul_ms": round(1e3 * t_mm, 3),
            "ratio_maps_over_matmul": round(t_maps / t_mm, 3),
            "threads": torch.get_num_threads()}


def _build_child(n: int, height: int, workdir: str) -> None:
    """Child process: generate n subjects, build, print timings and peak RSS as JSON."""
    from appearance.builder import build_model
    from appearance.generator import generate_subject
    from appearance.texture_io import write_texture_set

    torch.set_num_threads(1)
    root = Path(workdir) / "pop"
    t0 = time.perf_counter()
    for s in range(n):
        ts = generate_subject(s, height)
        write_texture_set(root / f"s{s:05d}", {"diffuse": ts.diffuse, "specular": ts.specular,
                                               "roughness": ts.roughness, "normal": ts.normal})
    t_gen = time.perf_counter() - t0
    rss_gen = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t1 = time.perf_counter()
    rep = build_model(root, Path(workdir) / "m.npz", height=height, progress=False)
    t_build = time.perf_counter() - t1
    print(json.dumps({"subjects": n, "height": height, "generate_s": round(t_gen, 1),
                      "build_s": round(t_build, 1),
                      "peak_rss_mb_after_generation": round(rss_gen, 1),
                      "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                           / 1024, 1),
                      "heldout_last": {k: v[-1] for k, v in rep["heldout"].items()
                                       if isinstance(v, list)}}))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default=None)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--build-subjects", type=int, default=300)
    ap.add_argument("--build-height", type=int, default=128)
    ap.add_argument("--skip-build", action="store_true")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        _build_child(int(a.child[0]), int(a.child[1]), a.child[2])
        return
    torch.set_num_threads(1)
    out = {"maps_vs_matmul": [bench_maps(a.model, b) for b in sorted({1, a.batch, 4})]}
    print(json.dumps(out["maps_vs_matmul"], indent=1))
    if not a.skip_build:
        with tempfile.TemporaryDirectory() as wd:
            r = subprocess.run([sys.executable, __file__, "--child", str(a.build_subjects),  # noqa: PLW1510
                                str(a.build_height), wd], capture_output=True, text=True)
            if r.returncode:
                print(r.stderr[-3000:])
                raise SystemExit(r.returncode)
            out["build"] = json.loads(r.stdout.strip().splitlines()[-1])
            print(json.dumps(out["build"], indent=1))


if __name__ == "__main__":
    main()
