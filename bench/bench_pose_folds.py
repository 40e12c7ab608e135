"""Where the pose bench's folds are (issue 60; a benchmark, not a test).

Replays ``bench/bench_pose_space.py``'s poses and identities (the same ``--poses``,
``--identities`` and ``--seed``: every family of :func:`hack_render.geometry.deformation.
sample_pose_space`) for one or more model files, neutral and with the bench's expression,
and records every folding pose-identity pair (its family, pose index, the whole-head
rotation as the sum of the joints' Euler angles, degrees, and how many triangles fold)
and every folded triangle (how many pairs fold it, its centre on the template, metres);
the pairs' and triangles' counts equal ``pose_space.json``'s ``folded_poses`` and
``folded_triangles`` for the same file.

    python bench/bench_pose_folds.py --model hack_render/data/hack_default.npz \\
        [--model CANDIDATE.npz ...] [--previous REV] [--families head_xyz] [--threads 2] \\
        [--identity-params A/params.json B/params.json ...] [--out bench/results/pose_folds.json]

``--identity-params``: the identities are the ``beta`` of these parameter files (e.g. the
identities ``hack-render track`` fitted to real clips) instead of ``--identities`` draws
(the poses are still those of ``--seed``); each file's beta is used whole.

Prints, per model and configuration, the counts, the range of the folding pairs' head
rotation, how many lie within the neck's active range (``anatomy.ACTIVE_RANGE_DEG``) and
the box of the folded triangles' centres; writes them with every pair.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pose_space import EXPRESSION, model_from_git
from provenance import ROOT, write_result

from hack_render.geometry.anatomy import whole_neck_angles_deg, within_active_range
from hack_render.geometry.deformation import fold_mask, sample_pose_space, skin_topology
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import load_model_file


def folds(model: HackModel, betas: torch.Tensor, theta: torch.Tensor, psi, topo,
          chunk: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """(I, P) folded-triangle counts per identity and pose, and (T,) how many pairs fold
    each skin triangle (:func:`fold_mask`, as the bench's ``model_deformation``)."""
    per_pair = np.zeros((len(betas), len(theta)), np.int64)
    per_tri = np.zeros(len(topo.faces), np.int64)
    with torch.no_grad():
        for i, b in enumerate(betas):
            person = model.personalize(b[None])
            rest = person(psi=psi).vertices
            for s in range(0, len(theta), chunk):
                th = theta[s:s + chunk].to(model.template.dtype)
                f = th.shape[0]
                posed = person(psi=None if psi is None else psi.expand(f, -1), theta=th).vertices
                rot = local_rotations(th, th.new_zeros(f, 3))
                j = person.joints.expand(f, -1, -1)
                _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1),
                                          chain_parents(model.parents))
                m = fold_mask(rest, posed, rel[..., :3, :3], topo)
                per_pair[i, s:s + f] = m.sum(1).numpy()
                per_tri += m.sum(0).numpy()
    return per_pair, per_tri


def _shown(path) -> str:
    """A model path as recorded: relative to the checkout when inside it."""
    p = Path(path).resolve()
    return str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(path)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, action="append", default=None,
                    help="model file (repeatable; default: the shipped one)")
    ap.add_argument("--previous", default=None,
                    help="also the model file of this git revision (e.g. the one shipped before)")
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--identities", type=int, default=10)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--families", default=None,
                    help="comma-separated pose families (default: all)")
    ap.add_argument("--identity-params", type=Path, nargs="+", default=None,
                    help="parameter files (JSON with a 'beta' list) whose identities to use")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--out", type=Path, default=None, help="results file (.json)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    paths = args.model or [ROOT / "hack_render/data/hack_default.npz"]
    fams = sample_pose_space(args.poses, args.seed)
    if args.families:
        want = args.families.split(",")
        unknown = sorted(set(want) - set(fams))
        if unknown:
            raise SystemExit(f"--families: unknown {unknown}; one of {sorted(fams)}")
        fams = {k: v for k, v in fams.items() if k in want}
    theta = torch.cat(list(fams.values())).float()
    fam_of = np.concatenate([[k] * len(v) for k, v in fams.items()])
    first = {k: int(np.argmax(fam_of == k)) for k in fams}
    head = whole_neck_angles_deg(theta.double())  # (P, 3): the joints' Euler angles summed
    active = within_active_range(theta.double())  # (P,) within the neck's active range
    g = torch.Generator().manual_seed(args.seed)
    betas = torch.randn(args.identities, 20, generator=g)
    sources = None
    if args.identity_params:
        rows = [json.loads(f.read_text())["beta"] for f in args.identity_params]
        betas = torch.zeros(len(rows), max(len(r) for r in rows))
        for i, r in enumerate(rows):
            betas[i, :len(r)] = torch.tensor(r)
        sources = [str(f) for f in args.identity_params]
    res: dict = {"poses": args.poses, "identities": len(betas), "seed": args.seed,
                 "families": {k: len(v) for k, v in fams.items()}, "expression": EXPRESSION,
                 "models": {}}
    if sources:
        res["identity_params"] = sources
        res["betas"] = [[round(float(x), 4) for x in b] for b in betas]
    t0 = time.time()
    runs = [(_shown(p), lambda p=p: HackModel(*load_model_file(p))) for p in paths]
    if args.previous:
        runs.append((f"git {args.previous}", lambda: model_from_git(args.previous)))
    for name_, make in runs:
        model = make()
        topo = skin_topology(model)
        centres = model.template[topo.faces].mean(1).numpy()
        entry = {}
        for expr in (False, True):
            psi = model.expression_vector(EXPRESSION)[None] if expr else None
            per_pair, per_tri = folds(model, betas, theta, psi, topo)
            ii, pp = np.nonzero(per_pair)
            tri = np.nonzero(per_tri)[0]
            pairs = [{"identity": int(i), "family": str(fam_of[p]),
                      "pose": int(p - first[fam_of[p]]),
                      "head_deg": [round(float(x), 1) for x in head[p]],
                      "active_range": bool(active[p]),
                      "triangles": int(per_pair[i, p])} for i, p in zip(ii, pp)]
            conf = {"folded_poses": len(pairs), "folded_triangles": int(per_pair.sum()),
                    "folded_poses_active": int(sum(q["active_range"] for q in pairs)),
                    "distinct_triangles": len(tri), "pairs": pairs,
                    "triangles": [{"triangle": int(t), "pairs": int(per_tri[t]),
                                   "centre_m": [round(float(x), 4) for x in centres[t]]}
                                  for t in tri]}
            if len(pairs):
                h = head[pp]
                conf["head_deg_range"] = {a: [round(float(h[:, k].min()), 1),
                                              round(float(h[:, k].max()), 1)]
                                          for k, a in enumerate("xyz")}
                c = centres[tri]
                conf["centre_box_m"] = {a: [round(float(c[:, k].min()), 3),
                                            round(float(c[:, k].max()), 3)]
                                        for k, a in enumerate("xyz")}
            name = "expression" if expr else "neutral"
            entry[name] = conf
            print(f"{Path(name_).name} {name:10s} folding pairs {len(pairs)} (triangles "
                  f"{conf['folded_triangles']}, {len(tri)} distinct; within the active range "
                  f"{conf['folded_poses_active']} pairs)"
                  + (f" | head x {conf['head_deg_range']['x']}, y {conf['head_deg_range']['y']},"
                     f" z {conf['head_deg_range']['z']} deg | triangle centres x "
                     f"{conf['centre_box_m']['x']}, y {conf['centre_box_m']['y']}, z "
                     f"{conf['centre_box_m']['z']} m" if pairs else ""), flush=True)
        res["models"][name_] = entry
    res["seconds"] = time.time() - t0
    if args.out:
        print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
