"""Pose-space stress test of the neck (issue 21; a benchmark, not a test).

Samples poses over the whole joint space (:func:`hack_render.geometry.deformation.
sample_pose_space`: every joint uniform within its limits, and whole-head rotations shared
out by ``distribute_head_rotation`` up to each axis's full range, singly and combined) for
identities beta ~ N(0, I) (20 components), with and without an expression, and measures
per model the largest skin-edge stretch and compression per pose (median / p99 / max over
poses) and the folded skin triangles, for

* plain LBS: the model without pose correctives,
* the previous shipped model (a model file from git history, ``--previous REV``),
* the shipped model (or ``--model``),

on all pairs and on those within the whole neck's active range
(:data:`hack_render.geometry.anatomy.ACTIVE_RANGE_DEG`, a coupling of the joints: the
sampled box lets every joint reach its limit at once; ``"active"`` and
``"<family>_active"`` entries), and, per pose, the lower bound on the largest stretch that
any deformer keeping the face rigid with the skull and the chest rim with the thorax must
reach (:func:`hack_render.geometry.deformation.stretch_lower_bound`): how many pose-identity
pairs no corrective or weighting can bring within the issue's targets (stretch <= 35 % /
60 %), and each model's stretch above the bound.

    python bench/bench_pose_space.py --threads 2             # 2,000 poses x 10 identities
    python bench/bench_pose_space.py --poses 400 --identities 3 --out /tmp/p.json
    python bench/bench_pose_space.py --bound-only            # the bound alone, merged into
                                                             # the results file's run

Writes ``bench/results/pose_space.json`` (commit, date, machine, command first).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import ROOT, write_result

from hack_render.geometry.anatomy import ACTIVE_RANGE_DEG, within_active_range
from hack_render.geometry.deformation import (
    model_deformation,
    model_stretch_bound,
    rigid_anchors,
    sample_pose_space,
    skin_topology,
)
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import load_model_file
from hack_render.geometry.model_file import without_correctives as lbs_arrays

#: the expression held over the poses in the "with expression" configuration
EXPRESSION = "mouthSmile_L=0.8, mouthSmile_R=0.8, jawOpen=0.5, browDown_L=0.4, browDown_R=0.4"


def model_from_git(rev: str, path: str = "hack_render/data/hack_default.npz") -> HackModel:
    """The model file as it was at ``rev``."""
    data = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, capture_output=True,
                          check=True).stdout
    with tempfile.NamedTemporaryFile(suffix=".npz") as f:
        f.write(data)
        f.flush()
        return HackModel(*load_model_file(f.name))


def without_correctives(model_path) -> HackModel:
    """The same model with its pose correctives (generic, personalised, the flexion block) removed."""
    arrays, meta = load_model_file(model_path)
    return HackModel(lbs_arrays(arrays), meta)


#: the issue's stretch targets: p99 and max of the largest skin-edge stretch per pose
TARGETS = (0.35, 0.60)


def summarise_bound(bound: np.ndarray) -> dict:
    """Median / p99 / max of the per-pose stretch lower bound, and the pairs above each
    target (no deformer with the model's rigid rows can meet the target on them)."""
    return {"poses": int(bound.size), "median": float(np.median(bound)),
            "p99": float(np.quantile(bound, 0.99)), "max": float(bound.max()),
            "poses_above": {f"{t:.2f}": int((bound > t).sum()) for t in TARGETS}}


def summarise(stretch: np.ndarray, comp: np.ndarray, folded: np.ndarray,
              lbs: np.ndarray | None, bound: np.ndarray | None = None) -> dict:
    out = {"poses": int(stretch.size),
           "stretch": {"median": float(np.median(stretch)), "p99": float(np.quantile(stretch, 0.99)),
                       "max": float(stretch.max())},
           "compression": {"median": float(np.median(comp)), "p99": float(np.quantile(comp, 0.99)),
                           "max": float(comp.max())},
           "folded_poses": int((folded > 0).sum()), "folded_triangles": int(folded.sum())}
    if lbs is not None:
        out["poses_worse_than_lbs"] = int((stretch > lbs + 0.01).sum())
        # the rule: every pair at most 0.03 above its plain LBS
        out["poses_worse_than_lbs_by_0.03"] = int((stretch > lbs + 0.03).sum())
        out["worse_than_lbs_max"] = float((stretch - lbs).max())
    if bound is not None:
        gap = stretch - bound
        out["stretch_above_bound"] = {"median": float(np.median(gap)),
                                      "p99": float(np.quantile(gap, 0.99)), "min": float(gap.min())}
    return out


def bounds(model: HackModel, betas: torch.Tensor, theta: torch.Tensor, psi) -> np.ndarray:
    """(I, P) stretch lower bound per identity and pose (expression psi held, or None)."""
    topo = skin_topology(model)
    anchors = rigid_anchors(model, topo)
    return np.stack([model_stretch_bound(model, b[None], theta, psi, topo, anchors).numpy()
                     for b in betas])


def bound_section(model, betas, theta, psi, fams, fam_of, active=None) -> dict:
    """The results' ``bound`` entry for one configuration, and the raw (I, P) bound
    (``active``: (P,) bool, the poses within the neck's active range, also summarised)."""
    b = bounds(model, betas, theta, psi)
    entry = {"all": summarise_bound(b)}
    for k, fam in enumerate(fams):
        entry[fam] = summarise_bound(b[:, fam_of == k])
    if active is not None:
        entry["active"] = summarise_bound(b[:, active])
    a = entry["all"]
    print(f"stretch bound: median {a['median']:.3f} p99 {a['p99']:.3f} max {a['max']:.3f} | "
          f"pairs above 0.35: {a['poses_above']['0.35']}, above 0.60: {a['poses_above']['0.60']}",
          flush=True)
    return entry, b


def merge_bound(args, models, betas, theta, psi, fams, fam_of) -> None:
    """``--bound-only``: add the bound to an existing results file of the same sampling."""
    import json

    from provenance import commit

    res = json.loads(args.out.read_text())
    same = (res["poses"], res["identities"], res["seed"]) == (args.poses, args.identities, args.seed)
    if not same:
        raise SystemExit(f"{args.out} was sampled with poses/identities/seed {res['poses']}/"
                         f"{res['identities']}/{res['seed']}, not {args.poses}/{args.identities}/"
                         f"{args.seed}: run the whole bench instead")
    t0 = time.time()
    for conf, expr in (("neutral", False), ("expression", True)):
        res["configurations"][conf]["bound"], _ = bound_section(
            models["shipped"], betas, theta, psi if expr else None, fams, fam_of)
    res["bound_provenance"] = {"commit": commit(), "command": " ".join(sys.argv),
                               "seconds": time.time() - t0,
                               "note": "the bound depends on the skeleton and the rigid rows "
                                       "only; the models' figures are from the run above"}
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"merged the bound into {args.out}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--identities", type=int, default=10)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--model", type=Path, default=ROOT / "hack_render/data/hack_default.npz")
    ap.add_argument("--previous", default="f9ed56b",
                    help="git revision of the previous shipped model ('' to skip)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/pose_space.json")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--bound-only", action="store_true",
                    help="compute the stretch lower bound alone and merge it into --out "
                         "(a results file of the same poses, identities and seed)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    models = {"lbs": without_correctives(args.model),
              "shipped": HackModel(*load_model_file(args.model))}
    if args.previous and not args.bound_only:
        models["previous"] = model_from_git(args.previous)
    topo = skin_topology(models["shipped"])
    fams = sample_pose_space(args.poses, args.seed)
    theta = torch.cat(list(fams.values())).float()
    fam_of = np.concatenate([[k] * len(v) for k, v in enumerate(fams.values())])
    g = torch.Generator().manual_seed(args.seed)
    betas = torch.randn(args.identities, 20, generator=g)
    psi = models["shipped"].expression_vector(EXPRESSION)
    if args.bound_only:
        return merge_bound(args, models, betas, theta, psi, fams, fam_of)
    # the poses within the whole neck's active range (a joint coupling: anatomy.py's
    # ACTIVE_RANGE_DEG): every figure is also given on them, "<family>_active" / "active"
    active = within_active_range(theta.double())
    res: dict = {"poses": args.poses, "identities": args.identities, "seed": args.seed,
                 "families": {k: len(v) for k, v in fams.items()}, "expression": EXPRESSION,
                 "previous": args.previous,
                 "active_range": {"deg": [list(r) for r in ACTIVE_RANGE_DEG],
                                  "poses": int(active.sum()),
                                  "families": {f: int(active[fam_of == k].sum())
                                               for k, f in enumerate(fams)}},
                 "configurations": {}}
    t0 = time.time()
    for expr in (False, True):
        raw = {}
        for name, model in models.items():
            st = [model_deformation(model, b[None], theta, psi if expr else None, topo)
                  for b in betas]
            raw[name] = [np.stack([getattr(s, k).numpy() for s in st])
                         for k in ("stretch", "compression", "folded")]
        conf = {}
        conf["bound"], bound = bound_section(models["shipped"], betas, theta,
                                             psi if expr else None, fams, fam_of, active)
        for name, (s, c, f) in raw.items():
            lbs = raw["lbs"][0] if name != "lbs" else None
            entry = {"all": summarise(s, c, f, lbs, bound)}
            for k, fam in enumerate(fams):
                sel = fam_of == k
                entry[fam] = summarise(s[:, sel], c[:, sel], f[:, sel],
                                       None if lbs is None else lbs[:, sel], bound[:, sel])
                sel = sel & active
                if sel.any():
                    entry[f"{fam}_active"] = summarise(s[:, sel], c[:, sel], f[:, sel],
                                                       None if lbs is None else lbs[:, sel],
                                                       bound[:, sel])
            entry["active"] = summarise(s[:, active], c[:, active], f[:, active],
                                        None if lbs is None else lbs[:, active], bound[:, active])
            conf[name] = entry
            a = entry["all"]
            print(f"{'expression' if expr else 'neutral':10s} {name:9s} stretch median "
                  f"{a['stretch']['median']:.3f} p99 {a['stretch']['p99']:.3f} max "
                  f"{a['stretch']['max']:.3f} | folded poses {a['folded_poses']} triangles "
                  f"{a['folded_triangles']}" + (f" | worse than LBS {a['poses_worse_than_lbs']} (max "
                                                 f"{a['worse_than_lbs_max']:.3f})"
                                                 if lbs is not None else ""), flush=True)
            a = entry["active"]
            print(f"{'':10s} {'':9s} within the active range ({a['poses']} pairs): stretch "
                  f"median {a['stretch']['median']:.3f} p99 {a['stretch']['p99']:.3f} | folded "
                  f"poses {a['folded_poses']} triangles {a['folded_triangles']}"
                  + (f" | worse than LBS {a['poses_worse_than_lbs']} (max "
                     f"{a['worse_than_lbs_max']:.3f})" if lbs is not None else ""),
                  flush=True)
        res["configurations"]["expression" if expr else "neutral"] = conf
    res["seconds"] = time.time() - t0
    write_result(args.out, res)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
