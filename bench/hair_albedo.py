"""The hair layer's colour calibration: the albedo of a thick slab of strands rendered by
this project's renderer (Mitsuba's ``hair`` BSDF, a white constant environment) for a grid
of eumelanin and pheomelanin concentrations. Writes ``hack_render/data/hair_albedo.json``,
which ``hair.style.slab_albedo`` / ``albedo_melanin`` interpolate (the fitter turns a
photo's hair colour into melanin with it).

    python bench/hair_albedo.py [--spp 64] [--size 40]

Derived data: every number in the file is measured by this script (its metadata says so).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

EUMELANIN = [0.0, 0.05, 0.1, 0.2, 0.3, 0.45, 0.7, 1.0, 1.3, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0]
PHEOMELANIN = [0.0, 0.1, 0.25, 0.5, 1.0, 1.6, 2.5, 4.0, 8.0]


def slab(path: Path, strands: int = 16000, k: int = 6, seed: int = 0) -> None:
    """A 6 x 10 cm slab of strands, 1 cm deep, running along y (0.06 mm radius)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.03, 0.03, strands)
    z = rng.uniform(-0.01, 0.0, strands)
    t = np.linspace(-0.05, 0.05, k)
    pts = np.zeros((strands, k, 4))
    pts[..., 0] = x[:, None] + rng.normal(0, 0.002, (strands, k))
    pts[..., 1] = t[None]
    pts[..., 2] = z[:, None] + rng.normal(0, 0.0005, (strands, k))
    pts[..., 3] = 6e-5
    path.write_text((("%.6f %.6f %.6f %.7f\n" * k) + "\n") * strands % tuple(pts.ravel()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=40)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] /
                    "hack_render" / "data" / "hair_albedo.json")
    args = ap.parse_args()
    import mitsuba as mi

    from hack_render.render.engine import ensure_variant

    ensure_variant(None)
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        curves = Path(tmp) / "slab.txt"
        slab(curves)
        table = np.zeros((len(EUMELANIN), len(PHEOMELANIN), 3))
        for i, eu in enumerate(EUMELANIN):
            for j, pheo in enumerate(PHEOMELANIN):
                scene = mi.load_dict({
                    "type": "scene", "integrator": {"type": "path", "max_depth": 32},
                    "sensor": {"type": "orthographic",
                               "to_world": mi.ScalarTransform4f().look_at(
                                   origin=[0, 0, 0.3], target=[0, 0, 0], up=[0, 1, 0])
                               @ mi.ScalarTransform4f().scale([0.02, 0.02, 1]),
                               "film": {"type": "hdrfilm", "width": args.size,
                                        "height": args.size, "rfilter": {"type": "box"}},
                               "sampler": {"type": "independent",
                                           "sample_count": args.spp}},
                    "env": {"type": "constant", "radiance": 1.0},
                    "hair": {"type": "bsplinecurve", "filename": str(curves),
                             "bsdf": {"type": "hair", "eumelanin": eu,
                                      "pheomelanin": pheo}}})
                img = np.asarray(mi.render(scene, seed=i * 100 + j))[..., :3]
                table[i, j] = img.reshape(-1, 3).mean(0)
    out = {"meta": {"what": "albedo (linear RGB) of a 1 cm slab of strands (0.06 mm radius) "
                            "under a white constant environment, seen from above, by "
                            "Mitsuba's hair BSDF at its default roughness",
                    "derived": "measured by bench/hair_albedo.py (rendered, not from "
                               "literature)",
                    "spp": args.spp, "size": args.size, "mitsuba": mi.__version__,
                    "seconds": round(time.time() - t0, 1)},
           "eumelanin": EUMELANIN, "pheomelanin": PHEOMELANIN,
           "albedo": np.round(table, 5).tolist()}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out} in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
