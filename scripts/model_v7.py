"""Model version 7 from the continuation of version 6 that `learn pose` writes: the same
arrays, the version number and the provenance line of the pose correctives brought up to date.

    hack-render learn pose --model V6.npz --continue --keep-weights -o CONT.npz ... \
        --corner-poses 0.25 --loss anchor=0.05       (the full command: docs/model.md)
    python scripts/model_v7.py CONT.npz hack_render/data/hack_default.npz \
        [--mp bench/results/mp_heldout.json ...]

``--mp`` (run on the written file, then this script again on the same input) puts M_P's
held-out ratios into the metadata (``bench/bench_mp_heldout.py``), as ``model_v6.py`` does.
A later continuation of version 7 is labelled the same way with ``--version 8 --note TEXT``
(TEXT: how it was made; ``{it}``, ``{corner}``, ``{anchor}``, ``{bound}``, ``{margin}``,
``{ids}``, ``{poses}`` are filled from the file's last run).
"""

from __future__ import annotations

import argparse

from model_v6 import record_mp

from hack_render.geometry.model_file import load_model_file, save_model_file

V7_NOTE = (
    "This file (model version 7): version 6 (whose correctives are version 5's) continued "
    "{it} steps with a quarter of the whole-head poses drawn near the corners of the "
    "per-axis box (corner_poses {corner}), a trust region on P and C around version 6's "
    "(anchor {anchor} per cm^2), the term on stretch above the pose's physical lower bound "
    "raised (bound {bound}, margin {margin}) and {ids} identities x {poses} poses mined a round "
    "(docs/model.md, 'Model version 7'; the command is learn.pose.command).")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", help="version 6 continued by `learn pose --continue` (still "
                    "labelled model version 6)")
    ap.add_argument("out", help="where to write version 7")
    ap.add_argument("--mp", nargs="*", default=[], help="bench/bench_mp_heldout.py's results "
                    "on the new file: the trained-weights seeds first, then the default-weights run")
    ap.add_argument("--version", type=int, default=7, help="the model version to write (a "
                    "later continuation of version 7: 8)")
    ap.add_argument("--note", help="the provenance sentence on how this file was made "
                    "(default: version 7's)")
    args = ap.parse_args()
    arrays, meta = load_model_file(args.source)
    pose = meta["learn"]["pose"]
    if meta.get("model_version") not in (6, 7, args.version) or "corner_poses" not in pose:
        raise SystemExit("expected version 6 continued with --corner-poses, found model version "
                         f"{meta.get('model_version')}")
    text6 = meta["provenance"]["pose_blendshapes"]
    w = pose["loss_weights"]
    meta["model_version"] = args.version
    head = (
        "optimised (not captured): generic P, 8 personalised components and the M_P MLP minimise "
        "the neck skin's deformation energy under LBS (strain, stretch and compression tails, "
        "folds, bending, never worse than plain LBS, the stretch above the pose's physical lower "
        "bound) over poses sampled from the whole joint space, with hard examples mined; each "
        "joint's corrective gated by its angle (12 degrees) and the chain's net rotation (weight "
        "0.3; model format 4); hack_render.learn.pose_energy. ")
    if "This file (model version" in text6:
        head = text6[:text6.index("This file (model version")]
    meta["provenance"]["pose_blendshapes"] = head + (args.note or V7_NOTE).format(
        it=pose["iterations"], corner=pose["corner_poses"], anchor=w["anchor"], bound=w["bound"],
        margin=w["bound_margin"], ids=pose.get("mine_identities"), poses=pose.get("mine_poses"))
    if args.mp:
        record_mp(meta, args.mp)
    save_model_file(args.out, arrays, meta)
    print(f"wrote {args.out}: model version {args.version}")


if __name__ == "__main__":
    main()
