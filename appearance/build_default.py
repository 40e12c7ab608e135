"""Rebuild the shipped default appearance model from the procedural population.

    python -m appearance.build_default [--subjects 400] [--height 256] [--components 36]

Generates subjects 0..N-1 with :func:`appearance.generator.generate_subject` (calibrated
constants from ``data/calibration.json``), writes them as EXR texture sets to a
temporary folder, builds the model with the ordinary builder (the same code path as
``hack-render learn appearance``), stores the basis as int8 so the file stays under
30 MB, and writes ``data/default_appearance.npz``, its report (``.report.json``,
``.report.png``) and the provenance file ``data/default_appearance.json``. The data is
procedural: no captured textures are involved.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from appearance.builder import build_model
from appearance.generator import generate_subject
from appearance.model import DEFAULT_MODEL
from appearance.population import CALIBRATION_FILE, load_calibration
from appearance.texture_io import write_texture_set
from hack_render.io import write_json

SIZE_LIMIT_MB = 30.0


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except Exception:  # not a git checkout (installed package)
        return "unknown"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subjects", type=int, default=400)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--components", type=int, default=36)
    ap.add_argument("--basis-dtype", default="int8", choices=["int8", "float16", "float32"])
    ap.add_argument("--out", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--workdir", type=Path, default=None, help="where the population is written")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)

    cal = load_calibration()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hack-appearance-pop-", dir=a.workdir) as wd:
        for s in tqdm(range(a.subjects), desc="generate procedural subjects"):
            ts = generate_subject(s, a.height, cal)
            write_texture_set(Path(wd) / f"subject_{s:05d}",
                              {"diffuse": ts.diffuse, "specular": ts.specular,
                               "roughness": ts.roughness, "normal": ts.normal})
        t_gen = time.perf_counter() - t0
        meta = {"kind": "procedural",
                "description": "procedural skin population from a calibrated two-layer "
                               "biophysical model (no captured textures)",
                "generator": "appearance.generator.generate_subject",
                "seeds": [0, a.subjects - 1], "calibration": load_calibration().fit,
                "command": f"python -m appearance.build_default --subjects {a.subjects} "
                           f"--height {a.height} --components {a.components} "
                           f"--basis-dtype {a.basis_dtype}",
                "template": "ICT-FaceKit generic_neutral_mesh.obj (MIT)"}
        t1 = time.perf_counter()
        report = build_model(wd, a.out, height=a.height, n_components=a.components,
                             basis_dtype=a.basis_dtype, metadata=meta)
        t_build = time.perf_counter() - t1
    size_mb = a.out.stat().st_size / 2 ** 20
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    cum = report["cumulative_explained_variance"]
    prov = {"kind": "procedural", "model": a.out.name, "size_mb": round(size_mb, 2),
            "size_limit_mb": SIZE_LIMIT_MB, "n_subjects": a.subjects, "height": a.height,
            "n_components": report["n_components"], "basis_dtype": a.basis_dtype,
            "explained_variance_at_k": round(float(cum[report["n_components"] - 1]), 4),
            "generate_seconds": round(t_gen, 1), "build_seconds": round(t_build, 1),
            "peak_rss_mb": round(peak_mb, 1), "git_commit": _git_commit(),
            "calibration_file": CALIBRATION_FILE.name, **meta}
    write_json(a.out.with_suffix(".json"), prov, indent=1)
    print(json.dumps({k: prov[k] for k in ("size_mb", "n_subjects", "height", "n_components",
                                           "explained_variance_at_k", "generate_seconds",
                                           "build_seconds", "peak_rss_mb")}, indent=1))
    print("held-out:", json.dumps(report.get("heldout"), indent=None))
    if size_mb > SIZE_LIMIT_MB:
        raise SystemExit(f"model is {size_mb:.1f} MB > {SIZE_LIMIT_MB} MB: use fewer "
                         f"--components or a smaller --height")
    return prov


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
