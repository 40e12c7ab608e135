"""Model version 8: version 7 with the flexion block (model format 5), fitted to ARAP and
applied at a fraction of the fit (``hack_render.learn.flex_learn``; the fraction and the
knots chosen on validation pairs of their own, ``bench/bench_flexion_block.py --scales``;
docs/model.md, "Model version 8"). Every other array is version 7's, unchanged.

    python scripts/model_v8.py V7.npz hack_render/data/hack_default.npz \
        [--scale 0.3 --knots=-80,80 --identities 40]

Fitting runs ARAP on ``--identities`` x 35 poses: ~5 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time

import torch

from hack_render.geometry.model_file import load_model_file, save_model_file
from hack_render.learn.flex_learn import (
    COHERENCE,
    PURITY_DEG,
    RIDGE,
    STEP_DEG,
    fit_flex_block,
    knots_deg,
    training_poses,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", help="model version 7, or a file of `learn pose` (no flexion "
                    "block)")
    ap.add_argument("out", help="where to write version 8")
    ap.add_argument("--scale", type=float, default=0.3, help="the fraction of the fit applied")
    ap.add_argument("--knots", default="-80,80", help="the outermost knots, degrees")
    ap.add_argument("--identities", type=int, default=40)
    ap.add_argument("--coherence", type=float, default=COHERENCE, help="the power of the "
                    "joints' flexion coherence (0: off)")
    ap.add_argument("--seed", type=int, default=777)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    arrays, meta = load_model_file(args.source)
    if any(k.startswith("flex_") for k in arrays):
        raise SystemExit(f"{args.source} already has a flexion block: give the file it was "
                         "fitted over (model version 7), or one `learn pose` wrote")
    lo, hi = (float(x) for x in args.knots.split(","))
    knots = knots_deg(lo, hi)
    t0 = time.time()
    arrays.update(fit_flex_block(arrays, knots, args.scale, identities=args.identities,
                                 seed=args.seed, coherence=args.coherence,
                                 report=lambda s: print(s, flush=True)))
    seconds = time.time() - t0
    meta["model_version"] = 8
    meta.setdefault("provenance", {})["flexion_block"] = (
        f"fitted (not captured): the ridge least-squares fit (ridge {RIDGE}) of ARAP's "
        f"rest-space residual over version 7's posed skin (ARAP with the skin's rigid sets) on "
        f"{args.identities} identities beta ~ N(0, I) (20 shape weights, seed {args.seed}) x "
        f"{len(training_poses())} whole-head flexion/extension poses (-70 to 66 degrees), hats "
        f"every {STEP_DEG:g} degrees over the net flexion angle (knots {lo:g} to {hi:g}, none at "
        f"0) times exp(-(off-axis / {PURITY_DEG:g} deg)^2) times the joints' flexion "
        f"coherence to the power {args.coherence:g}, linear in beta; applied at "
        f"{args.scale:g} of the fit (chosen on validation pairs: bench/bench_flexion_block.py "
        "--scales; docs/model.md, 'Model version 8'); hack_render.learn.flex_learn.")
    meta.setdefault("learn", {})["flex"] = {
        "scale": args.scale, "knots_deg": [float(k) for k in knots], "step_deg": STEP_DEG,
        "purity_deg": PURITY_DEG, "coherence": args.coherence, "ridge": RIDGE,
        "identities": args.identities,
        "seed": args.seed, "train_poses": len(training_poses()), "seconds": round(seconds, 1),
        "command": " ".join(["python", *sys.argv])}
    errors = save_model_file(args.out, arrays, meta)
    print(f"wrote {args.out}: model version 8 (flex_basis quantisation error "
          f"{errors.get('flex_basis', 0.0) * 1e6:.2f} um; fit {seconds:.0f} s)")


if __name__ == "__main__":
    main()
