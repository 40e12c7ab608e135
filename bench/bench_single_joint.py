"""Single-joint sweeps of the neck (issue 60 §1; a benchmark, not a test).

Each joint alone at each axis's limit (8 joints x 3 axes x both ends: 48 poses), on the
template, neutral: the largest skin-edge stretch (``geometry.deformation.model_deformation``)
for the shipped model (or ``--model``), a previous model file from git history
(``--previous REV``) and plain LBS (the model without its pose correctives). The issue asks
for single-joint sweeps no worse than before issue 21 (the c1-c2 axial twist within 26 %).

    PYTHONPATH=$PWD python bench/bench_single_joint.py --previous 9278dc5

Writes ``bench/results/single_joint.json`` (commit, date, machine, command first).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pose_space import model_from_git, without_correctives
from provenance import write_result

from hack_render.geometry.deformation import model_deformation, skin_topology
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import default_model_path, load_model_file

ROOT = Path(__file__).resolve().parents[1]


def sweep_poses(limits_rad: np.ndarray) -> tuple[torch.Tensor, list[tuple[int, int, int]]]:
    """(48, 8, 3) poses, each one joint's one axis at one end of its limits (K, 3, 2), and
    their (joint, axis, end) labels."""
    labels = [(j, a, e) for j in range(limits_rad.shape[0]) for a in range(3) for e in range(2)]
    theta = torch.zeros(len(labels), limits_rad.shape[0], 3)
    for i, (j, a, e) in enumerate(labels):
        theta[i, j, a] = float(limits_rad[j, a, e])
    return theta, labels


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=default_model_path())
    ap.add_argument("--previous", default="", help="a git revision whose model file to compare")
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/single_joint.json")
    args = ap.parse_args(argv)
    arrays, meta = load_model_file(args.model)
    models = {"shipped": HackModel(arrays, meta), "lbs": without_correctives(args.model)}
    if args.previous:
        models["previous"] = model_from_git(args.previous)
    names = [str(n) for n in arrays["joint_names"]]
    theta, labels = sweep_poses(np.radians(np.asarray(arrays["rotation_limits_deg"], np.float64)))
    topo = skin_topology(models["shipped"])
    stretch = {k: model_deformation(m, torch.zeros(1, 20), theta, None, topo=topo).stretch.numpy()
               for k, m in models.items()}
    rows = {f"{names[j]} {'xyz'[a]} {'min' if e == 0 else 'max'}":
            {k: round(float(s[i]), 4) for k, s in stretch.items()}
            for i, (j, a, e) in enumerate(labels)}
    twist = [rows[f"c1-c2 y {e}"] for e in ("min", "max")]
    res = {"title": "Single-joint sweeps (issue 60)",
           "note": "largest skin-edge stretch, the template, each joint alone at each axis's "
                   "limit; the issue's c1-c2 axial twist target: 0.26",
           "previous": args.previous or None,
           "c1_c2_twist": {k: max(t[k] for t in twist) for k in twist[0]},
           "largest": {k: round(float(s.max()), 4) for k, s in stretch.items()},
           "above_lbs": {k: int((s > stretch["lbs"] + 1e-4).sum()) for k, s in stretch.items()
                         if k != "lbs"},
           "poses": rows}
    for k, v in res["c1_c2_twist"].items():
        print(f"c1-c2 axial twist, {k}: {v:.3f} (largest over the 48: {res['largest'][k]:.3f})")
    print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
