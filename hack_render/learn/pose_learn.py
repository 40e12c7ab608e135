"""Dynamic deformation learning (paper Sec. 5.2, Eq. 8-12): P_beta and W from registered
mesh sequences.

Per identity i, the trainer fits personal pose blendshapes P_i (72, M, 3) on a vertex subset
M, the shared skinning weights W of those vertices, and (optionally) the per-frame pose theta,
minimising

    E = 1e5 E_rec + 1e6 E_rot + 5e3 E_sim + 5e5 E_col + 1e6 E_tem + 5e-2 E_smo + 1 E_ski

(the paper's weights, :data:`PAPER_WEIGHTS`):

* E_rec (Eq. 8): squared vertex error, summed over vertices, mean over frames (metres^2);
* E_rot (Eq. 9): :func:`hack_render.geometry.skeleton.rotation_limit_penalty`, mean over frames;
* E_sim (Eq. 10): :func:`hack_render.geometry.skeleton.adjacent_similarity_penalty`;
* E_col: the spine inside the skin: each posed joint must lie at least ``col_margin`` behind
  the 32 skin vertices nearest to it at rest, along their outward normals (a penetration
  penalty in the spirit of Hasson et al. 2019);
* E_tem (Eq. 11): per sequence and per optimised scalar (theta), lambda_1 max(|dv/dt| -
  eps, 0)^2 + lambda_2 (d^2v/dt^2)^2 with the paper's (lambda_v, lambda_1, lambda_2, eps);
* E_smo: squared uniform Laplacian of every pose blendshape over the subset mesh;
* E_ski: ||W - W~||^2 to the initial weights.

W stays non-negative with rows summing to one (a softmax over each vertex's support: the
joints it was skinned to, and their chain neighbours). Expressions, larynx and global
orientation are not part of the default training data (psi = 0, eta = 0, root fixed), so
E_beta refinement and psi/eta/tau estimation are not exercised here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.geometry.lbs import (
    chain_parents,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.geometry.skeleton import adjacent_similarity_penalty, rotation_limit_penalty

PAPER_WEIGHTS = {"rec": 1e5, "rot": 1e6, "sim": 5e3, "col": 5e5, "tem": 1e6, "smo": 5e-2, "ski": 1.0}
#: Eq. 11 (lambda_v, lambda_1, lambda_2, epsilon) per parameter.
TEMPORAL = {"psi": (1.0, 1.0, 0.01, 0.1), "theta": (1.0, 1.0, 5000.0, 0.15),
            "eta": (1.0, 1.0, 10.0, 0.005), "tau": (1.0, 1.0, 1.0, 0.001)}


@dataclass
class Sequence:
    """One registered sequence of one identity.

    Attributes:
        identity: index into the identities' rest meshes.
        targets: (F, M, 3) registered vertices on the subset, metres.
        theta: (F, 8, 3) axis-angle per joint (initial estimate, or ground truth).
    """

    identity: int
    targets: np.ndarray
    theta: np.ndarray


@dataclass
class PoseFitResult:
    pose_blendshapes: np.ndarray  # (I, 72, M, 3) metres
    weights: np.ndarray  # (M, K + 1)
    theta: list[np.ndarray]  # per sequence (F, 8, 3)
    history: list[dict] = field(default_factory=list)


def temporal_penalty(v: torch.Tensor, lam_v: float, lam_1: float, lam_2: float, eps: float) -> torch.Tensor:
    """Eq. 11 for one sequence of parameters v (F, ...) -> scalar."""
    if v.shape[0] < 3:
        return v.new_zeros(())
    d1 = v[1:] - v[:-1]
    d2 = v[2:] - 2 * v[1:-1] + v[:-2]
    return lam_v * (lam_1 * torch.relu(d1.abs() - eps).pow(2).sum() + lam_2 * d2.pow(2).sum())


def weight_support(w0: np.ndarray, parents: tuple[int, ...]) -> np.ndarray:
    """(M, K+1) bool: the nodes each vertex may be skinned to: its initial nodes and their
    neighbours on the chain (root = node 0)."""
    par = chain_parents(parents)
    sup = w0 > 1e-6
    out = sup.copy()
    for k, p in enumerate(par):
        if p >= 0:
            out[:, p] |= sup[:, k]
            out[:, k] |= sup[:, p]
    return out


class PoseTrainer:
    """Fits P_i, W (and optionally theta) to registered sequences; see the module docstring.

    Args:
        rest: (I, M, 3) identities' rest vertices on the subset (T_bar + B_S(beta_i)).
        joints: (I, K, 3) rest joints J(beta_i).
        faces: (T, 3) triangles over the subset (0..M-1), for normals and the Laplacian.
        weights_init: (M, K+1) initial (artist / procedural) weights W~.
        parents: joint parents (-1 = root).
    """

    def __init__(self, rest, joints, faces, weights_init, parents, weights: dict | None = None,
                 col_margin: float = 0.005, dtype=torch.float64):
        t = lambda x: torch.as_tensor(np.asarray(x), dtype=dtype)
        self.rest, self.joints = t(rest), t(joints)
        if self.rest.ndim != 3 or self.joints.ndim != 3 or self.rest.shape[0] != self.joints.shape[0]:
            raise HackError(f"PoseTrainer: expected rest (I, M, 3) and joints (I, K, 3), found "
                            f"{tuple(self.rest.shape)} and {tuple(self.joints.shape)}.")
        self.faces = torch.as_tensor(np.asarray(faces), dtype=torch.long)
        self.w_init = t(weights_init)
        self.parents = tuple(parents)
        self.lam = dict(PAPER_WEIGHTS, **(weights or {}))
        unknown = set(self.lam) - set(PAPER_WEIGHTS)
        if unknown:
            raise HackError(f"PoseTrainer: unknown loss weights {sorted(unknown)}; known: {sorted(PAPER_WEIGHTS)}.")
        self.col_margin = col_margin
        self.support = torch.as_tensor(weight_support(np.asarray(weights_init), self.parents))
        m = self.rest.shape[1]
        self.lap = self._laplacian(m)
        # E_col anchors: the 32 subset vertices nearest each joint at rest (per identity).
        d = torch.cdist(self.joints, self.rest)  # (I, K, M)
        self.col_idx = d.topk(min(32, m), largest=False).indices  # (I, K, 32)

    def _laplacian(self, m: int) -> torch.Tensor:
        f = self.faces
        i = torch.cat([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
        j = torch.cat([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
        a = torch.zeros(m, m, dtype=torch.bool)
        a[i, j] = True
        a = a.to(self.rest.dtype)
        deg = a.sum(1, keepdim=True).clamp(min=1)
        return (torch.eye(m, dtype=a.dtype) - a / deg).to_sparse()

    def _normals(self, v: torch.Tensor) -> torch.Tensor:
        f = self.faces
        fn = torch.cross(v[..., f[:, 1], :] - v[..., f[:, 0], :], v[..., f[:, 2], :] - v[..., f[:, 0], :], dim=-1)
        n = torch.zeros_like(v)
        for c in range(3):
            n = n.index_add(-2, f[:, c], fn)
        return n / n.norm(dim=-1, keepdim=True).clamp(min=1e-12)

    def weights_from_logits(self, logits: torch.Tensor) -> torch.Tensor:
        return torch.softmax(logits.masked_fill(~self.support, -1e9), dim=1)

    def predict(self, identity: int, theta: torch.Tensor, pose_blend: torch.Tensor,
                weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Posed subset vertices (F, M, 3) and joints (F, K, 3) of one identity."""
        f = theta.shape[0]
        rot = local_rotations(theta, theta.new_zeros(f, 3))
        feat = pose_feature(rot[:, 1:])  # (F, 72)
        rest = self.rest[identity] + (feat @ pose_blend.reshape(feat.shape[1], -1)).view(f, -1, 3)
        j = self.joints[identity].expand(f, -1, -1)
        nodes = torch.cat([j[:, :1], j], 1)
        posed_nodes, rel = rigid_transforms(rot, nodes, chain_parents(self.parents))
        return skin(rest, weights, rel), posed_nodes[:, 1:]

    def unposed_least_squares(self, sequences: list[Sequence], ridge: float = 1e-6) -> np.ndarray:
        """Closed-form pose blendshapes for the initial weights and the given theta: each
        frame's residual (target - LBS of the rest mesh) is unposed by the inverse of every
        vertex's blended rotation, then P_i = argmin sum_f |feat_f P - r_f|^2 + ridge |P|^2
        per identity (one 72 x 72 solve). Exact when the blended rotations are rigid; a
        starting point (``fit(pose_init=...)``) otherwise.

        Returns:
            (I, 72, M, 3) metres.
        """
        n_id, m = self.rest.shape[:2]
        gram = torch.zeros(n_id, 72, 72, dtype=self.rest.dtype)
        rhs = torch.zeros(n_id, 72, m * 3, dtype=self.rest.dtype)
        zero = torch.zeros(72, m, 3, dtype=self.rest.dtype)
        par = chain_parents(self.parents)
        with torch.no_grad():
            for s in sequences:
                th = torch.as_tensor(s.theta, dtype=self.rest.dtype)
                f = th.shape[0]
                rot = local_rotations(th, th.new_zeros(f, 3))
                feat = pose_feature(rot[:, 1:])
                v, _ = self.predict(s.identity, th, zero, self.w_init)
                j = self.joints[s.identity].expand(f, -1, -1)
                _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), par)
                a = torch.einsum("mk,fkij->fmij", self.w_init, rel[..., :3, :3])  # (F, M, 3, 3)
                r = torch.linalg.solve(a, (torch.as_tensor(s.targets, dtype=v.dtype) - v)[..., None])[..., 0]
                gram[s.identity] += feat.T @ feat
                rhs[s.identity] += feat.T @ r.reshape(f, -1)
            eye = torch.eye(72, dtype=gram.dtype)
            p = torch.linalg.solve(gram + ridge * eye, rhs)
        return p.reshape(n_id, 72, m, 3).numpy()

    def fit(self, sequences: list[Sequence], iterations: int = 1000, lr: float = 1e-3,
            optimise_theta: bool = False, pose_init: np.ndarray | None = None,
            learn_pose: bool = True, learn_weights: bool = True,
            progress: bool = True, log_every: int = 100) -> PoseFitResult:
        """Run Adam on E (Eq. 12), the learning rate decaying linearly to 1 % of ``lr``.

        P is optimised in centimetres so Adam's step (about lr per iteration) is 10
        micrometres at lr = 1e-3. ``learn_pose`` / ``learn_weights`` freeze P or W (e.g. to
        recover one when the other is known: jointly, P and W are not identifiable to first
        order in the rotations, and E_ski decides the split).
        """
        if not sequences:
            raise HackError("PoseTrainer.fit: no sequences given.")
        n_id, m = self.rest.shape[:2]
        dtype = self.rest.dtype
        p_cm = torch.zeros(n_id, 72, m, 3, dtype=dtype) if pose_init is None else \
            torch.as_tensor(pose_init * 100, dtype=dtype).clone()
        p_cm.requires_grad_(True)
        logits = torch.log(self.w_init.clamp(min=1e-4)).clone().requires_grad_(True)
        thetas = [torch.as_tensor(s.theta, dtype=dtype).clone().requires_grad_(optimise_theta)
                  for s in sequences]
        targets = [torch.as_tensor(s.targets, dtype=dtype) for s in sequences]
        params = ([p_cm] if learn_pose else []) + ([logits] if learn_weights else []) \
            + (thetas if optimise_theta else [])
        if not params:
            raise HackError("PoseTrainer.fit: nothing to learn (learn_pose, learn_weights and "
                            "optimise_theta are all off).")
        p_cm.requires_grad_(learn_pose)
        logits.requires_grad_(learn_weights)
        opt = torch.optim.Adam(params, lr=lr)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 1.0 - 0.99 * i / max(iterations, 1))
        history = []
        for it in tqdm(range(iterations), desc="pose learning", disable=not progress, mininterval=2.0):
            w = self.weights_from_logits(logits)
            terms = {k: p_cm.new_zeros(()) for k in PAPER_WEIGHTS}
            frames = 0
            for s, th, tg in zip(sequences, thetas, targets):
                verts, joints = self.predict(s.identity, th, p_cm[s.identity] / 100, w)
                terms["rec"] = terms["rec"] + ((verts - tg) ** 2).sum((1, 2)).sum()
                terms["rot"] = terms["rot"] + rotation_limit_penalty(th).sum()
                terms["sim"] = terms["sim"] + adjacent_similarity_penalty(th).sum()
                terms["col"] = terms["col"] + self._collision(s.identity, verts, joints).sum()
                terms["tem"] = terms["tem"] + temporal_penalty(th, *TEMPORAL["theta"])
                frames += th.shape[0]
            for k in ("rec", "rot", "sim", "col", "tem"):
                terms[k] = terms[k] / frames
            p = p_cm / 100
            terms["smo"] = sum((torch.sparse.mm(self.lap, p[i].permute(1, 0, 2).reshape(m, -1)) ** 2).sum()
                               for i in range(n_id))
            terms["ski"] = ((w - self.w_init) ** 2).sum()
            loss = sum(self.lam[k] * v for k, v in terms.items())
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            if it % log_every == 0 or it == iterations - 1:
                history.append({"iteration": it, "loss": float(loss.detach()),
                                **{k: float(v.detach()) for k, v in terms.items()}})
        return PoseFitResult(pose_blendshapes=(p_cm.detach() / 100).numpy(),
                             weights=self.weights_from_logits(logits).detach().numpy(),
                             theta=[t.detach().numpy() for t in thetas], history=history)

    def _collision(self, identity: int, verts: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        """Per-frame E_col: squared depth by which joints come closer than the margin to (or
        poke through) the skin around them."""
        n = self._normals(verts)  # (F, M, 3)
        idx = self.col_idx[identity]  # (K, 32)
        v = verts[:, idx]  # (F, K, 32, 3)
        d = ((v - joints[:, :, None]) * n[:, idx]).sum(-1)  # signed distance, > 0 inside
        return torch.relu(self.col_margin - d).pow(2).sum((1, 2))
