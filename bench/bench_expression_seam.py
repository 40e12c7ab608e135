"""M_E against its own target, and the seam at its vertex subset's edge (model version 6).

M_E's personal part lives on 1,500 skin vertices (59 % of its energy, ``learn.expressions``);
outside them it is zero. Version 5 cut it there in one step; version 6 ramps it down over
the subset's outer rings (``hack_render.learn.expression_learn.taper_personal``). For each
model file, on the expression learner's own 30 held-out identities (seed 60, the last 30 of
300 draws of 100 shape weights, never seen by its PCA or MLP) and each of the 53 expressions
at weight 1, against the deformation transfer (DT) of the generic shape onto the identity's
neutral mesh (the learner's target):

* ``ablation_mm``: mean per-vertex error over all moving skin vertices and over the subset
  (the learner's own report, ``learn.expressions.ablation_mm``), generic shapes alone and
  with the file's personal part;
* ``edge``: each skin edge's length under the expression over its neutral length, the
  file's against DT's, on the subset's seam (edges with one end in the subset) and
  elsewhere: the error's p99, p99.9 and largest, the (expression, edge) pairs off by more
  than 0.2, and those the file shrinks below half their neutral length where DT keeps them
  above 0.6 (a pinch DT does not make). Edges shorter than 0.5 mm at neutral (where the
  lips meet: a ratio of tiny lengths) are left out;
* ``bench_expression``: the smallest edge ratio under the pose bench's expression for the
  pose bench's 10 identities (``bench/bench_pose_space.py``: seed 21, 20 shape weights).

    python bench/bench_expression_seam.py --model OLD.npz --model NEW.npz --out bench/results/expression_seam.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pose_space import EXPRESSION
from provenance import write_result

from hack_render.geometry.deformation import skin_topology
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import default_model_path, load_model_file
from hack_render.learn.expression_learn import SKIN_LAST, ExpressionTransfer
from hack_render.learn.personal import mlp_forward


def held_out_betas(n: int) -> np.ndarray:
    """The expression learner's held-out identities (``learn_expressions``: seed 60, 300
    draws of 100 weights, the last 30 held out): the first ``n`` of them."""
    return np.random.default_rng(60).standard_normal((300, 100))[-30:][:n]


def personal_part(arrays: dict, beta: np.ndarray) -> np.ndarray:
    """(E, M, 3) the file's personal deltas on its subset for one identity (100,)."""
    mlp = {k: arrays[f"expr_mlp_{k}"].astype(np.float64) for k in ("w0", "b0", "w1", "b1", "w2", "b2")}
    w = mlp_forward(mlp, beta[None])[0]
    comps = arrays["expr_pca_components"].astype(np.float64)
    return arrays["expr_pca_mean"].astype(np.float64) + np.tensordot(w, comps, 1)


def against_dt(files: dict[str, dict], n: int) -> dict:
    ref = next(iter(files.values()))
    tmpl = ref["template_vertices"].astype(np.float64)
    expr = ref["expression_basis"].astype(np.float64)
    faces = ref["faces"].astype(np.int64)
    dirs = ref["shape_components"].astype(np.float64) * ref["shape_std"].astype(np.float64)[:, None, None]
    dt = ExpressionTransfer(tmpl, faces, expr)
    moving = np.flatnonzero(dt.moving)
    f = faces[(faces <= SKIN_LAST).all(1)]
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), 1), axis=0)
    edges = edges[np.linalg.norm(tmpl[edges[:, 0]] - tmpl[edges[:, 1]], axis=-1) >= 5e-4]
    length = lambda v: np.linalg.norm(v[..., edges[:, 0], :] - v[..., edges[:, 1], :], axis=-1)
    acc = {name: {"g_all": [], "p_all": [], "g_sub": [], "p_sub": [], "err": [], "pinch": []}
           for name in files}
    for beta in held_out_betas(n):
        neutral = tmpl + np.tensordot(beta, dirs, 1)
        truth = dt.transfer(neutral) - expr  # (E, N, 3): DT's personal part
        ratio_dt = length(neutral[None] + expr + truth) / length(neutral)[None]
        for name, arr in files.items():
            sub = arr["expr_pca_vertices"].astype(np.int64)
            mine = np.zeros_like(truth)
            mine[:, sub] = personal_part(arr, beta)
            res = np.linalg.norm((truth - mine)[:, moving], axis=-1)
            a = acc[name]
            a["g_all"].append(np.linalg.norm(truth[:, moving], axis=-1).mean())
            a["p_all"].append(res.mean())
            a["g_sub"].append(np.linalg.norm(truth[:, sub], axis=-1).mean())
            a["p_sub"].append(np.linalg.norm((truth - mine)[:, sub], axis=-1).mean())
            ratio = length(neutral[None] + expr + mine) / length(neutral)[None]
            a["err"].append(np.abs(ratio - ratio_dt))
            a["pinch"].append((ratio < 0.5) & (ratio_dt > 0.6))
    out = {}
    for name, a in acc.items():
        err, pinch = np.concatenate(a["err"]), np.concatenate(a["pinch"])
        inside = np.zeros(len(tmpl), bool)
        inside[files[name]["expr_pca_vertices"]] = True
        seam = inside[edges[:, 0]] != inside[edges[:, 1]]
        out[name] = {
            "ablation_mm": {"generic_all_moving_vertices": 1e3 * float(np.mean(a["g_all"])),
                            "personalised_all_moving_vertices": 1e3 * float(np.mean(a["p_all"])),
                            "generic_subset": 1e3 * float(np.mean(a["g_sub"])),
                            "personalised_subset": 1e3 * float(np.mean(a["p_sub"]))},
            "edge": {"seam": _part(err, pinch, seam), "elsewhere": _part(err, pinch, ~seam),
                     "expressions": len(expr)}}
    return out


def _part(err: np.ndarray, pinch: np.ndarray, m: np.ndarray) -> dict:
    """The edge figures of :func:`against_dt` on the edges ``m``."""
    return {"edges": int(m.sum()), "ratio_error_p99": float(np.percentile(err[:, m], 99)),
            "ratio_error_p999": float(np.percentile(err[:, m], 99.9)),
            "ratio_error_max": float(err[:, m].max()),
            "off_by_0.2": int((err[:, m] > 0.2).sum()), "pinched": int(pinch[:, m].sum())}


def bench_expression(path: str) -> list[float]:
    """The smallest skin-edge ratio under the pose bench's expression, per bench identity."""
    model = HackModel(*load_model_file(path))
    e = skin_topology(model).edges
    betas = torch.randn(10, 20, generator=torch.Generator().manual_seed(21))
    psi = torch.as_tensor(model.expression_vector(EXPRESSION), dtype=torch.float32).reshape(1, -1)
    out = []
    with torch.no_grad():
        for b in betas:
            r0 = model(beta=b[None]).vertices[0]
            r1 = model(beta=b[None], psi=psi).vertices[0]
            q = (r1[e[:, 0]] - r1[e[:, 1]]).norm(dim=-1) / (r0[e[:, 0]] - r0[e[:, 1]]).norm(dim=-1)
            out.append(round(float(q.min()), 4))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", help="a model file (repeat; default: the shipped one)")
    ap.add_argument("--identities", type=int, default=30, help="held-out identities (at most 30)")
    ap.add_argument("--out", help="write the results here (JSON)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    paths = args.model or [str(default_model_path())]
    files = {p: load_model_file(p)[0] for p in paths}
    res = {"identities": min(args.identities, 30), "models": against_dt(files, args.identities)}
    for p in paths:
        res["models"][p]["bench_expression_min_edge_ratio"] = bench_expression(p)
        print(p, json.dumps(res["models"][p]))
    if args.out:
        print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
