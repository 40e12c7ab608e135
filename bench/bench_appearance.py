"""Benchmarks of the appearance model (ratios measured in one run; not a test).

    python bench/bench_appearance.py [--model PATH] [--batch 1] [--build-subjects 300]
                                     [--build-height 128] [--skip-build] [--skip-maps]
                                     [--gen-height H] [--components K] [--workdir DIR]

    # the issue's scale check: 500 subjects at 1024 x 2048 within this machine's 24 GB
    python bench/bench_appearance.py --skip-maps --build-subjects 500 --build-height 1024 \
        --gen-height 128 --components 50 --workdir /tmp/app-scale

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

import numpy as np
import torch
from provenance import write_result  # bench/ is sys.path[0] when run as a script

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


def _generate_child(n: int, height: int, gen_height: int, workdir: str) -> None:
    """Child process: write n procedural subjects at ``height`` (skipping finished ones).

    With ``gen_height < height`` subjects are generated at ``gen_height`` and upsampled
    (bilinear), which keeps a scale test of the builder affordable; the maps then carry no
    detail finer than ``gen_height`` (the builder's memory and time do not depend on it).
    """
    from appearance.builder import resample
    from appearance.generator import generate_subject
    from appearance.texture_io import write_exr

    torch.set_num_threads(1)
    root = Path(workdir) / "pop"
    t0 = time.perf_counter()
    for s in range(n):
        folder = root / f"s{s:05d}"
        if (folder / "normal.exr").is_file():
            continue
        ts = generate_subject(s, gen_height)
        folder.mkdir(parents=True, exist_ok=True)
        for name in ("diffuse", "specular", "roughness", "normal"):  # normal last: "done"
            img = resample(getattr(ts, name), height)
            if name == "normal":
                img = img / np.linalg.norm(img, axis=-1, keepdims=True)
            write_exr(folder / f"{name}.exr", img, half=True)
    print(json.dumps({"generate_s": round(time.perf_counter() - t0, 1)}))


def _build_child(n: int, height: int, components: int, workdir: str) -> None:
    """Child process: build from the generated subjects; its peak RSS is the build's own."""
    from appearance.builder import build_model

    torch.set_num_threads(1)
    t1 = time.perf_counter()
    rep = build_model(Path(workdir) / "pop", Path(workdir) / "m.npz", height=height,
                      n_components=components or None, progress=False,
                      workdir=Path(workdir) / "work")
    print(json.dumps({"subjects": n, "height": height, "components": rep.get("n_components"),
                      "build_s": round(time.perf_counter() - t1, 1),
                      "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                           / 1024, 1),
                      "heldout_last": {k: v[-1] for k, v in rep.get("heldout", {}).items()
                                       if isinstance(v, list)}}))


def _run_child(*args) -> dict:
    r = subprocess.run([sys.executable, __file__, *map(str, args)], capture_output=True,  # noqa: PLW1510
                       text=True)
    if r.returncode:
        print(r.stderr[-3000:])
        raise SystemExit(r.returncode)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default=None)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--build-subjects", type=int, default=300)
    ap.add_argument("--build-height", type=int, default=128)
    ap.add_argument("--skip-build", action="store_true")
    ap.add_argument("--gen-height", type=int, default=None,
                    help="generate subjects at this height and upsample (scale tests)")
    ap.add_argument("--components", type=int, default=0, help="components kept (0 = all)")
    ap.add_argument("--workdir", default=None, help="keep subjects here (resumable)")
    ap.add_argument("--skip-maps", action="store_true")
    ap.add_argument("--out", default=None, help="also write the results, with commit, date, "
                    "machine and command, e.g. bench/results/appearance.json")
    ap.add_argument("--child-gen", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--child-build", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child_gen:
        _generate_child(int(a.child_gen[0]), int(a.child_gen[1]), int(a.child_gen[2]), a.child_gen[3])
        return
    if a.child_build:
        _build_child(int(a.child_build[0]), int(a.child_build[1]), int(a.child_build[2]), a.child_build[3])
        return
    torch.set_num_threads(1)
    out = {}
    if not a.skip_maps:
        out["maps_vs_matmul"] = [bench_maps(a.model, b) for b in sorted({1, a.batch, 4})]
        print(json.dumps(out["maps_vs_matmul"], indent=1))
    if not a.skip_build:
        with tempfile.TemporaryDirectory() as tmp:
            wd = a.workdir or tmp
            gen = _run_child("--child-gen", a.build_subjects, a.build_height,
                             a.gen_height or a.build_height, wd)
            out["build"] = {**gen, **_run_child("--child-build", a.build_subjects,
                                                a.build_height, a.components, wd)}
            print(json.dumps(out["build"], indent=1))
    if a.out:
        write_result(a.out, out)


if __name__ == "__main__":
    main()
