"""Pose correctives learned by minimising the neck skin's deformation energy over the
whole joint space (issue 21).

Why not regression onto simulated targets (docs/learn.md): correctives fitted to DQS + ARAP
sequences that moved one axis at a time extrapolated badly where axes combine, and ARAP's
own targets fold skin under combined poses. This learner asks the skinned neck itself to be
well behaved over poses sampled from the whole space (every joint uniform within its
limits, whole-head rotations up to each axis's full range, singly and combined), for
identities sampled afresh at every step, so M_P generalises to identities it never saw.

The model (paper Eq. 2-3, unchanged in form): the posed neck is
``LBS(T(beta) + f(theta) (P + sum_c m_c(beta) C_c), J(beta), theta, W)``, f = the 72 pose
features (R_k - I), P the generic pose blendshapes, C_c the personalised components and
m(beta) the M_P MLP (3 layers, 64 units), W the skinning weights of the neck vertices
(softmax over each vertex's chain neighbourhood). All of P, C, m and W are learned.

Energy per pose, over the skin triangles touching the neck (:class:`NeckRegion`), each term
a mean over its elements (r = |e| / |e0| - 1 per edge):

* ``strain``: r^2 (overall elasticity);
* ``stretch`` / ``compress``: relu(r - s0)^2 / relu(-r - c0)^2, the tails the stress test
  measures;
* ``fold``: relu(f0 - cos)^2, cos between a triangle's posed normal and its rest normal
  carried by its blended rigid rotation (the stress test's fold measure, made smooth);
* ``bend``: the change of the cosine between adjacent triangles' normals (bending
  stiffness: the buckling that ARAP lacks);
* ``worse``: per edge and triangle, the excess over plain LBS of the same pose and
  identity (stretch beyond max(LBS, s0), cos below min(LBS, f0)), LBS with the initial
  weights W0 and with the current W, whichever is better: correctives may only improve
  on LBS;
* ``fold_sum``: the fold hinge summed over a pose's triangles (``fold`` is a mean over
  some 3,000 triangles, so a pose that folds a handful weighs almost nothing in it; this
  term makes every folding triangle count);
* ``worse_max``: per pose, the excess of the largest edge stretch over plain LBS's largest
  (the stricter of W0 and the current W) plus a margin: the stress test's "worse than LBS";
* ``worse_pose``: the same bound on every edge, summed over a pose's edges: each edge
  stretched past plain LBS's largest stretch of that pose counts (the max alone moves
  one edge per step, and the next one then stands out);
* ``bound``: per edge, the stretch beyond the pose's stretch bound (the largest stretch
  no deformation with the face and chest rigid can avoid: :func:`~hack_render.learn.
  neck_region.region_bound`) plus ``bound_margin``, squared and summed over a pose's edges
  (off by default: the bench's "stretch above the bound", as a loss);
* ``smooth``: the squared uniform Laplacian of P over the region; ``weights``: ||W - W0||^2.

Hard examples (issue 21: the rare full-range combined rotations that still folded once the
mean energy was low): every few steps the learner screens a fresh batch without gradients
and keeps, in a pool, the pose-identity-expression triples that fold a triangle, come
within a margin of folding, or stretch more than plain LBS; each step then trains on some
of the pool beside the fresh samples (with ``near_bound`` > 0, also the rows whose largest
stretch exceeds their bound by more than it).

Rest shapes: T_bar + B_S(beta), or with ``rest_fn`` the model's own rest mesh for each
identity and a sampled expression, as the stress test measures it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from hack_render.geometry.deformation import (
    sample_corner_head_poses,
    sample_head_poses,
    sample_joint_poses,
)
from hack_render.geometry.lbs import (
    chain_parents,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.learn.neck_region import (
    NeckRegion,
    anchor_path_lengths,
    region_anchors,
    region_bound,
    skin_measures,
)
from hack_render.learn.pose_learn import weight_support

#: loss weights and thresholds (s0, c0: stretch / compression past which the tails count;
#: f0: the normal cosine below which a triangle counts as folding)
DEFAULTS = {"s0": 0.2, "c0": 0.3, "f0": 0.3, "strain": 1.0, "stretch": 30.0, "compress": 10.0,
            "fold": 30.0, "bend": 3.0, "worse": 300.0, "smooth": 1e-3, "weights": 1e-2,
            "fold_sum": 1.0, "worse_max": 100.0, "worse_pose": 0.0, "worse_margin": 0.005,
            "near_fold": 0.1, "near_worse": 0.0, "bound": 0.0, "bound_margin": 0.1,
            "near_bound": 0.0, "anchor": 0.0}

#: terms of :meth:`PoseEnergyLearner.terms` (the other DEFAULTS keys are thresholds)
TERMS = ("strain", "stretch", "compress", "fold", "bend", "worse", "smooth", "weights",
         "fold_sum", "worse_max", "worse_pose", "bound", "anchor")


def _minutes(seconds: float) -> str:
    """A duration for a person: "40 s", "12 min", "1.5 h"."""
    return (f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min" if seconds < 5400
            else f"{seconds / 3600:.1f} h")


@dataclass
class PoseEnergyResult:
    """Learned arrays (float32, model-file layout) and the training record."""

    pose_basis: np.ndarray  # (72, M, 3) generic P on the subset, metres
    components: np.ndarray  # (C, 72, M, 3) personalised components
    mlp: dict[str, np.ndarray]  # M_P: w0, b0, w1, b1, w2, b2
    weights: np.ndarray  # (M, K + 1) skinning weights of the subset
    history: list[dict] = field(default_factory=list)
    seconds: float = 0.0


@dataclass
class PoseBatch:
    """Training rows: identities beta (B, S), poses theta (B, 8, 3), expressions psi (B, E)
    or None, and each row's rest region (B, V, 3) and rest joints (B, K, 3); ``fresh`` (B,)
    bool: rows of newly sampled identities (None: all), the only rows M_P learns from;
    ``bound`` (B,): each row's stretch bound (:func:`~hack_render.learn.neck_region.
    region_bound`), or None where the learner needs none."""

    beta: torch.Tensor
    theta: torch.Tensor
    psi: torch.Tensor | None
    rest: torch.Tensor
    joints: torch.Tensor
    fresh: torch.Tensor | None = None
    bound: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.theta.shape[0]

    def rows(self, keep: torch.Tensor) -> PoseBatch:
        return PoseBatch(self.beta[keep], self.theta[keep], None if self.psi is None else self.psi[keep],
                         self.rest[keep], self.joints[keep],
                         None if self.fresh is None else self.fresh[keep],
                         None if self.bound is None else self.bound[keep])

    @staticmethod
    def cat(parts: list[PoseBatch]) -> PoseBatch:
        psi = None if any(p.psi is None for p in parts) else torch.cat([p.psi for p in parts])
        fresh = None
        if any(p.fresh is not None for p in parts):
            fresh = torch.cat([torch.ones(len(p), dtype=torch.bool) if p.fresh is None else p.fresh
                               for p in parts])
        bound = (None if any(p.bound is None for p in parts)
                 else torch.cat([p.bound for p in parts]))
        return PoseBatch(*(torch.cat([getattr(p, k) for p in parts]) for k in ("beta", "theta")),
                         psi, *(torch.cat([getattr(p, k) for p in parts]) for k in ("rest", "joints")),
                         fresh, bound)


class PoseEnergyLearner:
    """Learns P, C, M_P and W (see the module docstring).

    Args:
        template: (N, 3) T_bar (with the model's default larynx), metres.
        shape_dirs: (S, N, 3) shape blendshapes times their std (beta ~ N(0, I)).
        joint_regressor: (K, N); weights: (N, K + 1) initial skinning weights W0.
        parents: joint parents; region: :func:`neck_region`; subset: (M,) model ids.
        num_components: C, personalised components; num_shape: betas fed to M_P.
        rest_fn: optional ``(beta (U, S), psi (U, E) or None) -> (rest (U, V, 3), joints
            (U, K, 3))``, the region's rest vertices and the rest joints of each identity
            and expression (default: T_bar + B_S(beta) and the regressor's joints).
        num_expressions: E, expression weights sampled for ``rest_fn`` (0: neutral only);
        jaw_open: the index of the jaw opening among them, sampled more often;
        symmetric: (left, right) index pairs of mirrored expressions (e.g. mouthSmile_L /
        _R), given one value on both sides in half of the expressive rows.
        gate_deg: the correctives' gate angle, degrees (each joint's feature times
            :func:`~hack_render.geometry.lbs.pose_gate`; model format 3), or None.
        gate_chain: the gate's chain weight lambda (the chain's net rotation opens every
            joint's gate; model format 4), 0: each joint's own angle alone.
        single_axis: sample a quarter of the poses as whole-head rotations about one axis
            alone (x, y or z, a third each, as the stress test's head_x/y/z families)
            instead of combined ones at 60 % of the range.
        corner: the share of the full-range whole-head poses (batches and mined rows)
            drawn near the box's corners (:func:`sample_corner_head_poses`); 0: none.
    """

    def __init__(self, template, shape_dirs, joint_regressor, weights, parents, region: NeckRegion,
                 num_components: int = 8, num_shape: int = 20, hidden: int = 64,
                 loss: dict | None = None, seed: int = 0, dtype=torch.float64,
                 rest_fn=None, num_expressions: int = 0, jaw_open: int | None = None,
                 symmetric: list[tuple[int, int]] | None = None, gate_deg: float | None = None,
                 single_axis: bool = False, gate_chain: float = 0.0, corner: float = 0.0):
        self.single_axis, self.corner = single_axis, float(corner)
        self.gate_rad = None if not gate_deg else float(np.deg2rad(gate_deg))
        self.gate_chain = float(gate_chain)
        t = lambda x: torch.as_tensor(np.asarray(x), dtype=dtype)
        self.region, self.parents = region, tuple(parents)
        self.lam = dict(DEFAULTS, **(loss or {}))
        vid = region.vertices
        self.template = t(template)[vid]
        sd = t(shape_dirs)[:num_shape]
        self.shape_dirs = sd[:, vid]
        reg = t(joint_regressor)
        self.joints0 = reg @ t(template)
        self.joint_dirs = torch.einsum("kn,snc->skc", reg, sd)
        self.num_shape = num_shape
        w0 = t(weights)[vid]
        self.w_fixed = w0
        sub = region.subset
        self.w0_sub = w0[sub]
        support = torch.as_tensor(weight_support(w0[sub].numpy(), self.parents))
        rigid = self.w0_sub.max(1).values >= 1 - 1e-6  # skull- or root-rigid rows stay so
        self.support = torch.where(rigid[:, None], self.w0_sub > 0.5, support)
        self.anchors = region_anchors(region, w0)
        m = len(sub)
        g = torch.Generator().manual_seed(seed)
        self.p_cm = torch.zeros(72, m, 3, dtype=dtype, requires_grad=True)
        self.c_cm = (1e-3 * torch.randn(num_components, 72, m, 3, generator=g, dtype=dtype)).requires_grad_()
        self.mlp = torch.nn.Sequential(torch.nn.Linear(num_shape, hidden), torch.nn.ReLU(),
                                       torch.nn.Linear(hidden, hidden), torch.nn.ReLU(),
                                       torch.nn.Linear(hidden, num_components)).to(dtype)
        # small, not zero: with a zero last layer and near-zero C, neither gets a gradient
        torch.nn.init.normal_(self.mlp[4].weight, std=0.01, generator=g)
        torch.nn.init.zeros_(self.mlp[4].bias)
        self.logits = torch.log(self.w0_sub.clamp(min=1e-4)).clone().requires_grad_()
        self.lap = self._laplacian(m)
        self.rest_fn, self.num_expressions = rest_fn, num_expressions if rest_fn else 0
        self.jaw_open = jaw_open
        self.symmetric = torch.as_tensor(symmetric or [], dtype=torch.long).reshape(-1, 2)

    def start_from(self, arrays: dict) -> None:
        """Continue from learned model arrays (``pose_basis`` on the subset's rows,
        ``pose_pca_components``, ``pose_mlp_*``, ``skinning_weights``; model-file layout)."""
        sub_ids = self.region.vertices[self.region.subset].numpy()
        with torch.no_grad():
            self.p_cm.copy_(torch.as_tensor(np.asarray(arrays["pose_basis"])[:, sub_ids]) * 100)
            self.c_cm.copy_(torch.as_tensor(np.asarray(arrays["pose_pca_components"])) * 100)
            self._start = (self.p_cm.detach().clone(), self.c_cm.detach().clone())
            lin = [m for m in self.mlp if isinstance(m, torch.nn.Linear)]
            for i, layer in enumerate(lin):
                layer.weight.copy_(torch.as_tensor(np.asarray(arrays[f"pose_mlp_w{i}"])))
                layer.bias.copy_(torch.as_tensor(np.asarray(arrays[f"pose_mlp_b{i}"])))
            w = torch.as_tensor(np.asarray(arrays["skinning_weights"]), dtype=self.logits.dtype)
            self.logits.copy_(torch.log(w[sub_ids].clamp(min=1e-6)))

    def personalisation_spread(self, seed: int = 0, samples: int = 512) -> float:
        """The largest standard deviation of M_P's output over sampled identities (0 for a
        dead M_P: one constant for every identity)."""
        g = torch.Generator().manual_seed(seed)
        beta = torch.randn(samples, self.num_shape, generator=g, dtype=self.template.dtype)
        with torch.no_grad():
            return float(self.mlp(beta).std(0).max())

    def restart_personalisation(self, seed: int = 0, samples: int = 512) -> float:
        """Fold M_P's mean output over sampled identities into P (``P += mean_beta m(beta) C``)
        and restart M_P small, as at construction: a continuation whose M_P had died (one
        constant for every identity) keeps its generic correctives and learns the personal
        part afresh. Returns the largest standard deviation of the old m(beta) over the
        samples (0 for a dead M_P)."""
        g = torch.Generator().manual_seed(seed)
        beta = torch.randn(samples, self.num_shape, generator=g, dtype=self.template.dtype)
        with torch.no_grad():
            w = self.mlp(beta)
            self.p_cm += torch.einsum("c,cdmk->dmk", w.mean(0), self.c_cm)
            for layer in self.mlp:
                if isinstance(layer, torch.nn.Linear):
                    layer.reset_parameters()
            torch.nn.init.normal_(self.mlp[4].weight, std=0.01, generator=g)
            torch.nn.init.zeros_(self.mlp[4].bias)
        return float(w.std(0).max())

    def _laplacian(self, m: int) -> torch.Tensor:
        sub = self.region.subset
        loc = -torch.ones(len(self.region.vertices), dtype=torch.long)
        loc[sub] = torch.arange(m)
        e = loc[self.region.edges]
        e = e[(e >= 0).all(1)]
        i = torch.cat([e[:, 0], e[:, 1]])
        j = torch.cat([e[:, 1], e[:, 0]])
        deg = torch.zeros(m, dtype=self.template.dtype).index_add_(0, i, torch.ones(len(i), dtype=self.template.dtype))
        vals = -1.0 / deg.clamp(min=1)[i]
        idx = torch.cat([torch.stack([i, j]), torch.arange(m).repeat(2, 1)], 1)
        return torch.sparse_coo_tensor(idx, torch.cat([vals, torch.ones(m, dtype=vals.dtype)]), (m, m),
                                       check_invariants=True).coalesce()

    def weights(self) -> torch.Tensor:
        """(V, K + 1) region weights: learned on the subset, W0 elsewhere."""
        ws = torch.softmax(self.logits.masked_fill(~self.support, -1e9), dim=1)
        return self.w_fixed.index_put((self.region.subset,), ws)

    def blendshapes(self, beta: torch.Tensor, fresh: torch.Tensor | None = None) -> torch.Tensor:
        """(B, 72, M, 3) P + sum_c m_c(beta) C_c, metres; ``fresh`` (B,) bool: the rows whose
        gradient reaches M_P (the others see its output as a constant)."""
        w = self.mlp(beta)
        if fresh is not None:
            w = torch.where(fresh[:, None], w, w.detach())
        return (self.p_cm + torch.einsum("bc,cdmk->bdmk", w, self.c_cm)) / 100

    def rest(self, beta: torch.Tensor, psi: torch.Tensor | None = None):
        """Rest region (U, V, 3) and rest joints (U, K, 3) of identities beta (U, S) with
        expressions psi (U, E) (see ``rest_fn``)."""
        if self.rest_fn is not None:
            with torch.no_grad():
                rest, joints = self.rest_fn(beta, psi)
            return rest.to(self.template.dtype), joints.to(self.template.dtype)
        rest = self.template + torch.einsum("bs,svc->bvc", beta, self.shape_dirs)
        return rest, self.joints0 + torch.einsum("bs,skc->bkc", beta, self.joint_dirs)

    def pose(self, batch: PoseBatch, corrective: bool = True, weights: torch.Tensor | None = None):
        """Posed region (B, V, 3) and node rotations (B, K+1, 3, 3) of a :class:`PoseBatch`;
        without ``corrective``, plain LBS with ``weights`` (default W0)."""
        theta, rest = batch.theta, batch.rest
        rot, rel = self._transforms(theta, batch.joints)
        v = rest
        if corrective:
            feat = pose_feature(rot[:, 1:], self.gate_rad, self.gate_chain)  # as the model file will
            delta = torch.einsum("bd,bdmk->bmk", feat, self.blendshapes(batch.beta, batch.fresh))
            v = rest.index_add(1, self.region.subset, delta)
        w = self.weights() if corrective else (self.w_fixed if weights is None else weights)
        return skin(v, w, rel), rel[..., :3, :3]

    def _transforms(self, theta: torch.Tensor, joints: torch.Tensor):
        """Node rotations (B, K+1, 3, 3) of poses theta (B, 8, 3) and the nodes' transforms
        (B, K+1, 4, 4), rest to posed, about rest joints (B, K, 3)."""
        rot = local_rotations(theta, theta.new_zeros(theta.shape[0], 3))
        _, rel = rigid_transforms(rot, torch.cat([joints[:, :1], joints], 1), chain_parents(self.parents))
        return rot, rel

    def _wants_bound(self) -> bool:
        return bool(self.lam["bound"] or self.lam["near_bound"])

    def _bounds(self, rest: torch.Tensor, joints: torch.Tensor, theta: torch.Tensor,
                per: int) -> torch.Tensor:
        """(B,) the stretch bound of each row: ``per`` consecutive rows share an identity's
        rest region (U, V, 3) and joints (U, K, 3); theta (B, 8, 3)."""
        paths = torch.stack([torch.as_tensor(anchor_path_lengths(r.numpy(), self.anchors))
                             for r in rest]).to(rest.dtype)
        with torch.no_grad():
            _, rel = self._transforms(theta, joints.repeat_interleave(per, 0))
            return region_bound(rest.repeat_interleave(per, 0), rel, self.anchors,
                                paths.repeat_interleave(per, 0))

    def _lbs_reference(self, batch: PoseBatch):
        """Plain LBS with W0 and with the current W, the stricter per element: edge strain
        (B, E), fold cosines (B, T), and per pose the smaller of the two largest strains (B,)."""
        reg = self.region
        with torch.no_grad():
            r_l, c_l, r_max = None, None, None
            for w in (self.w_fixed, self.weights()):
                lbs, rot0 = self.pose(batch, corrective=False, weights=w)
                r, c, _ = skin_measures(reg, batch.rest, lbs, rot0, w[reg.faces].mean(1))
                r_l = r if r_l is None else torch.minimum(r_l, r)
                c_l = c if c_l is None else torch.maximum(c_l, c)
                r_max = r.amax(1) if r_max is None else torch.minimum(r_max, r.amax(1))
        return r_l, c_l, r_max

    def terms(self, batch: PoseBatch) -> dict[str, torch.Tensor]:
        lam, reg = self.lam, self.region
        r_l, c_l, r_lmax = self._lbs_reference(batch)
        posed, rot = self.pose(batch)
        r, cosf, bend = skin_measures(reg, batch.rest, posed, rot, self.weights()[reg.faces].mean(1))
        s0 = torch.full_like(r_l, lam["s0"])
        f0 = torch.full_like(c_l, lam["f0"])
        p = self.p_cm / 100
        m = p.shape[1]
        fold = torch.relu(lam["f0"] - cosf).pow(2)
        above = (r.new_zeros(()) if batch.bound is None else torch.relu(
            r - (batch.bound + lam["bound_margin"])[:, None]).pow(2).sum(1).mean())
        return {
            "strain": (r ** 2).mean(), "stretch": torch.relu(r - lam["s0"]).pow(2).mean(),
            "compress": torch.relu(-r - lam["c0"]).pow(2).mean(),
            "fold": fold.mean(), "bend": (bend ** 2).mean(),
            "worse": torch.relu(r - torch.maximum(r_l, s0)).pow(2).mean()
            + torch.relu(torch.minimum(c_l, f0) - cosf).pow(2).mean(),
            "smooth": (torch.sparse.mm(self.lap, p.permute(1, 0, 2).reshape(m, -1)) ** 2).sum(),
            "weights": ((self.weights()[reg.subset] - self.w0_sub) ** 2).sum(),
            "fold_sum": fold.sum(1).mean(),
            "worse_max": torch.relu(r.amax(1) - r_lmax + lam["worse_margin"]).pow(2).mean(),
            "worse_pose": torch.relu(r - r_lmax[:, None] + lam["worse_margin"]).pow(2).sum(1).mean(),
            "bound": above,
            # (P, C) - their values at :meth:`start_from`, cm^2: a continuation's trust region
            "anchor": sum(((x - x0) ** 2).sum() for x, x0 in zip((self.p_cm, self.c_cm), self._start))
            if getattr(self, "_start", None) is not None else r.new_zeros(()),
        }

    def screen(self, batch: PoseBatch) -> torch.Tensor:
        """(B,) bool: the hard examples: the rows that fold a triangle or come near it (a
        fold cosine below ``near_fold``), or whose largest strain comes within
        ``near_worse`` of plain LBS's (the stricter of W0 and W) or exceeds it, or (with
        ``near_bound`` > 0) exceeds the row's bound by more than ``near_bound``."""
        reg = self.region
        with torch.no_grad():
            _, _, r_lmax = self._lbs_reference(batch)
            posed, rot = self.pose(batch)
            r, cosf, _ = skin_measures(reg, batch.rest, posed, rot, self.weights()[reg.faces].mean(1))
        hard = (cosf.amin(1) < self.lam["near_fold"]) | (r.amax(1) > r_lmax - self.lam["near_worse"])
        if self.lam["near_bound"] and batch.bound is not None:
            hard |= r.amax(1) > batch.bound + self.lam["near_bound"]
        return hard

    def _expressions(self, g: torch.Generator, n: int) -> torch.Tensor | None:
        """(n, E) expressions: half neutral, the rest a jaw opening (U(0, 1), half the
        time) and each other weight U(0, 1) with probability 0.15, mirrored pairs given
        their left value on both sides in half of the rows (a smile is usually both
        sides': the stress test holds one)."""
        if not self.num_expressions:
            return None
        dt = self.template.dtype
        psi = torch.rand(n, self.num_expressions, generator=g, dtype=dt)
        psi = psi * (torch.rand(n, self.num_expressions, generator=g, dtype=dt) < 0.15)
        if len(self.symmetric):
            both = torch.rand(n, generator=g) < 0.5
            left, right = self.symmetric[:, 0], self.symmetric[:, 1]
            psi[:, right] = torch.where(both[:, None], psi[:, left], psi[:, right])
        if self.jaw_open is not None:
            psi[:, self.jaw_open] = torch.rand(n, generator=g, dtype=dt) * (torch.rand(n, generator=g) < 0.5)
        return psi * (torch.rand(n, 1, generator=g) < 0.5)

    def sample(self, g: torch.Generator, identities: int, poses: int) -> PoseBatch:
        """A batch: identities beta ~ N(0, I) (each with a sampled expression where
        ``rest_fn`` is given), each in ``poses`` poses (half per-joint uniform, a quarter
        whole-head at full range, ``corner`` of them near the corners, a quarter at 60 % of
        it or, with ``single_axis``, about one axis alone)."""
        k = max(poses // 4, 1)
        n = identities * k
        if self.single_axis:
            last = torch.cat([sample_head_poses(n // 3 + (i < n % 3), g, ax) for i, ax in enumerate("xyz")])
        else:
            last = 0.6 * sample_head_poses(n, g, "xyz")
        joint = sample_joint_poses(identities * (poses - 2 * k), g)
        c = round(n * self.corner)
        full = [sample_corner_head_poses(c, g)] * bool(c) + [sample_head_poses(n - c, g, "xyz")]
        th = torch.cat([joint, *full, last]).to(self.template.dtype)
        th = th[torch.randperm(len(th), generator=g)]
        beta = torch.randn(identities, self.num_shape, generator=g, dtype=self.template.dtype)
        psi = self._expressions(g, identities)
        rest, joints = self.rest(beta, psi)
        per = len(th) // identities
        rep = lambda x: None if x is None else x.repeat_interleave(per, 0)
        bound = self._bounds(rest, joints, th, per) if self._wants_bound() else None
        return PoseBatch(rep(beta), th, rep(psi), rep(rest), rep(joints), bound=bound)

    def fit(self, iterations: int = 600, lr: float = 0.01, identities: int = 4, poses: int = 8,
            learn_weights: bool = True, seed: int = 0, progress: bool = True,
            log_every: int = 50, mlp_lr: float = 1e-4, hard: int = 0, mine_every: int = 10,
            mine_poses: int = 48, pool_size: int = 512,
            mine_identities: int | None = None, report=None) -> PoseEnergyResult:
        """Adam (``lr`` in centimetres for P and C, and for W's logits; ``mlp_lr`` for M_P,
        the paper's 1e-4: at 1e-2 its hidden units all died within a few hundred steps and
        it returned one constant for every identity), decaying linearly to 10 %.

        ``hard`` > 0: every ``mine_every`` steps screen ``mine_identities`` (default:
        ``identities``) x ``mine_poses`` fresh rows (:meth:`screen`) and keep the hard ones
        in a pool of at most ``pool_size`` (oldest dropped); each step adds ``hard`` rows
        drawn from the pool. More mined identities bring more sampled expressions (one per
        identity), where a fold that needs an expression and a pose together is found.

        ``report``: called once with the time a step takes, measured over the first
        ``mine_every`` steps (one mining round), and the run's time in all."""
        groups = [{"params": [self.p_cm, self.c_cm] + ([self.logits] if learn_weights else []),
                   "lr": lr, "base": lr},
                  {"params": list(self.mlp.parameters()), "lr": mlp_lr, "base": mlp_lr}]
        opt = torch.optim.Adam(groups)
        g = torch.Generator().manual_seed(seed)
        hist, t0, pool, mined = [], time.time(), None, 0
        for it in tqdm(range(iterations), desc="pose correctives", disable=not progress, mininterval=2.0):
            for grp in opt.param_groups:
                grp["lr"] = grp["base"] * (1 - 0.9 * it / max(iterations, 1))
            if hard and it % mine_every == 0:
                cand = self.sample(g, mine_identities or identities, mine_poses)
                found = cand.rows(self.screen(cand))
                # M_P learns from fresh identities only: the pool repeats a few hundred
                # identities for many steps, and M_P fitted to them did worse on unseen ones
                found.fresh = torch.zeros(len(found), dtype=torch.bool)
                mined += len(found)
                pool = found if pool is None else PoseBatch.cat([pool, found])
                pool = pool.rows(torch.arange(max(len(pool) - pool_size, 0), len(pool)))
            batch = self.sample(g, identities, poses)
            if hard and pool is not None and len(pool):
                pick = torch.randint(len(pool), (min(hard, len(pool)),), generator=g)
                batch = PoseBatch.cat([batch, pool.rows(pick)])
            terms = self.terms(batch)
            loss = sum(self.lam[k] * v for k, v in terms.items())
            opt.zero_grad()
            loss.backward()
            opt.step()
            if report is not None and it == min(mine_every, iterations) - 1:
                step = (time.time() - t0) / (it + 1)
                report(f"about {step:.1f} s a step here (over the first {it + 1}), "
                       f"~{_minutes(step * iterations)} in all")
            if it % log_every == 0 or it == iterations - 1:
                hist.append({"iteration": it, "loss": float(loss.detach()),
                             **{k: float(v.detach()) for k, v in terms.items()},
                             **({"pool": 0 if pool is None else len(pool), "mined": mined} if hard else {})})
        lin = [m for m in self.mlp if isinstance(m, torch.nn.Linear)]
        mlp = {}
        for i, layer in enumerate(lin):
            mlp[f"w{i}"] = layer.weight.detach().numpy().astype(np.float32)
            mlp[f"b{i}"] = layer.bias.detach().numpy().astype(np.float32)
        return PoseEnergyResult(
            pose_basis=(self.p_cm.detach() / 100).numpy().astype(np.float32),
            components=(self.c_cm.detach() / 100).numpy().astype(np.float32), mlp=mlp,
            weights=self.weights()[self.region.subset].detach().numpy().astype(np.float32),
            history=hist, seconds=time.time() - t0)
