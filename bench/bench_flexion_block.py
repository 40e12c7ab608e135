"""A corrective keyed on the chain's net flexion angle, fitted to ARAP (issue 60 §1: head
flexion/extension above the bound; a study, not a test; its windowed form at 0.4 is model
version 8's flexion block).

Version 7's correctives are linear in the gated per-joint ``R - I`` features; along a
whole-head nod those features are nearly collinear, so copying ARAP's flexion with them
needs coefficients of norm ~1e9 (docs/model.md, "A corrective keyed on the net flexion").
This study tries the other form: a block of rest-space offsets weighted by piecewise-linear
hat functions of the chain's net rotation about x (the head against the thorax; a hat
every ``--step`` degrees, none at 0, so the block vanishes at rest), times a purity factor
``exp(-(|net rotation about y, z| / 20 deg)^2)`` that fades it out of combined rotations.
The offsets are the least-squares fit, on whole-head flexion/extension poses, of ARAP's
rest-space residual over version 7 (the offsets that version 7's skinning carries onto
ARAP's posed skin; ARAP with the same rigid sets as ``bench/bench_pose_arap.py``):

* ``template``: the template identity alone, hats every 5 degrees, tested on the subset's
  flexion poses of the template (ARAP, version 7 and the block, above the bound);
* ``personal``: offsets linear in beta (hats x [1, beta]), ``--train-identities`` sampled
  identities (seed 777, none of the subset's), neutral;
* ``expressions``: hats x [1, beta, psi], each training identity with an expression drawn
  as the learner draws them (half neutral, jawOpen U(0, 1) half the time, each other
  weight U(0, 1) with probability 0.15).
* ``lower_face``: hats x [1, beta, q, the products q_i q_j (i <= j)] with q the weights of
  jawOpen, mouthSmile_L and mouthSmile_R (the expression's weights that move the skin
  under the chin), each training identity with those three drawn (three quarters of the
  identities; each weight U(0, 1) with probability 0.6) and the others zero.

The last two are scored on ``bench/bench_pose_arap.py``'s subset (200 poses, the template
and 2 identities of seed 2101), neutral and with the pose bench's expression: per family,
the largest stretch above the bound (median / p99), folding pairs, and pairs more than
0.01 above the same identity's plain LBS, version 7 beside the block.

``--scales 0.4,0.5,...`` runs the scale study instead: the ``personal`` block (neutral,
hats x [1, beta]) applied at a fraction of its least-squares size. The fraction is chosen
on validation pairs that share nothing with the training or the subset (200 poses of seed
3100, 6 identities of seed 3101): the scale with the lowest neutral and expression
flexion/extension medians (the larger of the two), neutral and with the pose bench's
expression, among those with no more folding pairs and no more pairs 0.01 above plain LBS
than version 7 (over all families; the issue asks for none, but version 7 has some on the
validation's whole box) and an expression flexion/extension p99 <= 0.400; also by the same
rule within the neck's active range (the second view of docs/model.md). Then every scale
is scored on the subset.
``--basis mlp``: the block personalised as the model's own pose correctives are, by the
8 weights of version 7's M_P network w(beta) instead of beta itself (hats x [1, w(beta)]:
the block is then 16 more rows of the personalised pose basis); ``--basis none``: one
block for everyone (hats x [1]).

``--knots LO,HI``: the outermost knots (default -80,80); ``-60,40`` makes a block that is
zero past the neck's active range of net flexion (-70 to 50 degrees): model version 8's
(``hack_render.learn.flex_learn``, which fits the shipped block the same way).

    PYTHONPATH=$PWD python bench/bench_flexion_block.py [--train-identities 40]
        [--out bench/results/flexion_block.json]
    PYTHONPATH=$PWD python bench/bench_flexion_block.py --scales 0.4,0.5,0.6,0.7,0.8,0.9,1
        --out bench/results/flexion_block_scale.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pose_gate import add_subset_arguments, subset
from bench_pose_space import EXPRESSION
from provenance import write_result

from hack_render.geometry.anatomy import within_active_range
from hack_render.geometry.deformation import (
    deformation_stats,
    model_stretch_bound,
    rigid_anchors,
    skin_topology,
)
from hack_render.geometry.lbs import (
    chain_parents,
    flex_weights,
    local_rotations,
    rigid_transforms,
)
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import default_model_path, load_model_file, without_correctives
from hack_render.learn.flex_learn import knots_deg
from hack_render.learn.flex_learn import training_poses as train_poses
from hack_render.learn.pose_data import ArapNeck, pose_sequence

PURITY_DEG = 20.0
#: the outermost knots, degrees (``--knots``): past them the block fades out over one step
KNOTS_DEG = [-80.0, 80.0]
FAMILIES = ("all", "joints_uniform", "head_x", "head_xyz")
#: the expression weights of the ``lower_face`` fit
LOWER_FACE = ("jawOpen", "mouthSmile_L", "mouthSmile_R")


def hat_weights(theta: torch.Tensor, step_deg: float) -> torch.Tensor:
    """(P, H) the block's weights: hats over the net flexion angle (knots every step from
    :data:`KNOTS_DEG` [0] to [1], -80 to 80 degrees unless ``--knots``, but 0) times the
    purity factor."""
    rot = local_rotations(theta, theta.new_zeros(len(theta), 3))[:, 1:]
    knots = torch.deg2rad(torch.as_tensor(knots_deg(*KNOTS_DEG, step_deg), dtype=theta.dtype))
    return flex_weights(rot, knots, np.deg2rad(step_deg), np.deg2rad(PURITY_DEG))


class Study:
    def __init__(self):
        arrays, meta = load_model_file(default_model_path())
        # the base every block is fitted over: the default model without its own block
        # (version 8's other arrays are version 7's)
        arrays = {k: v for k, v in arrays.items() if not k.startswith("flex_")}
        self.model = HackModel(arrays, meta).double()
        self.lbs = HackModel(without_correctives(arrays),
                             meta).double()
        self.names = [str(x) for x in arrays["expression_names"]]
        self.topo = skin_topology(self.model)
        self.anchors = rigid_anchors(self.model, self.topo)
        self.w = self.model.skinning_weights.double()
        self.rigid = self.w.max(1).values >= 1 - 1e-6
        self.skin = torch.unique(self.topo.faces.reshape(-1))  # the block's vertices
        self.lower_face = [self.names.index(n) for n in LOWER_FACE]

    def posed(self, beta: torch.Tensor, psi: torch.Tensor | None, theta: torch.Tensor,
              arap: bool = False) -> dict:
        """Rest mesh, version 7's and plain LBS's posed meshes, ARAP's (``arap``), the node
        rotations and each vertex's blended skinning transform (P, N, 4, 4)."""
        person = self.model.personalize(beta[None])
        p1 = None if psi is None else psi.reshape(1, -1)
        pp = None if p1 is None else p1.expand(len(theta), -1)
        with torch.no_grad():
            rest = person(psi=p1).vertices[0]
            out = {"rest": rest, "v7": person(psi=pp, theta=theta).vertices,
                   "lbs": self.lbs.personalize(beta[None])(psi=pp, theta=theta).vertices}
        j = person.joints.double().expand(len(theta), -1, -1)
        rot = local_rotations(theta, theta.new_zeros(len(theta), 3))
        _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(self.model.parents))
        out["rot"], out["blend"] = rel[..., :3, :3], torch.einsum("vk,pkij->pvij", self.w, rel)
        if arap:
            neck = ArapNeck(rest.numpy(), self.topo.faces.numpy(), self.rigid.numpy())
            out["arap"] = pose_sequence(rest, person.joints.reshape(-1, 3).double(), self.w,
                                        self.model.parents, theta, "arap", neck, 30)
        return out

    @staticmethod
    def to_rest(blend, x, rest):
        return torch.linalg.solve(blend[..., :3, :3], (x - blend[..., :3, 3])[..., None])[..., 0] - rest

    @staticmethod
    def from_rest(blend, r, rest):
        return torch.einsum("pvij,pvj->pvi", blend[..., :3, :3], rest + r) + blend[..., :3, 3]

    def residual(self, p: dict) -> torch.Tensor:
        """(P, S * 3) ARAP's rest-space offsets over version 7's on the skin."""
        d = self.to_rest(p["blend"], p["arap"], p["rest"]) - self.to_rest(p["blend"], p["v7"], p["rest"])
        return d[:, self.skin].reshape(len(d), -1)

    def with_block(self, p: dict, offsets: torch.Tensor) -> torch.Tensor:
        r = self.to_rest(p["blend"], p["v7"], p["rest"])
        r[:, self.skin] += offsets.reshape(len(r), -1, 3)
        return self.from_rest(p["blend"], r, p["rest"])

    def gaps(self, p: dict, posed: torch.Tensor, bound: torch.Tensor) -> tuple:
        st = deformation_stats(p["rest"], posed, p["rot"], self.topo)
        return (st.stretch - bound).numpy(), st.folded.numpy(), st.stretch.numpy()

    def sample_psi(self, g: torch.Generator) -> torch.Tensor:
        e = len(self.names)
        psi = torch.rand(e, generator=g, dtype=torch.float64)
        psi = psi * (torch.rand(e, generator=g, dtype=torch.float64) < 0.15)
        psi[self.names.index("jawOpen")] = float(torch.rand(1, generator=g, dtype=torch.float64)) \
            * float(torch.rand(1, generator=g) < 0.5)
        return psi * float(torch.rand(1, generator=g) < 0.5)

    def sample_lower_face(self, g: torch.Generator) -> torch.Tensor:
        psi = torch.zeros(len(self.names), dtype=torch.float64)
        if float(torch.rand(1, generator=g)) < 0.75:
            for j in self.lower_face:
                psi[j] = float(torch.rand(1, generator=g, dtype=torch.float64)) \
                    * float(torch.rand(1, generator=g) < 0.6)
        return psi

    def lower_face_terms(self, psi: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        q = (torch.zeros(len(LOWER_FACE), dtype=torch.float64) if psi is None
             else psi.reshape(-1)[self.lower_face])
        i, j = torch.triu_indices(len(q), len(q))
        return q, q[i] * q[j]


def ridge(x: torch.Tensor, y: torch.Tensor, lam: float) -> torch.Tensor:
    return torch.linalg.solve(x.T @ x + lam * torch.eye(x.shape[1], dtype=x.dtype), x.T @ y)


def design(h: torch.Tensor, *factors: torch.Tensor) -> torch.Tensor:
    z = torch.cat([torch.ones(1, dtype=h.dtype), *factors])
    return (h[:, :, None] * z).reshape(len(h), -1)


def pair_stats(raw: dict[str, np.ndarray], keys, sel: np.ndarray) -> dict:
    """Per block in ``keys``, over the selected poses of ``raw``'s (identities, poses)
    arrays: the largest stretch above the bound (median, p99), folding pairs and pairs more
    than 0.01 above plain LBS."""
    return {k: {"above_bound_median": float(np.median(raw[k][:, sel])),
                "above_bound_p99": float(np.quantile(raw[k][:, sel], 0.99)),
                "folding_pairs": int((raw[f"{k}_folded"][:, sel] > 0).sum()),
                "above_lbs_by_0.01": int((raw[f"{k}_lbs"][:, sel] > 0.01).sum())} for k in keys}


def say_row(prefix: str, rows: dict) -> None:
    print(prefix + " | ".join(
        f"{k} {v['above_bound_median']:.3f} / {v['above_bound_p99']:.3f} "
        f"({v['folding_pairs']} folding, {v['above_lbs_by_0.01']} above LBS)"
        for k, v in rows.items()), flush=True)


def identity_factor(s: Study, b: torch.Tensor, basis: str) -> torch.Tensor:
    """What the personal block is linear in: beta itself, M_P's weights w(beta), or nothing
    (``none``: one block for every identity)."""
    if basis == "beta":
        return b
    if basis == "none":
        return b[:0]
    with torch.no_grad():
        return s.model.pose_personal.mlp(b[None])[0]


def score(s: Study, betas, theta, fam_of, names, dk, scales, step, basis="beta") -> dict:
    """Per configuration (neutral, expression), family and block: the largest stretch above
    the bound (median, p99), folding pairs and pairs more than 0.01 above plain LBS; blocks
    ``v7`` (none) and ``x<scale>`` (the personal offsets ``dk`` times the scale)."""
    h = hat_weights(theta, step)
    out = {}
    for conf, psi in (("neutral", None), ("expression", s.model.expression_vector(EXPRESSION).double())):
        raw: dict[str, list] = {}
        for b in betas:
            p = s.posed(b, psi, theta)
            bound = model_stretch_bound(s.model, b[None], theta, psi, s.topo, s.anchors)
            lbs = deformation_stats(p["rest"], p["lbs"], p["rot"], s.topo).stretch.numpy()
            off = design(h, identity_factor(s, b, basis)) @ dk
            cands = {"v7": p["v7"], **{f"x{k:g}": s.with_block(p, k * off) for k in scales}}
            for k, x in cands.items():
                gap, folded, stretch = s.gaps(p, x, bound)
                for key, v in ((k, gap), (f"{k}_folded", folded), (f"{k}_lbs", stretch - lbs)):
                    raw.setdefault(key, []).append(v)
        raw = {k: np.stack(v) for k, v in raw.items()}
        out[conf] = {}
        active = within_active_range(theta.numpy())
        for fam in (*FAMILIES, "all_active", "head_x_active"):
            base = fam.removesuffix("_active")
            sel = np.ones(len(fam_of), bool) if base == "all" else fam_of == names.index(base)
            if fam.endswith("_active"):
                sel = sel & active
            out[conf][fam] = pair_stats(raw, ("v7", *(f"x{k:g}" for k in scales)), sel)
    return out


def say_scores(label: str, entry: dict) -> None:
    for conf, fams in entry.items():
        for fam, rows in fams.items():
            say_row(f"{label} {conf:10s} {fam:14s} ", rows)


def choose_scale(entry: dict, scales, view: str = "") -> float | None:
    """The validation rule of the module docstring; ``view`` "_active": every figure
    within the neck's active range (``geometry.anatomy.within_active_range``)."""
    best, key = None, None
    for k in scales:
        rows = [(entry[c][f"all{view}"][f"x{k:g}"], entry[c][f"all{view}"]["v7"]) for c in entry]
        flex = [entry[c][f"head_x{view}"][f"x{k:g}"] for c in entry]
        ok = all(r["folding_pairs"] <= v["folding_pairs"]
                 and r["above_lbs_by_0.01"] <= v["above_lbs_by_0.01"] for r, v in rows) \
            and entry["expression"][f"head_x{view}"][f"x{k:g}"]["above_bound_p99"] <= 0.400
        worst = max(r["above_bound_median"] for r in flex)
        if ok and (key is None or worst < key):
            best, key = k, worst
    return best


def scale_study(args, s: Study, t0: float) -> None:
    """``--scales``: see the module docstring."""
    scales = [float(x) for x in args.scales.split(",")]
    train = train_poses()
    g = torch.Generator().manual_seed(777)
    ids = torch.randn(args.train_identities, 20, generator=g, dtype=torch.float64)
    h_train = hat_weights(train, args.step)
    x, y = [], []
    for b in ids:
        x.append(design(h_train, identity_factor(s, b, args.basis)))
        y.append(s.residual(s.posed(b, None, train, arap=True)))
    dk = ridge(torch.cat(x), torch.cat(y), args.ridge)
    print(f"the personal block fitted on {args.train_identities} identities "
          f"[{time.time() - t0:.0f} s]", flush=True)
    results = {"scales": scales, "basis": args.basis, "step_deg": args.step, "ridge": args.ridge,
               "knots_deg": KNOTS_DEG,
               "purity_deg": PURITY_DEG, "train_identities": args.train_identities,
               "train_poses": len(train), "expression": EXPRESSION,
               "validation": {"poses": 200, "pose_seed": 3100, "identities": 6,
                              "identity_seed": 3101},
               "subset": {"poses": args.poses, "identities": args.identities, "seed": args.seed}}
    val = argparse.Namespace(model=None, poses=200, identities=7, seed=3100)
    names, theta, fam_of, betas = subset(val)
    results["validation_scores"] = score(s, betas[1:].double(), theta.double(), fam_of, names,
                                         dk, scales, args.step, args.basis)
    say_scores("validation", results["validation_scores"])
    results["chosen_scale"] = choose_scale(results["validation_scores"], scales)
    results["chosen_scale_active"] = choose_scale(results["validation_scores"], scales, "_active")
    print(f"chosen on validation: {results['chosen_scale']}, within the active range "
          f"{results['chosen_scale_active']} [{time.time() - t0:.0f} s]", flush=True)
    names, theta, fam_of, betas = subset(args)
    results["subset_scores"] = score(s, betas.double(), theta.double(), fam_of, names, dk,
                                     scales, args.step, args.basis)
    say_scores("subset", results["subset_scores"])
    results["seconds"] = time.time() - t0
    print(f"wrote {write_result(args.out, results)}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_subset_arguments(ap)
    ap.add_argument("--train-identities", type=int, default=40)
    ap.add_argument("--step", type=float, default=10.0, help="hat spacing, degrees")
    ap.add_argument("--ridge", type=float, default=1e-2)
    ap.add_argument("--knots", default="-80,80", help="the outermost hats' knots, degrees "
                    "(e.g. -60,40: the block vanishes outside the active range's -70 to 50)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--scales", default=None, help="the scale study (module docstring), "
                    "e.g. 0.4,0.5,0.6,0.7,0.8,0.9,1")
    ap.add_argument("--basis", choices=("beta", "mlp", "none"), default="beta",
                    help="--scales: what the personal block is linear in")
    ap.add_argument("--out", type=Path, default=Path("bench/results/flexion_block.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    KNOTS_DEG[:] = [float(x) for x in args.knots.split(",")]
    t0 = time.time()
    s = Study()
    if args.scales:
        scale_study(args, s, t0)
        return
    train = train_poses()
    names, theta, fam_of, betas = subset(args)
    theta, betas = theta.double(), betas.double()
    results = {"purity_deg": PURITY_DEG, "lower_face": list(LOWER_FACE), "step_deg": args.step, "ridge": args.ridge,
               "train_identities": args.train_identities, "train_poses": len(train),
               "subset": {"poses": args.poses, "identities": args.identities, "seed": args.seed},
               "expression": EXPRESSION}

    # the template alone: can the form copy ARAP on one identity?
    zero = torch.zeros(20, dtype=torch.float64)
    p = s.posed(zero, None, train, arap=True)
    d = ridge(hat_weights(train, 5.0), s.residual(p), args.ridge)
    flex = torch.as_tensor(fam_of == names.index("head_x"))
    th = theta[flex]
    p = s.posed(zero, None, th, arap=True)
    bound = model_stretch_bound(s.model, zero[None], th, None, s.topo, s.anchors)
    row = {k: float(np.median(s.gaps(p, x, bound)[0])) for k, x in
           (("v7", p["v7"]), ("block", s.with_block(p, hat_weights(th, 5.0) @ d)), ("arap", p["arap"]))}
    results["template"] = dict(row, poses=int(flex.sum()))
    print(f"template, its {int(flex.sum())} flexion poses of the subset, median above the bound: "
          + ", ".join(f"{k} {v:.3f}" for k, v in row.items()) + f" [{time.time() - t0:.0f} s]", flush=True)

    g = torch.Generator().manual_seed(777)
    ids = torch.randn(args.train_identities, 20, generator=g, dtype=torch.float64)
    h_train = hat_weights(train, args.step)
    rows = {"personal": ([], []), "expressions": ([], []), "lower_face": ([], [])}
    for b in ids:
        for kind in rows:
            psi = (s.sample_psi(g) if kind == "expressions" else s.sample_lower_face(g)
                   if kind == "lower_face" else None)
            p = s.posed(b, psi, train, arap=True)
            x = (design(h_train, b) if kind == "personal" else design(h_train, b, psi)
                 if kind == "expressions" else design(h_train, b, *s.lower_face_terms(psi)))
            rows[kind][0].append(x)
            rows[kind][1].append(s.residual(p))
    print(f"ARAP on {args.train_identities} x {len(rows)} training identities "
          f"[{time.time() - t0:.0f} s]", flush=True)
    fits = {k: ridge(torch.cat(x), torch.cat(y), args.ridge) for k, (x, y) in rows.items()}
    h_test = hat_weights(theta, args.step)
    e = len(s.names)
    for conf, psi in (("neutral", None), ("expression", s.model.expression_vector(EXPRESSION).double())):
        raw = {k: [] for k in ("v7", "v7_folded", "v7_lbs", *(f"{k}{x}" for k in fits
                                                              for x in ("", "_folded", "_lbs")))}
        for b in betas:
            p = s.posed(b, psi, theta)
            bound = model_stretch_bound(s.model, b[None], theta, psi, s.topo, s.anchors)
            lbs = deformation_stats(p["rest"], p["lbs"], p["rot"], s.topo).stretch.numpy()
            cands = {"v7": p["v7"]}
            for k, dk in fits.items():
                pv = torch.zeros(e, dtype=torch.float64) if psi is None else psi.reshape(-1)
                x = (design(h_test, b) if k == "personal" else design(h_test, b, pv)
                     if k == "expressions" else design(h_test, b, *s.lower_face_terms(psi)))
                cands[k] = s.with_block(p, x @ dk)
            for k, x in cands.items():
                gap, folded, stretch = s.gaps(p, x, bound)
                raw[k].append(gap)
                raw[f"{k}_folded"].append(folded)
                raw[f"{k}_lbs"].append(stretch - lbs)
        raw = {k: np.stack(v) for k, v in raw.items()}
        entry = {}
        for fam in FAMILIES:
            sel = np.ones(len(fam_of), bool) if fam == "all" else fam_of == names.index(fam)
            entry[fam] = pair_stats(raw, ("v7", *fits), sel)
            say_row(f"{conf:10s} {fam:14s} ", entry[fam])
        results[conf] = entry
    results["seconds"] = time.time() - t0
    print(f"wrote {write_result(args.out, results)}")


if __name__ == "__main__":
    main()
