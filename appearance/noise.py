"""Seeded procedural noise: 3-D value-noise fBm on surface points and 2-D Worley cells.

Noise evaluated on template surface points (centimetres) rather than UV coordinates is
continuous across UV seams, so the two atlas tiles agree where they meet.
"""

from __future__ import annotations

import numpy as np

LATTICE = 64  # periodic lattice size per octave


def _smooth(t):
    return t * t * (3.0 - 2.0 * t)


def value_noise3(points: np.ndarray, lattice: np.ndarray) -> np.ndarray:
    """Trilinear value noise in [-1, 1] at (N, 3) points (lattice units), periodic lattice."""
    g = lattice.shape[0]
    p0 = np.floor(points).astype(np.int64)
    f = _smooth(points - p0)
    i0 = np.mod(p0, g)
    i1 = np.mod(p0 + 1, g)
    out = 0.0
    for dx in (0, 1):
        ix = i1[:, 0] if dx else i0[:, 0]
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            iy = i1[:, 1] if dy else i0[:, 1]
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                iz = i1[:, 2] if dz else i0[:, 2]
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out = out + wx * wy * wz * lattice[ix, iy, iz]
    return out


def fbm3(points_cm: np.ndarray, rng: np.random.Generator, scale_cm: float,
         octaves: int = 4, gain: float = 0.5) -> np.ndarray:
    """Fractal value noise (N,) with unit-ish std at (N, 3) points in cm.

    Args:
        scale_cm: feature size of the first octave; each octave halves it.
        rng: draws the lattices (so the field is deterministic per seed).
    """
    out = np.zeros(len(points_cm))
    amp, total = 1.0, 0.0
    offset = rng.random(3) * LATTICE
    for o in range(octaves):
        lat = rng.uniform(-1.0, 1.0, (LATTICE,) * 3).astype(np.float32)
        out += amp * value_noise3(points_cm / (scale_cm / 2 ** o) + offset, lat)
        total += amp * amp
        amp *= gain
    return out / np.sqrt(total) * np.sqrt(3.0)  # value noise std ~ 1/sqrt(3) per octave


def worley2(h: int, w: int, cell: float, rng: np.random.Generator):
    """2-D Worley (cellular) noise on an (h, w) grid: distance to the nearest feature point.

    Args:
        cell: cell size in texels (one jittered feature point per cell).
    Returns:
        (h, w) float32 distance in texels, and (h, w) float32 random value per cell.
    """
    ny, nx = int(np.ceil(h / cell)) + 2, int(np.ceil(w / cell)) + 2
    jit = rng.random((ny, nx, 2)).astype(np.float32)
    val = rng.random((ny, nx)).astype(np.float32)
    ys = (np.arange(h, dtype=np.float32) + 0.5) / cell
    xs = (np.arange(w, dtype=np.float32) + 0.5) / cell
    cy, cx = np.floor(ys).astype(np.int64), np.floor(xs).astype(np.int64)
    best = np.full((h, w), np.inf, np.float32)
    bval = np.zeros((h, w), np.float32)
    for oy in (-1, 0, 1):
        gy = np.clip(cy + oy, 0, ny - 1)
        for ox in (-1, 0, 1):
            gx = np.clip(cx + ox, 0, nx - 1)
            fy = gy[:, None] + jit[gy[:, None], gx[None, :], 0]
            fx = gx[None, :] + jit[gy[:, None], gx[None, :], 1]
            d = (ys[:, None] - fy) ** 2 + (xs[None, :] - fx) ** 2
            closer = d < best
            best = np.where(closer, d, best)
            bval = np.where(closer, val[gy[:, None], gx[None, :]], bval)
    return np.sqrt(best) * cell, bval
