"""High-resolution procedural pore layer, composed with the PCA normal map at render size.

Pores (about 0.1 mm wide, 0.2-0.5 mm apart) need about 2K texels across the face, far
beyond a PCA that ships as package data, so they are generated on demand (procedural,
seeded): a 2-D Worley cell field per atlas tile (one pit per cell, cell size set in mm
through the tile's texel size), pit depth and spacing varying by region (large pores on
the nose and cheeks, fine on the forehead, none on the lips, eyelids fine), plus fine
isotropic micro-relief. The height field becomes slopes, and
:func:`compose_detail` adds them to the bilinearly upsampled PCA normal map (adding
slopes = "partial-derivative blending", exact for heights that add), renormalising.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F

from appearance.generator import atlas_context
from appearance.model import slopes_to_normals
from appearance.noise import worley2
from appearance.regions import REGION_ID, region_labels
from hack_render.errors import HackError

# (pore spacing mm, pore depth mm) per region; 0 depth: no pores.
PORES = {"nose": (0.35, 0.05), "cheeks": (0.30, 0.035), "forehead": (0.25, 0.03),
         "chin": (0.30, 0.035), "upper_lip": (0.25, 0.02), "jaw": (0.28, 0.025),
         "eyelids": (0.2, 0.008), "lips": (0.2, 0.0), "brows": (0.25, 0.02),
         "ears": (0.25, 0.015), "neck": (0.3, 0.02), "scalp": (0.3, 0.015),
         "sockets": (0.2, 0.0)}


def _texel_mm(height: int) -> np.ndarray:
    """Surface size of one texel per tile (mm) at atlas height H (template scale)."""
    return atlas_context(256).texel_cm * 10.0 * 256.0 / height


@lru_cache(maxsize=4)
def detail_slopes(height: int, seed: int = 0) -> np.ndarray:
    """(H, 2H, 2) float32 pore-layer slopes (dh/du, dh/dv in surface units) at atlas H.

    Deterministic in (height, seed). H between 64 and 8192.
    """
    if not 64 <= int(height) <= 8192:
        raise HackError(f"detail height: expected 64..8192, found {height}.")
    h = int(height)
    rng = np.random.default_rng([int(seed), 77])
    lab = _labels_at(h, region_labels)
    tmm = _texel_mm(h)
    spacing = np.full(lab.shape, 0.28, np.float32)
    depth = np.zeros(lab.shape, np.float32)
    for name, (sp, dp) in PORES.items():
        sel = lab == REGION_ID[name]
        spacing[sel], depth[sel] = sp, dp
    out = np.zeros((h, 2 * h, 2), np.float32)
    for t, sl in enumerate((np.s_[:, :h], np.s_[:, h:])):
        hgt = np.zeros((h, h), np.float32)
        for sp in sorted(set(v[0] for v in PORES.values())):
            cell = sp / tmm[t]
            if cell < 1.0:  # pores below a texel apart would alias: leave them out
                continue
            dist, val = worley2(h, h, cell, rng)
            radius = 0.05 / tmm[t] * (0.7 + 0.6 * val)  # pore radius ~0.05 mm
            pit = np.exp(-(dist / np.maximum(radius, 0.5)) ** 2)
            use = np.isclose(spacing[sl], sp)
            hgt -= np.where(use, pit * depth[sl] * (0.6 + 0.8 * val), 0)
        hgt += 0.004 * rng.standard_normal((h, h)).astype(np.float32)  # micro-relief, mm
        gy, gx = np.gradient(hgt, tmm[t])
        out[sl] = np.stack([gx, -gy], -1)  # +v is up (row 0 is v = 1)
    return out


def _labels_at(h: int, region_labels) -> np.ndarray:
    """Region labels at atlas height h (computed at <= 1024 and upsampled by nearest)."""
    base = min(h, 1024)
    lab = region_labels(base)
    if base == h:
        return lab
    r = h // base if h % base == 0 else None
    if r:
        return np.repeat(np.repeat(lab, r, 0), r, 1)
    ii = (np.arange(h) * base) // h
    jj = (np.arange(2 * h) * base) // h
    return lab[ii][:, jj]


def upsample_normals(normal: torch.Tensor, height: int) -> torch.Tensor:
    """(B, H, 2H, 3) unit normals to (B, R, 2R, 3): bilinear in slopes, renormalised."""
    slopes = normal[..., :2] / normal[..., 2:3].clamp_min(1e-3)
    s = F.interpolate(slopes.permute(0, 3, 1, 2), size=(height, 2 * height), mode="bilinear",
                      align_corners=False).permute(0, 2, 3, 1)
    return slopes_to_normals(s)


def compose_detail(normal: torch.Tensor, height: int, seed: int = 0,
                   strength: float = 1.0) -> torch.Tensor:
    """Compose the pore layer with PCA normals at render resolution.

    Args:
        normal: (B, H, 2H, 3) unit tangent-space normals (``AppearanceModel.maps().normal``).
        height: output atlas height R (e.g. 2048 for 1024 px close-ups of the face).
        seed: detail layer seed. strength: scale of the pore slopes (0 = none).
    Returns:
        (B, R, 2R, 3) unit normals, n_z > 0, differentiable w.r.t. ``normal``.
    """
    if normal.ndim != 4 or normal.shape[-1] != 3 or normal.shape[2] != 2 * normal.shape[1]:
        raise HackError(f"normal: expected shape (B, H, 2H, 3), found {tuple(normal.shape)}.")
    base = upsample_normals(normal, int(height))
    if strength == 0:
        return base
    d = torch.from_numpy(detail_slopes(int(height), int(seed))).to(base)
    slopes = base[..., :2] / base[..., 2:3] + strength * d
    return slopes_to_normals(slopes)
