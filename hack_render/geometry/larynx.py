"""The larynx term L(beta, eta, tau) of HACK (paper Sec. 3.3, Eq. 4), sampled from UV maps.

The larynx basis is a stack of displacement images ``L_i`` of shape (3, H, W), stored in
metres in model space, covering a rectangle ``uv_bounds = (u0, v0, u1, v1)`` of the
template's UV atlas (image row 0 at ``v1``, the top). For vertex ``j`` with texture
coordinate ``(u_j, v_j)`` the displacement is

    d_j = eta * sum_i c_i(beta) * L_i(u_j, v_j + tau * v_per_metre)

with ``c(beta) = A beta + c0``, a documented generalisation of Eq. 4 (``A = I``, ``c0 = 0``
is the paper's form; ``c0`` lets a mean larynx exist at ``beta = 0``). ``tau`` is in metres
of vertical slide along the neck's UV ``v`` direction, so the larynx only moves vertically.
Sampling is bilinear and differentiable in beta, eta and tau.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def larynx_coefficients(beta: torch.Tensor, coef_matrix: torch.Tensor,
                        coef_offset: torch.Tensor) -> torch.Tensor:
    """c(beta) = A beta + c0. beta: (B, S), A: (L, S'), c0: (L,) -> (B, L); extra betas ignored."""
    s = min(beta.shape[1], coef_matrix.shape[1])
    return beta[:, :s] @ coef_matrix[:, :s].T + coef_offset


def combine_maps(coeffs: torch.Tensor, maps: torch.Tensor) -> torch.Tensor:
    """sum_i c_i L_i. coeffs: (B, L), maps: (L, 3, H, W) -> (B, 3, H, W)."""
    return torch.einsum("bl,lchw->bchw", coeffs, maps)


def sample_displacement(combined: torch.Tensor, vertex_uv: torch.Tensor, uv_bounds: torch.Tensor,
                        eta: torch.Tensor, tau: torch.Tensor, v_per_metre: float) -> torch.Tensor:
    """Sample combined larynx maps at shifted UVs.

    Args:
        combined: (B, 3, H, W) from :func:`combine_maps` (metres).
        vertex_uv: (M, 2) UVs of the larynx-region vertices.
        uv_bounds: (4,) rectangle (u0, v0, u1, v1) covered by the maps.
        eta: (B,) size; tau: (B,) vertical slide in metres.
        v_per_metre: UV ``v`` units per metre of slide.

    Returns:
        (B, M, 3) displacements in metres; zero outside the maps (padding_mode="zeros").
    """
    u0, v0, u1, v1 = uv_bounds.unbind()
    v = vertex_uv[None, :, 1] + tau[:, None] * v_per_metre  # (B, M)
    u = vertex_uv[None, :, 0].expand_as(v)
    gx = 2 * (u - u0) / (u1 - u0) - 1
    gy = 1 - 2 * (v - v0) / (v1 - v0)  # row 0 is the top (v1)
    grid = torch.stack([gx, gy], -1).unsqueeze(1)  # (B, 1, M, 2)
    out = F.grid_sample(combined, grid.to(combined.dtype), mode="bilinear",
                        padding_mode="zeros", align_corners=False)  # (B, 3, 1, M)
    return eta[:, None, None] * out[:, :, 0].transpose(1, 2)
