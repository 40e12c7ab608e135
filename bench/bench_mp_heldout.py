"""M_P on held-out identities (issue 60 §2; a benchmark, not a test).

For a model file (default: the shipped one), identities drawn from a seed the learner never
used (beta ~ N(0, I), each with the learner's sampled expression) are posed over the
learner's pose sampler (per-joint uniform, whole-head rotations at full and 60 % range),
and the neck skin's deformation energy (``hack_render.learn.pose_energy``: the learner's
own terms, with the loss weights and head-pose sampler the file's correctives were learned
with (its ``learn.pose`` metadata; ``--weights default``: the learner's defaults, which
files learned with other weights were not optimised for), without the parameter
regularisers ``smooth`` and ``weights``, which do not depend on the identity) is computed
twice on the same poses:

* personalised: P + sum_c m_c(beta) C_c, the file's M_P;
* generic: M_P's output replaced by its mean over 512 sampled identities (the personalised
  part's average, folded into P: what the model would be without M_P).

Per identity: both energies, their ratio, and the largest edge stretch of each. M_P is
alive when the personalised energy is lower on held-out identities and the two differ
measurably; a dead M_P (one constant for every identity) gives the same energy both ways.

``--oracle``: what any M_P with this file's components could gain, per held-out identity:
the identity's rows are split into ``--poses`` fit poses and as many test poses (the same
sampler, the same expression); the personalised coefficients are fitted to that identity
alone (a constant (C,) vector, L-BFGS from M_P's mean output, on the fit poses) and scored
on the test poses against the mean output, beside M_P's own output on the same test poses.
An oracle test ratio near 1 says the energy's identity dependence that these components
can express is below what the pose sample shows; below 1, it is how much an identity's
own coefficients gain on poses they were not fitted to (M_P's ceiling, roughly).

    PYTHONPATH=$PWD python bench/bench_mp_heldout.py --model g2.npz --out mp.json
    PYTHONPATH=$PWD python bench/bench_mp_heldout.py --oracle --identities 6 --poses 256 --out o.json
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
from hack_render.learn.pose_energy import PoseBatch

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


def held_out(arrays: dict, identities: int = 10, poses: int = 48, seed: int = 9001,
             trained: dict | None = None) -> dict:
    """Per held-out identity, the energy with M_P and with its mean output (module doc)."""
    learner, gate, comps, mlp, mean, g = _setup(arrays, trained, seed)
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


def _learner(arrays: dict, trained: dict | None = None):
    """The energy learner of a model's arrays; ``trained``: the file's ``learn.pose``
    metadata, whose loss weights and head-pose sampler the energy then uses (None: the
    learner's defaults)."""
    gate = float(arrays["pose_gate_deg"]) if "pose_gate_deg" in arrays else None
    comps = int(np.asarray(arrays["pose_pca_components"]).shape[0])
    trained = trained or {}
    learner = energy_learner(arrays, num_components=comps, gate_deg=gate,
                             gate_chain=float(arrays.get("pose_gate_chain", 0.0)),
                             loss=trained.get("loss_weights"),
                             single_axis=bool(trained.get("single_axis_head_poses", False)),
                             corner=float(trained.get("corner_poses", 0.0)))
    learner.start_from(arrays)
    return learner, gate, comps


def _setup(arrays: dict, trained: dict | None, seed: int) -> tuple:
    """(learner, gate, components, M_P's MLP, its mean output, the held-out generator)."""
    learner, gate, comps = _learner(arrays, trained)
    return (learner, gate, comps, learner.mlp, mean_output(learner),
            torch.Generator().manual_seed(seed))


def _energy_of(learner, batch, m: torch.Tensor) -> torch.Tensor:
    """The held-out energy (module doc) of ``batch`` with M_P's output replaced by ``m``
    (C,), differentiable in ``m``."""
    learner.mlp = lambda beta: m.expand(len(beta), -1)
    terms = learner.terms(batch)
    return sum(learner.lam[k] * v for k, v in terms.items() if k not in REGULARISERS)


def _fit_constant(learner, batch, start: torch.Tensor, steps: int) -> torch.Tensor:
    """The constant coefficients (C,) that minimise the energy of ``batch`` (L-BFGS from
    ``start``)."""
    m = start.clone().requires_grad_()
    opt = torch.optim.LBFGS([m], lr=1.0, max_iter=steps, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        e = _energy_of(learner, batch, m)
        e.backward()
        return e
    opt.step(closure)
    return m.detach()


def oracle(arrays: dict, identities: int = 6, poses: int = 256, seed: int = 9001,
           steps: int = 25, trained: dict | None = None) -> dict:
    """Per held-out identity, the best constant coefficients on its fit poses, scored on
    its test poses, against M_P's mean output and against one constant fitted to all the
    identities' fit poses together (module doc, ``--oracle``)."""
    learner, gate, comps, mlp, mean, g = _setup(arrays, trained, seed)
    parts = []
    for _ in range(identities):
        batch = learner.sample(g, 1, 2 * poses)
        split = torch.randperm(len(batch), generator=g)
        parts.append((batch, batch.rows(split[:len(batch) // 2]), batch.rows(split[len(batch) // 2:])))
    # one constant fitted to every identity's fit poses together (a generic fit: with
    # hinge terms it follows the few rows that fold or exceed LBS, docs/model.md)
    pooled = _fit_constant(learner, PoseBatch.cat([f for _, f, _ in parts]), mean, steps)
    rows = []
    for i, (batch, fit, test) in enumerate(parts):
        with torch.no_grad():
            own = mlp(batch.beta[:1])[0]
            e_mean_fit = float(_energy_of(learner, fit, mean))
            e_mean = float(_energy_of(learner, test, mean))
            e_own = float(_energy_of(learner, test, own))
            e_pool = float(_energy_of(learner, test, pooled))
        m = _fit_constant(learner, fit, mean, steps)
        with torch.no_grad():
            e_fit = float(_energy_of(learner, fit, m))
            e_best = float(_energy_of(learner, test, m))
        learner.mlp = mlp
        rows.append({"identity": i, "fit_poses": len(fit), "test_poses": len(test),
                     "oracle_fit_ratio": e_fit / e_mean_fit, "oracle_test_ratio": e_best / e_mean,
                     "pooled_test_ratio": e_pool / e_mean, "oracle_over_pooled": e_best / e_pool,
                     "mp_test_ratio": e_own / e_mean, "energy_mean_test": e_mean,
                     "oracle_minus_mean_max": float((m - mean).abs().max()),
                     "mp_minus_mean_max": float((own - mean).abs().max()),
                     "expression": bool(batch.psi is not None and float(batch.psi.abs().sum()) > 0)})
        r = rows[-1]
        print(f"identity {i}: own constant {r['oracle_fit_ratio']:.4f} on its fit poses, "
              f"{r['oracle_test_ratio']:.4f} on its test poses; the pooled constant "
              f"{r['pooled_test_ratio']:.4f}; M_P {r['mp_test_ratio']:.4f} (ratios to M_P's "
              f"mean output); own / pooled {r['oracle_over_pooled']:.4f}", flush=True)
    col = lambda k: np.array([r[k] for r in rows])
    return {"identities": rows, "gate_deg": gate, "components": comps, "seed": seed,
            "poses_per_identity": 2 * poses, "lbfgs_steps": steps,
            "summary": {"oracle_fit_ratio_median": float(np.median(col("oracle_fit_ratio"))),
                        "oracle_test_ratio_median": float(np.median(col("oracle_test_ratio"))),
                        "pooled_test_ratio_median": float(np.median(col("pooled_test_ratio"))),
                        "oracle_over_pooled_median": float(np.median(col("oracle_over_pooled"))),
                        "oracle_over_pooled_max": float(col("oracle_over_pooled").max()),
                        "oracle_beats_pooled": int((col("oracle_over_pooled") < 1).sum()),
                        "mp_test_ratio_median": float(np.median(col("mp_test_ratio")))}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None, help="model file (default: shipped)")
    ap.add_argument("--identities", type=int, default=10)
    ap.add_argument("--poses", type=int, default=48)
    ap.add_argument("--seed", type=int, default=9001, help="held out: no learner run used it")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--oracle", action="store_true", help="the per-identity upper bound "
                    "(module doc); --poses is then the fit poses per identity (as many test)")
    ap.add_argument("--weights", choices=("trained", "default"), default="trained",
                    help="the energy's loss weights and head-pose sampler: those the file's "
                    "pose correctives were learned with (its learn.pose metadata; the "
                    "learner's defaults where it has none), or the learner's defaults")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    path = args.model or default_model_path()
    arrays, meta = load_model_file(path)
    trained = (meta or {}).get("learn", {}).get("pose") if args.weights == "trained" else None
    t0 = time.time()
    run = oracle if args.oracle else held_out
    res = run(arrays, args.identities, args.poses, args.seed, trained=trained)
    res.update({"model": str(path) if args.model else "the shipped model",
                "weights": "the file's learn.pose loss_weights" if trained and
                trained.get("loss_weights") else "the learner's defaults",
                "loss_weights": (trained or {}).get("loss_weights"),
                "single_axis_head_poses": bool((trained or {}).get("single_axis_head_poses")),
                "seconds": round(time.time() - t0, 1)})
    if args.oracle:
        print(json.dumps(res["summary"]))
        if args.out:
            print(f"wrote {write_result(args.out, res)}")
        return
    for r in res["identities"]:
        print(f"identity {r['identity']}: energy {r['energy_personalised']:.5f} with M_P, "
              f"{r['energy_generic']:.5f} with its mean (ratio {r['ratio']:.3f}); largest "
              f"stretch {r['max_stretch_personalised']:.3f} / {r['max_stretch_generic']:.3f}")
    print(json.dumps(res["summary"]))
    if args.out:
        print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
