"""Head orientation -> the 8 cervical joints (paper Sec. 6.1): a small MLP, 2 hidden layers
of 512 units, from the skull's orientation relative to the thorax to theta.

A face tracker (DECA, ARKit) sees the head's orientation, not the neck's joints.
``geometry.distribute_head_rotation`` shares a head rotation over the joints by a fixed rule
(in proportion to each joint's anatomical range); this mapping learns the sharing from
parameter sequences whose neck joints were measured (e.g. tracked per frame), and is worth
using only where it beats that rule on sequences it did not see (:func:`compare`).

Head orientation: the o-c1 node's rotation relative to the thorax, i.e. the product of the
8 joints' rotations (rest frames are aligned with the model's axes, so local rotations
compose directly): ``R_head = R_c7-t1 ... R_o-c1``. The network reads its first two columns
(the continuous 6D representation, Zhou et al. 2019) and returns axis-angle theta (8, 3).

No default mapping ships with hack-render: no sequences with measured neck joints are
available here (see docs/motion.md).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.geometry.params import load_sequence
from hack_render.geometry.rotations import axis_angle_to_matrix, matrix_to_euler
from hack_render.geometry.skeleton import JOINT_NAMES, distribute_head_rotation
from hack_render.io.npz import write_npz

FORMAT = "hack-head-to-neck"
HIDDEN = 512


def head_orientation(theta: torch.Tensor) -> torch.Tensor:
    """The skull's rotation relative to the thorax. theta (..., 8, 3) -> (..., 3, 3)."""
    r = axis_angle_to_matrix(theta)
    out = r[..., 0, :, :]
    for j in range(1, r.shape[-3]):
        out = out @ r[..., j, :, :]
    return out


def _features(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two columns (the 6D representation)."""
    return rot[..., :, :2].transpose(-1, -2).reshape(*rot.shape[:-2], 6)


def as_rotation(head) -> torch.Tensor:
    """Head orientations as matrices: (T, 3, 3), or (T, 3) axis-angle, -> (T, 3, 3)."""
    h = torch.as_tensor(head, dtype=torch.float64)
    if h.ndim == 2 and h.shape[1] == 3:
        return axis_angle_to_matrix(h)
    if h.ndim == 3 and h.shape[1:] == (3, 3):
        return h
    raise HackError(f"head orientation: expected (T, 3) axis-angle or (T, 3, 3) matrices, "
                    f"found shape {tuple(h.shape)}.")


class HeadToNeckMLP(nn.Module):
    """6 -> 512 -> 512 -> 24 with ReLUs (the paper's 2 layers of 512 units)."""

    def __init__(self, hidden: int = HIDDEN):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(6, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                 nn.ReLU(), nn.Linear(hidden, 24))

    def forward(self, rot: torch.Tensor) -> torch.Tensor:
        """rot (B, 3, 3) -> theta (B, 8, 3) radians."""
        return self.net(_features(rot)).view(-1, 8, 3)


@dataclass
class HeadToNeck:
    """A trained mapping and what it was trained on (``meta``)."""

    mlp: HeadToNeckMLP
    meta: dict

    def predict(self, head) -> np.ndarray:
        """theta (T, 8, 3) for head orientations (T, 3) axis-angle or (T, 3, 3)."""
        rot = as_rotation(head).to(torch.float32)
        with torch.no_grad():
            return self.mlp(rot).double().numpy()

    def save(self, path: str | Path) -> Path:
        """An ``.npz`` of named float32 weights and a JSON ``meta`` string (no pickle)."""
        path = Path(path)
        if path.suffix.lower() != ".npz":
            raise HackError(f"-o {path}: expected an .npz output, found "
                            f"{path.suffix or 'no suffix'}.")
        arrays = {k: v.detach().numpy() for k, v in self.mlp.state_dict().items()}
        return write_npz(path, {"meta": np.str_(json.dumps(self.meta)), **arrays})

    @classmethod
    def load(cls, path: str | Path) -> HeadToNeck:
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                state = {k: torch.from_numpy(z[k].copy()) for k in z.files if k != "meta"}
        except (OSError, KeyError, ValueError) as exc:
            raise HackError(f"{path}: not a head-to-neck file ({exc}); write one with "
                            "`hack-render learn head-to-neck`.") from exc
        if meta.get("format") != FORMAT:
            raise HackError(f"{path}: expected format {FORMAT!r}, found {meta.get('format')!r}.")
        mlp = HeadToNeckMLP(int(meta.get("hidden", HIDDEN)))
        try:
            mlp.load_state_dict(state)
        except RuntimeError as exc:
            raise HackError(f"{path}: weights do not match the network: {exc}") from exc
        return cls(mlp.float(), meta)


def joint_angle_errors(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Geodesic angle (degrees) between predicted and true joint rotations: (T, 8, 3) x 2
    -> (T, 8)."""
    a = axis_angle_to_matrix(torch.as_tensor(pred, dtype=torch.float64))
    b = axis_angle_to_matrix(torch.as_tensor(true, dtype=torch.float64))
    rel = a.transpose(-1, -2) @ b
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    return np.rad2deg(torch.arccos(cos).numpy())


def distribute_baseline(head) -> np.ndarray:
    """The fixed rule: ``distribute_head_rotation`` of the head's Euler angles (unclamped,
    so it reaches every orientation the data holds). (T, 3)|(T, 3, 3) -> (T, 8, 3)."""
    return distribute_head_rotation(matrix_to_euler(as_rotation(head)), clamp=False).numpy()


def compare(mapping: HeadToNeck, thetas: list[np.ndarray]) -> dict:
    """Per-joint angle error (degrees; mean over frames) of the mapping and of
    ``distribute_head_rotation`` on sequences ``thetas`` ((T, 8, 3) each)."""
    theta = np.concatenate(thetas)
    head = head_orientation(torch.as_tensor(theta))
    e_mlp = joint_angle_errors(mapping.predict(head), theta)
    e_rule = joint_angle_errors(distribute_baseline(head), theta)
    return {"frames": len(theta), "joints": list(JOINT_NAMES),
            "mlp_deg": e_mlp.mean(0).round(4).tolist(),
            "distribute_deg": e_rule.mean(0).round(4).tolist(),
            "mlp_mean_deg": round(float(e_mlp.mean()), 4),
            "distribute_mean_deg": round(float(e_rule.mean()), 4)}


def train(thetas: list[np.ndarray], steps: int = 3000, batch: int = 256, lr: float = 1e-3,
          seed: int = 0, progress: bool = True, sources: list[str] | None = None) -> HeadToNeck:
    """Fit the MLP to sequences' frames ((T, 8, 3) each): the head orientation of every
    frame in, its joints out (mean squared axis-angle error, Adam, cosine-decayed rate)."""
    theta = torch.as_tensor(np.concatenate(thetas), dtype=torch.float32)
    if len(theta) < 2:
        raise HackError(f"head-to-neck: expected at least 2 training frames, found {len(theta)}.")
    rot = head_orientation(theta.double()).float()
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    mlp = HeadToNeckMLP()
    opt = torch.optim.Adam(mlp.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    t0 = time.perf_counter()
    loss = torch.zeros(())
    bar = tqdm(range(steps), desc="head-to-neck", unit="step", disable=not progress)
    for step in bar:
        idx = torch.randint(len(theta), (min(batch, len(theta)),), generator=g)
        loss = ((mlp(rot[idx]) - theta[idx]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 100 == 0:
            bar.set_postfix(rmse_deg=f"{np.rad2deg(loss.item() ** 0.5):.3f}")
    meta = {"format": FORMAT, "version": 1, "hidden": HIDDEN, "steps": steps, "seed": seed,
            "training_frames": len(theta), "training_sequences": sources or [],
            "train_rmse_deg": float(np.rad2deg(loss.item() ** 0.5)),
            "seconds": round(time.perf_counter() - t0, 2),
            "input": "o-c1 rotation relative to the thorax (product of the 8 joint rotations)",
            "provenance": {"kind": "learned from the training sequences listed",
                           "note": "as good as those sequences' neck joints: synthetic or "
                                   "derived sequences give a synthetic or derived mapping"}}
    return HeadToNeck(mlp.eval(), meta)


def load_thetas(paths: list[Path]) -> list[np.ndarray]:
    """theta (T, 8, 3) of each parameter sequence file (errors name the file)."""
    out = []
    for p in paths:
        seq = load_sequence(p)
        if not np.any(seq.theta):
            raise HackError(f"{p}: every frame's theta is zero; a head-to-neck mapping needs "
                            "sequences with measured neck joints.")
        out.append(seq.theta)
    return out
