"""M_P on held-out identities (issue 60 §2; a benchmark, not a test).

For a model file (default: the shipped one), identities drawn from a seed the learner never
used (beta ~ N(0, I), each with the learner's sampled expression) are posed over the
learner's pose sampler (per-joint uniform, whole-head rotations at full and 60 % range),
and the neck skin's deformation energy (``hack_render.learn.pose_energy``: the learner's
own terms and weights, without the parameter regularisers ``smooth`` and ``weights``,
which do not depend on the identity) is computed twice on the same poses:

* personalised: P + sum_c m_c(beta) C_c, the file's M_P;
* generic: M_P's output replaced by its mean over 512 sampled identities (the personalised
  part's average, folded into P: what the model would be without M_P).

Per identity: both energies, their ratio, and the largest edge stretch of each. M_P is
alive when the personalised energy is lower on held-out identities and the two differ
measurably; a dead M_P (one constant for every identity) gives the same energy both ways.

    PYTHONPATH=$PWD python bench/bench_mp_heldout.py --model g2.npz --out mp.json
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
from provenance import write_result

from hack_render.geometry.model_file import default_model_path, load_model_file
from hack_render.learn.full_model import energy_learner
from hack_render.learn.neck_region import skin_measures

#: identity-independent regularisers of the learner, left out of the held-out energy
REGULARISERS = ("smooth", "weights")


def mean_output(learner, samples: int = 512, seed: int = 0) -> torch.Tensor:
    """(C,) M_P's mean output over sampled identities."""
    g = torch.Generator().manual_seed(seed)
    beta = torch.randn(samples, learner.num_shape, generator=g, dtype=learner.template.dtype)
    with torch.no_grad():
        return learner.mlp(beta).mean(0)


def energy(learner, batch) -> tuple[float, float]:
    """(weighted energy without the regularisers, largest edge stretch) of a batch."""
    with torch.no_grad():
        terms = learner.terms(batch)
        e = sum(learner.lam[k] * float(v) for k, v in terms.items() if k not in REGULARISERS)
        posed, rot = learner.pose(batch)
        reg = learner.region
        r, _, _ = skin_measures(reg, batch.rest, posed, rot, learner.weights()[reg.faces].mean(1))
    return e, float(r.amax())


def held_out(arrays: dict, identities: int = 10, poses: int = 48, seed: int = 9001) -> dict:
    """Per held-out identity, the energy with M_P and with its mean output (module doc)."""
    gate = float(arrays["pose_gate_deg"]) if "pose_gate_deg" in arrays else None
    comps = int(np.asarray(arrays["pose_pca_components"]).shape[0])
    learner = energy_learner(arrays, num_components=comps, gate_deg=gate,
                             gate_chain=float(arrays.get("pose_gate_chain", 0.0)))
    learner.start_from(arrays)
    mlp = learner.mlp
    mean = mean_output(learner)
    g = torch.Generator().manual_seed(seed)
    rows = []
    for i in range(identities):
        batch = learner.sample(g, 1, poses)
        with torch.no_grad():
            spread = float((mlp(batch.beta[:1]) - mean).abs().max())
        learner.mlp = mlp
        e_p, s_p = energy(learner, batch)
        learner.mlp = lambda beta: mean.expand(len(beta), -1)
        e_g, s_g = energy(learner, batch)
        learner.mlp = mlp
        rows.append({"identity": i, "energy_personalised": e_p, "energy_generic": e_g,
                     "ratio": e_p / e_g if e_g > 0 else float("nan"),
                     "max_stretch_personalised": s_p, "max_stretch_generic": s_g,
                     "mp_output_minus_mean_max": spread,
                     "expression": bool(batch.psi is not None and float(batch.psi.abs().sum()) > 0)})
    ratios = np.array([r["ratio"] for r in rows])
    return {"identities": rows, "gate_deg": gate, "components": comps, "seed": seed,
            "poses_per_identity": poses,
            "summary": {"ratio_median": float(np.median(ratios)),
                        "ratio_max": float(ratios.max()), "ratio_min": float(ratios.min()),
                        "lower_with_mp": int((ratios < 1).sum()),
                        "mp_output_spread_max": max(r["mp_output_minus_mean_max"] for r in rows)}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None, help="model file (default: shipped)")
    ap.add_argument("--identities", type=int, default=10)
    ap.add_argument("--poses", type=int, default=48)
    ap.add_argument("--seed", type=int, default=9001, help="held out: no learner run used it")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    path = args.model or default_model_path()
    arrays, _ = load_model_file(path)
    t0 = time.time()
    res = held_out(arrays, args.identities, args.poses, args.seed)
    res.update({"model": str(path) if args.model else "the shipped model",
                "seconds": round(time.time() - t0, 1)})
    for r in res["identities"]:
        print(f"identity {r['identity']}: energy {r['energy_personalised']:.5f} with M_P, "
              f"{r['energy_generic']:.5f} with its mean (ratio {r['ratio']:.3f}); largest "
              f"stretch {r['max_stretch_personalised']:.3f} / {r['max_stretch_generic']:.3f}")
    print(json.dumps(res["summary"]))
    if args.out:
        print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
