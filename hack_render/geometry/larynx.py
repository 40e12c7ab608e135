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

Ranges (enforced like the joints' rotation limits: :func:`larynx_limit_penalty` for fitting,
:func:`clamp_larynx` / :func:`larynx_outside_limits` on input, ``--limits`` on the CLI):

* ``tau`` in [-0.01, +0.02] m (``TAU_RANGE_M``). Up: the larynx rises about 2-3 cm (up and
  forward) in a swallow (Logemann, *Evaluation and Treatment of Swallowing Disorders*, 2nd
  ed. 1998, videofluoroscopic laryngeal elevation) and by a few millimetres in speech
  (shared docs ANATOMY.md). The upper bound is the swallow's lower end, 2 cm, because that
  is what the shipped maps hold: the larynx region's vertices end ~2.2 cm above the
  prominence at rest, and beyond +2 cm the bump leaves the region (at beta = 0 its summed
  displacement falls 7 % by +2.5 cm, its peak 5 % by +3 cm). Down: the larynx "does not move
  down much" (ANATOMY.md); it lowers by a few millimetres in speech and by up to about 1 cm
  for low pitch (Honda, Hirai, Masaki & Shimada, "Role of vertical larynx movement and
  cervical lordosis in F0 control", Language and Speech 42, 1999: MRI of larynx height
  against F0), so -1 cm; at -4 cm the prominence would sit on the suprasternal notch.
* ``eta`` in [0, 1.5] (``ETA_RANGE``), a size factor on the identity's own larynx. The
  laryngeal prominence protrudes about 5-10 mm in adult males and 1-3 mm in females
  (ANATOMY.md). The shipped maps give, at eta = 1, a peak displacement of 6.6 mm at the
  median identity (3.0 mm at the 5th percentile, 11.4 mm at the 95th; 500 identities
  beta ~ N(0, I)): eta = 0 flattens it (no prominence, the lower end of the female range
  with rounding), eta = 1.5 takes the median identity to ~10 mm, the top of the male range.
  Negative eta would turn the prominence into a dent, which no neck has; larger eta
  extrapolates the learned maps linearly beyond any simulated identity.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from hack_render.geometry.anatomy import (  # noqa: F401  (the ranges and check, re-exported)
    ETA_DEFAULT,
    ETA_RANGE,
    TAU_RANGE_M,
    larynx_outside_limits,
)


def larynx_limit_penalty(eta: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """E_larynx: L1 excess of eta and tau over their ranges, each divided by its range's
    width (dimensionless, so a fraction of a range costs the same for both).

    eta, tau: (B,) -> (B,); zero inside the ranges, positive and differentiable outside."""
    out = eta.new_zeros(torch.broadcast_shapes(eta.shape, tau.shape))
    for x, (lo, hi) in ((eta, ETA_RANGE), (tau, TAU_RANGE_M)):
        out = out + (torch.relu(x - hi) + torch.relu(lo - x)) / (hi - lo)
    return out


def clamp_larynx(eta: torch.Tensor, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """eta and tau clamped to ``ETA_RANGE`` and ``TAU_RANGE_M`` (any shapes)."""
    return eta.clamp(*ETA_RANGE), tau.clamp(*TAU_RANGE_M)


def larynx_coefficients(beta: torch.Tensor, coef_matrix: torch.Tensor,
                        coef_offset: torch.Tensor) -> torch.Tensor:
    """c(beta) = A beta + c0. beta: (B, S), A: (L, S'), c0: (L,) -> (B, L); extra betas ignored."""
    s = min(beta.shape[1], coef_matrix.shape[1])
    return beta[:, :s] @ coef_matrix[:, :s].T + coef_offset


def combine_maps(coeffs: torch.Tensor, maps: torch.Tensor) -> torch.Tensor:
    """sum_i c_i L_i. coeffs: (B, L), maps: (L, 3, H, W) -> (B, 3, H, W)."""
    return (coeffs @ maps.reshape(maps.shape[0], -1)).view(coeffs.shape[0], *maps.shape[1:])


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
