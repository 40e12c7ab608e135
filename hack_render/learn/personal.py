"""Personalised blendshape spaces: PCA of per-identity deltas and the mapping MLP (Eq. 7).

Used for both M_E (expressions, Sec. 5.1) and M_P (pose, Sec. 5.2): the per-identity sets
{X_beta} (n, D, M, 3) are flattened, PCA'd, and an MLP of three linear layers (64 units,
ReLU) predicts the first C PCA weights from beta. Training uses Adam at 1e-4 on the squared
error of the weights, which equals Eq. 7's blendshape error because the PCA basis is
orthonormal (up to one global scale that keeps the targets near unit size).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from hack_render.learn.pca import PCA, fit_pca


@dataclass
class PersonalSpace:
    """A learned personalised space and its training record."""

    pca: PCA
    mlp: dict[str, np.ndarray]  # w0, b0, w1, b1, w2, b2 (weights in PCA-weight units)
    train_loss: float
    val_loss: float | None
    epochs: int


def train_mapping(betas: np.ndarray, weights: np.ndarray, val_betas: np.ndarray | None = None,
                  val_weights: np.ndarray | None = None, hidden: int = 64, lr: float = 1e-4,
                  epochs: int = 3000, batch: int = 32, seed: int = 0,
                  progress: bool = True, desc: str = "mapping MLP") -> tuple[dict, float, float | None]:
    """Fit beta (n, S) -> PCA weights (n, C) with a 3-layer ReLU MLP (Adam, ``lr``).

    Returns:
        (arrays w0..b2 as float32 numpy, final train MSE, final validation MSE or None), the
        MSEs in PCA-weight units squared (metres^2 for orthonormal components).
    """
    torch.manual_seed(seed)
    scale = float(np.abs(weights).std()) or 1.0
    xb = torch.as_tensor(betas, dtype=torch.float32)
    yb = torch.as_tensor(weights / scale, dtype=torch.float32)
    net = torch.nn.Sequential(torch.nn.Linear(xb.shape[1], hidden), torch.nn.ReLU(),
                              torch.nn.Linear(hidden, hidden), torch.nn.ReLU(),
                              torch.nn.Linear(hidden, yb.shape[1]))
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    n = len(xb)
    for _ in tqdm(range(epochs), desc=desc, disable=not progress, mininterval=2.0):
        perm = torch.randperm(n, generator=gen)
        for i in range(0, n, batch):
            idx = perm[i:i + batch]
            loss = ((net(xb[idx]) - yb[idx]) ** 2).sum(1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        train = float(((net(xb) - yb) ** 2).sum(1).mean()) * scale**2
        val = None
        if val_betas is not None and len(val_betas):
            xv = torch.as_tensor(val_betas, dtype=torch.float32)
            yv = torch.as_tensor(val_weights / scale, dtype=torch.float32)
            val = float(((net(xv) - yv) ** 2).sum(1).mean()) * scale**2
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    out = {}
    for i, m in enumerate(lin):
        w, b = m.weight.detach().numpy().copy(), m.bias.detach().numpy().copy()
        if i == 2:
            w, b = w * scale, b * scale
        out[f"w{i}"], out[f"b{i}"] = w.astype(np.float32), b.astype(np.float32)
    return out, train, val


def mlp_forward(mlp: dict[str, np.ndarray], betas: np.ndarray) -> np.ndarray:
    """Numpy forward of the mapping MLP, (n, S) -> (n, C); betas beyond w0's width ignored."""
    x = np.asarray(betas, dtype=np.float64)[:, : mlp["w0"].shape[1]]
    x = np.maximum(x @ mlp["w0"].T + mlp["b0"], 0)
    x = np.maximum(x @ mlp["w1"].T + mlp["b1"], 0)
    return x @ mlp["w2"].T + mlp["b2"]


def learn_personal_space(betas: np.ndarray, deltas: np.ndarray, num_components: int = 50,
                         val_fraction: float = 0.1, epochs: int = 3000, seed: int = 0,
                         progress: bool = True, desc: str = "mapping MLP") -> PersonalSpace:
    """PCA of per-identity deltas (n, ...) and the MLP from beta to the first C weights.

    The last ``val_fraction`` of the identities are held out of both the PCA and the MLP
    (the paper's 90/10 split); with ``val_fraction = 0`` all are used.
    """
    n = len(betas)
    flat = deltas.reshape(n, -1)
    ntest = int(round(n * val_fraction))
    tr = slice(0, n - ntest)
    pca = fit_pca(flat[tr], num_components)
    w_tr = pca.project(flat[tr])
    w_te = pca.project(flat[n - ntest:]) if ntest else None
    mlp, train, val = train_mapping(betas[tr], w_tr, betas[n - ntest:] if ntest else None, w_te,
                                    epochs=epochs, seed=seed, progress=progress, desc=desc)
    return PersonalSpace(pca=pca, mlp=mlp, train_loss=train, val_loss=val, epochs=epochs)


def personal_arrays(prefix: str, space: PersonalSpace, vertices: np.ndarray,
                    shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Model-file arrays of a personalised group ``prefix`` in {expr, pose}.

    shape: (D, M) deltas per identity and vertices per delta.
    """
    d, m = shape
    c = len(space.pca.components)
    out = {f"{prefix}_pca_vertices": np.asarray(vertices, np.int32),
           f"{prefix}_pca_mean": space.pca.mean.reshape(d, m, 3).astype(np.float32),
           f"{prefix}_pca_components": space.pca.components.reshape(c, d, m, 3).astype(np.float32)}
    for k, val in space.mlp.items():
        out[f"{prefix}_mlp_{k}"] = val.astype(np.float32)
    return out
