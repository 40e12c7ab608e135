"""Model version 6 from version 5: M_E's personal part tapered over its vertex subset's outer
rings (``hack_render.learn.expression_learn.taper_personal``), every other array as it was.

    python scripts/model_v6.py V5.npz hack_render/data/hack_default.npz \
        [--seam bench/results/expression_seam.json] [--mp bench/results/mp_heldout.json ...]

``--seam`` and ``--mp`` (run on the written file, then this script again on the same input)
put the measured figures into the metadata: the expression ablation of the new file and
M_P's held-out ratios (``bench/bench_expression_seam.py``, ``bench/bench_mp_heldout.py``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hack_render.geometry.model_file import load_model_file, save_model_file
from hack_render.learn.expression_learn import TAPER_RINGS, taper_personal

SEAM_NOTE = (
    " Model version 6: the personal part ramps down over the subset's outer {k} rings from the "
    "skin outside it (ring r of {k}: r / {k1}; 285 of the 1500 vertices), where version 5 cut "
    "it to zero in one step across 219 seam edges (under a smile with the jaw open, a "
    "submental edge of one of the pose bench's identities shrank to 22 % of its neutral "
    "length, deformation transfer's 69 %; bench/bench_expression_seam.py).")


def record_mp(meta: dict, paths: list[str]) -> None:
    """M_P's held-out figures (bench/bench_mp_heldout.py on the written file: the trained-weights
    seeds first, then the default-weights run) into ``learn.pose.mp_heldout`` and the
    pose_blendshapes provenance line (replacing an earlier such sentence)."""
    prov = meta["provenance"]
    sets = [json.loads(Path(p).read_text()) for p in paths]
    first = sets[0]
    keep = ("summary", "identities", "seed", "poses_per_identity", "command", "commit",
            "weights", "loss_weights", "single_axis_head_poses")
    held = {k: first[k] for k in keep if k in first}
    trained_w = lambda s: "loss_weights" in str(s.get("weights"))
    held["other_sets"] = {f"{s.get('seed')}" + ("" if trained_w(s) else " (default weights)"):
                          {k: s[k] for k in ("summary", "seed", "weights", "command", "commit") if k in s}
                          for s in sets[1:]}
    meta["learn"]["pose"]["mp_heldout"] = held
    text = prov["pose_blendshapes"]
    mark = " M_P on held-out identities (bench/bench_mp_heldout.py"
    cut = text.index(mark) if mark in text else len(text)
    trained = [s for s in sets if trained_w(s)]
    other = [s for s in sets if not trained_w(s)]
    lower = sum(s["summary"]["lower_with_mp"] for s in trained)
    text = text[:cut] + (
        " M_P on held-out identities (bench/bench_mp_heldout.py, on this file; the energy its "
        "correctives were learned with: learn.pose.loss_weights and its head-pose sampler), the "
        "energy with M_P over the energy with its mean output, "
        f"{len(trained)} sets of {first['summary'].get('identities', 10)} identities (seeds "
        + ", ".join(str(s["seed"]) for s in trained) + "): "
        + "; ".join(f"median {s['summary']['ratio_median']:.3f} ({s['summary']['ratio_min']:.3f}-"
                    f"{s['summary']['ratio_max']:.3f}), lower on {s['summary']['lower_with_mp']} of 10"
                    for s in trained)
        + f" ({lower} of {10 * len(trained)} lower)"
        + "".join(f"; with the learner's default weights instead (seed {s['seed']}): median "
                  f"{s['summary']['ratio_median']:.3f}, lower on {s['summary']['lower_with_mp']} of 10"
                  for s in other) + ".")
    prov["pose_blendshapes"] = text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", help="the version 5 model file")
    ap.add_argument("out", help="where to write version 6")
    ap.add_argument("--rings", type=int, default=TAPER_RINGS)
    ap.add_argument("--seam", help="bench/bench_expression_seam.py's results on the new file")
    ap.add_argument("--mp", nargs="*", default=[], help="bench/bench_mp_heldout.py's results "
                    "on the new file: the trained-weights seeds first, then the default-weights run")
    args = ap.parse_args()
    arrays, meta = load_model_file(args.source)
    if meta.get("model_version") != 5:
        raise SystemExit(f"expected model version 5, found {meta.get('model_version')}")
    faces, n = arrays["faces"], len(arrays["template_vertices"])
    arrays = taper_personal(arrays, faces, n, args.rings)
    meta["model_version"] = 6
    prov = meta["provenance"]
    prov["personalised_expressions"] += SEAM_NOTE.format(k=args.rings, k1=args.rings + 1)
    prov["pose_blendshapes"] = prov["pose_blendshapes"].replace(
        "This file (model version 5):", "This file (model version 6; its correctives are "
        "version 5's):")
    ex = meta["learn"]["expressions"]
    ex["taper_rings"] = args.rings
    if args.seam:
        res = json.loads(Path(args.seam).read_text())
        mine = next(v for k, v in res["models"].items() if Path(k).resolve() == Path(args.out).resolve())
        ex["ablation_mm_version5"] = ex.get("ablation_mm_version5", ex["ablation_mm"])
        ex["ablation_mm"] = dict(mine["ablation_mm"], moving_vertices=ex["ablation_mm_version5"]["moving_vertices"])
        ex["ablation_source"] = (
            "bench/bench_expression_seam.py on this file: the learner's 30 held-out identities, "
            "deformation transfer onto the file's template and shape space (the learner's own "
            "report on version 5 is ablation_mm_version5; the bench measures version 5 within "
            "0.3 % of it)")
        ex["seam"] = {"edge": mine["edge"], "command": res.get("command"), "commit": res.get("commit"),
                      "bench_expression_min_edge_ratio": mine["bench_expression_min_edge_ratio"]}
    if args.mp:
        record_mp(meta, args.mp)
    save_model_file(args.out, arrays, meta)
    print(f"wrote {args.out}: model version 6, M_E tapered over {args.rings} rings")


if __name__ == "__main__":
    main()
