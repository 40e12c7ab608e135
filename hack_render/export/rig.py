"""One person's HACK as a CG rig: a rest mesh, morph targets, a skeleton and skin weights,
and the morph weights and joint rotations that reproduce the model's forward pass.

The forward pass (``geometry/model.py``) for a fixed identity beta and larynx size eta is

    rest = v_shaped + psi @ E(beta) + f(theta) @ P(beta) + L(beta, eta, tau)
    G    = transl + sum_k W[:, k] rel_k(theta, global_orient) rest

with ``f(theta)`` the pose feature (R_j - I per joint, 72 numbers). A glTF skinned mesh
with morph targets computes ``sum_k w_k J_k IBM_k (base + sum_t weight_t delta_t)``, so:

- base: ``v_shaped + L(beta, eta, 0)`` (identity and larynx size baked in);
- targets: the 53 personalised expressions E(beta) (weights psi), ``larynx_size``
  (L at eta = 1, tau = 0: weight = a change of eta), the larynx slide as in-between
  targets at fixed tau (weights: linear interpolation between neighbours, since L is not
  linear in tau), and the pose correctives P(beta) (weights: the pose feature), each
  feature's target split by sign so that every weight is >= 0 (:func:`pose_split`:
  diagonal features R_ii - 1 are never positive; 8 x (3 + 2 x 6) = 120 targets). Weights
  in [0, 1] are what importers expect: Blender's glTF importer (4.5) widens a shape key's
  slider range from the first keyframe only, and clamps the rest;
- skeleton: a root (thorax, at c7-t1, carrying global_orient and transl) and the 8 joints
  with rest-pose inverse bind matrices; 4 weights per vertex (the model's 9, truncated to
  the largest 4: :func:`top_weights`; :attr:`ExportRig.weight_error_m` says what it
  costs), or 8 (two glTF sets; the model never has more than 8 nonzero, so exact);
- the flexion block of a format-5 model (:mod:`hack_render.geometry.flex_block`): one
  target per hat (its offsets for this identity), weighted by the hat times the purity
  factor of the joints' net rotation (:func:`flex_weights_np`; at most two non-zero).

Pure torch/numpy; no file formats here (see :mod:`.gltf`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.geometry.flex_block import flex_weights_np
from hack_render.geometry.lbs import (
    chain_parents,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.geometry.rotations import euler_to_axis_angle

ROOT_NAME = "thorax"
#: Larynx slide in-betweens: spacing and default half-range, metres.
TAU_STEP = 0.001
TAU_RANGE = 0.02
INFLUENCES = 4


@dataclass
class ExportRig:
    """A person ready for a CG format (N = model vertices, K = morph targets).

    Attributes:
        base: (N, 3) float64 rest mesh, metres.
        target_names: K names; expressions first, in the model's order.
        targets: (K, N, 3) float32 morph deltas, metres (mostly zero rows: see nonzero).
        node_names: 9 names, root first, then the model's joints.
        parents: 9 parent indices (-1 for the root).
        rest_nodes: (9, 3) rest positions of the nodes (the root sits at c7-t1).
        joints4: (N, I) int node indices; weights4: (N, I) float32, rows sum to 1
            (I = 4 influences, or 8).
        weight_error_m: largest vertex displacement (m) that keeping I weights causes over
            the poses of :func:`weight_truncation_error` (joints at their limits).
        tau_grid: (G,) float64 slide values of the in-between targets (0 excluded).
        num_expressions: E; the expression targets are ``targets[:E]``.
        eta: the larynx size baked into ``base``.
        pose_gate_rad: the model's corrective gate (format 3, ``HackModel.pose_gate_rad``):
            each joint's pose-corrective weights are its ``R - I`` times
            :func:`~hack_render.geometry.lbs.pose_gate`; None: ungated.
        pose_gate_chain: the gate's chain weight (format 4, ``HackModel.pose_gate_chain``;
            0: each joint's own angle alone).
        flex: the flexion block's hats (format 5): ``knots_deg``, ``width_deg``,
            ``purity_deg``, ``coherence``; None: no block. Its targets are the last ``len(knots_deg)``.
    """

    base: np.ndarray
    target_names: list[str]
    targets: np.ndarray
    node_names: list[str]
    parents: list[int]
    rest_nodes: np.ndarray
    joints4: np.ndarray
    weights4: np.ndarray
    weight_error_m: float
    tau_grid: np.ndarray
    num_expressions: int
    eta: float
    pose_gate_rad: float | None = None
    pose_gate_chain: float = 0.0
    flex: dict | None = None

    @property
    def slots(self) -> dict[str, slice]:
        """Where each kind of target sits in ``targets``."""
        e, g, n = self.num_expressions, len(self.tau_grid), len(self.target_names)
        f = n - (len(self.flex["knots_deg"]) if self.flex else 0)
        out = {"expression": slice(0, e), "larynx_size": slice(e, e + 1),
               "larynx_slide": slice(e + 1, e + 1 + g), "pose": slice(e + 1 + g, f)}
        if self.flex:
            out["flex"] = slice(f, n)
        return out


def top_weights(weights: np.ndarray, k: int = INFLUENCES) -> tuple[np.ndarray, np.ndarray]:
    """Keep the k largest weights per row. weights (N, J), nodes in chain order (a serial
    chain: node j's neighbours are j - 1 and j + 1) -> idx (N, k), w (N, k) float32.

    A dropped weight goes to the kept node nearest to it along the chain (ties: the one
    below), not spread over all kept nodes: neighbouring joints move alike, so this costs
    less (4 influences, joints at their limits: 4.6 mm instead of 12 mm for plain
    renormalisation on the default model). Rows still sum to 1; unused slots get index 0
    and weight 0."""
    weights = np.asarray(weights, np.float64)
    n, j = weights.shape
    idx = np.argsort(-weights, axis=1, kind="stable")[:, :k]
    valid = np.take_along_axis(weights, idx, 1) > 0
    nodes = np.arange(j)[None, :, None]  # (1, J, 1) against kept (N, 1, k)
    dist = np.abs(idx[:, None, :] - nodes) + 1e-3 * (idx[:, None, :] > nodes)
    slot = np.argmin(np.where(valid[:, None, :], dist, np.inf), axis=2)  # (N, J)
    w = np.zeros((n, idx.shape[1]))
    for node in range(j):
        np.add.at(w, (np.arange(n), slot[:, node]), weights[:, node])
    w /= w.sum(1, keepdims=True)
    idx = np.where(w > 0, idx, 0)
    order = np.argsort(-w, axis=1, kind="stable")  # nonzero weights first
    return np.take_along_axis(idx, order, 1), np.take_along_axis(w, order, 1).astype(np.float32)


def tau_weights(tau: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Weights (T, G) of the slide in-betweens at ``grid`` (G,) for slides tau (T,): linear
    interpolation between the two neighbours (0 is the base, no target), clamped at the
    ends of the grid."""
    full = np.sort(np.r_[grid, 0.0])
    t = np.clip(np.asarray(tau, np.float64), full[0], full[-1])
    j = np.clip(np.searchsorted(full, t, side="right") - 1, 0, len(full) - 2)
    a = (t - full[j]) / (full[j + 1] - full[j])
    out = np.zeros((len(t), len(full)))
    np.put_along_axis(out, j[:, None], (1 - a)[:, None], 1)
    np.put_along_axis(out, (j + 1)[:, None], a[:, None], 1)
    keep = full != 0.0
    return out[:, keep]


def pose_split(num_joints: int) -> list[tuple[int, float, str]]:
    """The pose-corrective targets: (feature index, sign, name) each; the target is sign
    times the feature's corrective and its weight max(sign * feature, 0). Diagonal
    features (R_ii - 1 <= 0) have one target (sign -1), the others one per sign."""
    out = []
    for j in range(num_joints):
        for r in range(3):
            for c in range(3):
                f = 9 * j + 3 * r + c
                out += [(f, -1.0, f"r{r}{c}-")] if r == c else [(f, 1.0, f"r{r}{c}+"),
                                                                (f, -1.0, f"r{r}{c}-")]
    return out


def pose_features(theta: torch.Tensor, gate_rad: float | None = None,
                  chain: float = 0.0) -> torch.Tensor:
    """theta (T, 8, 3) axis-angle -> (T, 72): the weights of the pose-corrective targets,
    the model's own (``HackModel.pose_features``: each joint's ``R - I``, times its gate
    in a gated model, ``gate_rad``, with its chain weight ``chain``)."""
    zeros = theta.new_zeros(theta.shape[0], 3)
    return pose_feature(local_rotations(theta, zeros)[:, 1:], gate_rad, chain)


def build_rig(model, beta: torch.Tensor | None, eta: float, tau_range: float = TAU_RANGE,
              tau_step: float = TAU_STEP, influences: int = INFLUENCES) -> ExportRig:
    """Personalise ``model`` for one identity (beta (1, S)) and larynx size ``eta``, with
    ``influences`` (4 or 8) skin weights per vertex.

    Every target comes from the model's public forward pass (its ``rest_vertices``), which
    is linear in psi, in the pose feature and in eta: an expression target is the rest mesh
    at psi = e_i minus the neutral one; a joint's 9 pose-corrective targets solve the 9 x 9
    system of 9 rotations of that joint alone. So the rig follows the model, whatever its
    internal layout (personalised bases, sparse rows), without reading its buffers."""
    if influences not in (4, 8):
        raise HackError(f"--influences: expected 4 or 8 skin weights per vertex, found "
                        f"{influences}.")
    dtype = model.template.dtype
    beta = torch.zeros(1, 0, dtype=dtype) if beta is None else torch.as_tensor(beta, dtype=dtype)
    e, k = model.num_expressions, model.num_joints

    def rest(n: int, **kw) -> tuple[np.ndarray, np.ndarray]:
        with torch.no_grad():
            out = model(beta=beta.expand(n, -1), **{"eta": torch.zeros(n, dtype=dtype), **kw})
        return out.rest_vertices.double().numpy(), out.rest_joints[0].double().numpy()

    neutral, rest_joints = rest(1)
    neutral = neutral[0]
    psi = torch.eye(e, dtype=dtype)
    blocks = [(rest(e, psi=psi)[0] - neutral).astype(np.float32)]
    names = list(model.expression_names)
    base = neutral
    grid = np.zeros(0)
    if model.has_larynx:
        grid = _tau_grid(tau_range, tau_step)
        taus = np.r_[0.0, 0.0, grid]
        etas = np.r_[1.0, eta, np.full(len(grid), eta)]
        lar = rest(len(taus), eta=torch.as_tensor(etas, dtype=dtype),
                   tau=torch.as_tensor(taus, dtype=dtype))[0] - neutral
        base = neutral + lar[1]  # eta baked in, at tau = 0
        blocks.append(np.concatenate([lar[:1], lar[2:] - lar[1]]).astype(np.float32))
        names += ["larynx_size"] + [f"larynx_slide_{1000 * t:+.0f}mm" for t in grid]
    flex = _flex_targets(model, beta, neutral.shape[0]) if model.flex is not None else None
    pose = _pose_targets(rest, neutral, k, dtype, model.pose_gate_rad, model.pose_gate_chain,
                         None if flex is None else flex[1])
    if pose is not None:
        split = pose_split(k)
        blocks.append(np.stack([sign * pose[f] for f, sign, _ in split]))
        names += [f"pose_{model.joint_names[f // 9]}_{tag}" for f, _, tag in split]
    if flex is not None:
        blocks.append(flex[0].astype(np.float32))
        names += [f"flex_{kd:+.0f}deg" for kd in flex[2]["knots_deg"]]
    joints4, weights4 = top_weights(model.skinning_weights.double().numpy(), influences)
    rig = ExportRig(base=base, target_names=names, targets=np.concatenate(blocks, 0),
                    node_names=[ROOT_NAME, *model.joint_names],
                    parents=[-1] + [p + 1 if p >= 0 else 0 for p in model.parents],
                    rest_nodes=np.concatenate([rest_joints[:1], rest_joints], 0),
                    joints4=joints4, weights4=weights4, weight_error_m=0.0, tau_grid=grid,
                    num_expressions=e, eta=float(eta), pose_gate_rad=model.pose_gate_rad,
                    pose_gate_chain=model.pose_gate_chain,
                    flex=None if flex is None else flex[2])
    rig.weight_error_m = weight_truncation_error(model, rig)
    return rig


#: Axes (unnormalised) of the 9 rotations per joint whose (R - I) span all 3 x 3 matrices.
_PROBE_AXES = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1), (1, -1, 0),
               (0, 1, -1), (-1, 0, 1))
_PROBE_ANGLE = 1.0  # radians: far from zero, so the 9 x 9 systems are well conditioned


def _flex_targets(model, beta: torch.Tensor, n: int) -> tuple:
    """The flexion block's targets (H, N, 3) for identity beta (1, s), a function of poses
    theta (T, K, 3) giving its offsets (T, N, 3), and the rig's ``flex`` entry."""
    fb = model.flex
    with torch.no_grad():
        rows = fb.identity_rows(beta)[0].double().view(fb.num_hats, -1, 3)  # (H, M, 3)
    dense = torch.zeros(fb.num_hats, n, 3, dtype=torch.float64)
    dense[:, fb.vertices] = rows
    entry = {"knots_deg": list(fb.knots_deg), "width_deg": float(np.degrees(fb.width)),
             "purity_deg": float(np.degrees(fb.purity)), "coherence": fb.coherence}

    def offsets(theta: np.ndarray) -> np.ndarray:
        w = flex_weights_np(theta, entry["knots_deg"], entry["width_deg"], entry["purity_deg"],
                            entry["coherence"])
        return np.einsum("th,hnc->tnc", w, dense.numpy())

    return dense.numpy(), offsets, entry


def _pose_targets(rest, neutral: np.ndarray, k: int, dtype,
                  gate_rad: float | None = None, chain: float = 0.0,
                  flex=None) -> np.ndarray | None:
    """(9K, N, 3) pose-corrective targets (feature order: joint, row, column of R - I), or
    None when the model has none (the rest mesh does not depend on the pose). With a gate,
    the probes' features are gated as the model's (one factor per joint: every probe turns
    its joint by the same angle, and the chain's net rotation is that joint's own).
    ``flex``: the flexion block's offsets of poses (:func:`_flex_targets`), taken out of
    the probes (a probe's rotation is also a net rotation; the block has targets of its
    own)."""
    axes = np.asarray(_PROBE_AXES, np.float64)
    aa = _PROBE_ANGLE * axes / np.linalg.norm(axes, axis=1, keepdims=True)  # (9, 3)
    theta = np.zeros((9 * k, k, 3))
    for j in range(k):
        theta[9 * j:9 * j + 9, j] = aa
    y = rest(9 * k, theta=torch.as_tensor(theta, dtype=dtype))[0] - neutral  # (9K, N, 3)
    if flex is not None:
        y = y - flex(theta)
    if not np.any(np.abs(y) > (1e-6 if flex is not None else 0.0)):  # float32 rounding
        return None
    feat = pose_features(torch.as_tensor(theta), gate_rad, chain).numpy()  # (9K, 9K), block diagonal
    out = np.zeros_like(y)
    n = y.shape[1] * 3
    for j in range(k):
        rows = slice(9 * j, 9 * j + 9)
        out[rows] = np.linalg.solve(feat[rows, rows], y[rows].reshape(9, n)).reshape(9, -1, 3)
    return out.astype(np.float32)


def _tau_grid(tau_range: float, step: float) -> np.ndarray:
    if not (0 < step <= tau_range <= 0.1):
        raise HackError(f"larynx slide range: expected 0 < step <= range <= 0.1 m, found step "
                        f"{step}, range {tau_range}.")
    k = round(tau_range / step)
    return np.array([i * step for i in range(-k, k + 1) if i != 0])


def weight_truncation_error(model, rig: ExportRig, theta: torch.Tensor | None = None) -> float:
    """Largest vertex displacement (m) between skinning with the model's weights and with
    the 4 kept, over poses ``theta`` (T, 8, 3) (default: each joint at its limits, one
    axis at a time, and the whole-head extremes of the turntable's look-around)."""
    if theta is None:
        theta = limit_poses(model)
    rot = local_rotations(theta.double(), theta.new_zeros(len(theta), 3).double())
    nodes = torch.as_tensor(rig.rest_nodes)[None].expand(len(theta), -1, -1)
    _, rel = rigid_transforms(rot, nodes, chain_parents(model.parents))
    rest = torch.as_tensor(rig.base)[None].expand(len(theta), -1, -1)
    full = skin(rest, model.skinning_weights.double(), rel)
    w4 = np.zeros(model.skinning_weights.shape)
    rows = np.arange(len(w4))[:, None].repeat(rig.joints4.shape[1], 1)
    np.add.at(w4, (rows, rig.joints4), rig.weights4.astype(np.float64))  # unused slots add 0
    cut = skin(rest, torch.as_tensor(w4), rel)
    return float((full - cut).norm(dim=-1).max())


def limit_poses(model) -> torch.Tensor:
    """Poses (T, 8, 3) at the anatomical limits: every joint at both ends of each axis
    together (flexion, extension, axial either way, lateral either way)."""
    lim = torch.deg2rad(model.rotation_limits_deg.double())  # (8, 3, 2)
    poses = []
    for axis in range(3):
        for end in range(2):
            e = torch.zeros(8, 3, dtype=torch.float64)
            e[:, axis] = lim[:, axis, end]
            poses.append(euler_to_axis_angle(e))
    return torch.stack(poses)


def frame_weights(rig: ExportRig, psi: np.ndarray | None, theta: np.ndarray,
                  tau: np.ndarray | None) -> np.ndarray:
    """Morph weights (T, K) for frames: psi (T, E) or None, theta (T, 8, 3), tau (T,) or None."""
    t = len(theta)
    out = np.zeros((t, len(rig.target_names)))
    s = rig.slots
    if psi is not None:
        out[:, s["expression"]] = psi
    if len(rig.tau_grid):
        out[:, s["larynx_slide"]] = tau_weights(np.zeros(t) if tau is None else tau, rig.tau_grid)
    if s["pose"].stop > s["pose"].start:
        feat = pose_features(torch.tensor(np.asarray(theta), dtype=torch.float64),
                             rig.pose_gate_rad, rig.pose_gate_chain).numpy()
        split = pose_split(feat.shape[1] // 9)
        idx = np.array([f for f, _, _ in split])
        sign = np.array([sg for _, sg, _ in split])
        out[:, s["pose"]] = np.maximum(feat[:, idx] * sign, 0.0)
    if rig.flex:
        f = rig.flex
        out[:, s["flex"]] = flex_weights_np(theta, f["knots_deg"], f["width_deg"], f["purity_deg"],
                                            f["coherence"])
    return out


def axis_angle_quaternions(r: np.ndarray) -> np.ndarray:
    """Axis-angle (..., 3) -> unit quaternions (..., 4) in glTF order (x, y, z, w), exact
    near zero; consecutive rows along axis 0 keep one hemisphere (for interpolation)."""
    r = np.asarray(r, np.float64)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    # sin(a/2)/a with its series for small a (no division by zero)
    safe = np.where(angle > 0, angle, 1.0)
    s = np.where(angle < 1e-4, 0.5 - angle ** 2 / 48, np.sin(angle / 2) / safe)
    q = np.concatenate([r * s, np.cos(angle / 2)], -1)
    for i in range(1, len(q)) if q.ndim > 1 else ():
        flip = (q[i] * q[i - 1]).sum(-1, keepdims=True) < 0
        q[i] = np.where(flip, -q[i], q[i])
    return q
