"""Folds and the LBS rule on a seeded subset, with the pose correctives' gate (issue 60; a
benchmark, not a test).

For a model file (default: the shipped one) and each gate angle (0: the file as it is; c:
its correctives gated by each joint's angle, ``geometry.lbs.pose_gate``), over a seeded
subset of ``sample_pose_space`` (the template and sampled identities, neutral and with the
bench's expression): pose-identity pairs that fold (triangles), pairs whose largest stretch
is more than 1 point above the same identity's plain LBS (the model without its
correctives), the largest excess, and the stretch median / p99 / max.

    PYTHONPATH=$PWD python bench/bench_pose_gate.py --gates 0,6,8          # shipped model
    PYTHONPATH=$PWD python bench/bench_pose_gate.py --model g1.npz --gates 0

Prints one line per configuration and gate (the figures in docs/model.md, "Folds and the
LBS rule").
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch

from hack_render.geometry.deformation import model_deformation, sample_pose_space, skin_topology
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import default_model_path, load_model_file, without_correctives

EXPRESSION = "mouthSmile_L=0.8, mouthSmile_R=0.8, jawOpen=0.5, browDown_L=0.4, browDown_R=0.4"


def add_subset_arguments(ap: argparse.ArgumentParser) -> None:
    """The subset's options (also ``bench/bench_pose_arap.py``'s): the model file, the
    poses and their seed, the identities (the template and N - 1 of seed + 1)."""
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--poses", type=int, default=200)
    ap.add_argument("--identities", type=int, default=3, help="the template and N-1 sampled")
    ap.add_argument("--seed", type=int, default=2100, help="poses; identities use seed + 1")


def subset(args) -> tuple[list[str], torch.Tensor, np.ndarray, torch.Tensor]:
    """The family names, poses (P, 8, 3) float64, each pose's family index (P,) and the
    identities (I, 20) float32 of :func:`add_subset_arguments`' options."""
    fams = sample_pose_space(args.poses, seed=args.seed)
    theta = torch.cat(list(fams.values()))
    fam_of = np.concatenate([[k] * len(v) for k, v in enumerate(fams.values())])
    g = torch.Generator().manual_seed(args.seed + 1)
    betas = torch.cat([torch.zeros(1, 20), torch.randn(args.identities - 1, 20, generator=g)])
    return list(fams), theta, fam_of, betas


def measure(model, betas, theta, psi, topo) -> tuple[np.ndarray, np.ndarray]:
    """(I, P) largest stretch and folded triangles per identity and pose."""
    st = [model_deformation(model, b[None], theta, psi, topo=topo) for b in betas]
    return np.stack([s.stretch.numpy() for s in st]), np.stack([s.folded.numpy() for s in st])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_subset_arguments(ap)
    ap.add_argument("--gates", default="0", help="gate angles, degrees, comma-separated")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    arrays, meta = load_model_file(args.model or default_model_path())
    model = HackModel(arrays, meta)
    lbs = HackModel(without_correctives(arrays), meta)
    topo = skin_topology(model)
    names, theta, fam_of, betas = subset(args)
    theta = theta.float()
    own_gate = model.pose_gate_rad
    t0 = time.time()
    for conf, psi in (("neutral", None), ("expression", model.expression_vector(EXPRESSION))):
        ls, lf = measure(lbs, betas, theta, psi, topo)
        print(f"{conf} lbs: folding pairs {int((lf > 0).sum())} ({int(lf.sum())} triangles) | "
              f"stretch median {np.median(ls):.3f} p99 {np.quantile(ls, .99):.3f} max {ls.max():.3f}")
        for c in (float(x) for x in args.gates.split(",")):
            model.pose_gate_rad = math.radians(c) if c > 0 else own_gate
            ms, mf = measure(model, betas, theta, psi, topo)
            ex = ms - ls
            i, p = np.unravel_index(ex.argmax(), ex.shape)
            print(f"{conf} gate {c:g} deg: folding pairs {int((mf > 0).sum())} ({int(mf.sum())} "
                  f"triangles) | worse than LBS by > 0.01: {int((ex > 0.01).sum())} of {ex.size}, "
                  f"max {ex.max():.3f} (identity {i}, pose {p}, {names[fam_of[p]]}) | stretch "
                  f"median {np.median(ms):.3f} p99 {np.quantile(ms, .99):.3f} max {ms.max():.3f} "
                  f"[{time.time() - t0:.0f} s]", flush=True)
    model.pose_gate_rad = own_gate


if __name__ == "__main__":
    main()
