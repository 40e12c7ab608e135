"""Procedural texture sets from the calibrated two-layer skin model (labelled "procedural").

:func:`generate_subject` draws one subject, deterministically from its seed, and returns a
:class:`TextureSet` in the atlas layout of :mod:`appearance.uv`:

- diffuse albedo: per texel chromophores C_m(x), C_h(x), b_m mapped through the spectral
  model (:mod:`appearance.skin_optics`, via a look-up table) to linear sRGB. The subject's
  base chromophores (:mod:`appearance.population`) are modulated by regional factors
  (lips, eyelids, cheeks, nose and ears redder; neck paler; sockets mucosa), low-frequency
  mottling, freckles, moles and vessels; hair (brows, stubble, scalp) darkens the albedo;
- specular intensity (scale of the F0 = 0.028 lobe, in [0, 1]) and perceptual roughness
  by region (oily T-zone: high specular, low roughness; matte cheeks), after Weyrich et
  al. 2006, with per-subject oiliness;
- tangent-space normals from a height field: forehead lines, crow's feet, nasolabial
  folds, neck rings (depth growing with a per-subject age), bumpy mottling. Pores are not
  here: they live in the high-resolution detail layer (:mod:`appearance.detail`).

Noise is evaluated on template surface points, so fields are continuous across seams;
the soft region weights, blurred per tile in UV space, are blended across the seams
between the two tiles over :data:`SEAM_BLEND_CM` on each side, so the regional skin
(the scalp's hair tint, the neck's paler skin) meets at the same value from both sides.
Texels outside the skin islands are filled from the nearest valid texel (same tile).
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

from appearance.cache import cached_arrays, file_key, source_key
from appearance.noise import fbm3
from appearance.population import (
    Calibration,
    albedo_lut,
    draw_chromophores,
    load_calibration,
    subject_uniforms,
)
from appearance.regions import LANDMARK_VERTICES, REGION_ID, REGIONS, region_labels
from appearance.uv import TEMPLATE_FILE, UVLayout, default_template, rasterize_layout
from hack_render.geometry.obj_io import read_obj

# Regional multipliers of (C_m, C_h) and base (specular, roughness); specular scales the
# F0 = 0.028 lobe (1 = full skin Fresnel), roughness is perceptual (GGX alpha = r^2).
# Ordering after Weyrich et al. 2006: nose and forehead most specular and least rough,
# cheeks and neck matte; lips and sockets wet.
REGION_PARAMS = {
    #            C_m    C_h   spec  rough
    "forehead": (1.00, 1.00, 0.90, 0.55),
    "brows":    (1.05, 1.00, 0.70, 0.62),
    "eyelids":  (1.15, 1.70, 0.65, 0.58),
    "nose":     (1.00, 1.60, 1.00, 0.50),
    "cheeks":   (1.00, 1.50, 0.60, 0.65),
    "lips":     (0.75, 4.00, 0.85, 0.45),
    "upper_lip": (1.05, 1.30, 0.75, 0.60),
    "chin":     (1.00, 1.20, 0.80, 0.58),
    "jaw":      (1.00, 1.10, 0.65, 0.63),
    "ears":     (1.00, 1.70, 0.60, 0.62),
    "scalp":    (0.95, 1.00, 0.45, 0.70),
    "neck":     (0.88, 0.85, 0.55, 0.66),
    "sockets":  (0.40, 5.00, 1.00, 0.30),
}


#: Width (cm) over which the region weights are blended across the UV seams (each side).
SEAM_BLEND_CM = 1.0


@dataclass(frozen=True)
class TextureSet:
    """One subject's maps, numpy float32, atlas layout (H, 2H, C), row 0 is v = 1.

    diffuse (H, 2H, 3) linear sRGB; specular (H, 2H, 1) intensity in [0, 1];
    roughness (H, 2H, 1) perceptual; normal (H, 2H, 3) unit tangent space, OpenGL +Y.
    ``params`` holds the subject's scalar draws (base chromophores, age, ...).
    """

    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray
    params: dict


@dataclass(frozen=True)
class AtlasContext:
    """Per-resolution precomputation shared by all subjects."""

    layout: UVLayout
    labels: np.ndarray       # (H, 2H) uint8
    soft: np.ndarray         # (R, N) soft region weights at valid texels
    pos: np.ndarray          # (N, 3) cm
    texel_cm: np.ndarray     # (2,) texel size in cm per tile


@lru_cache(maxsize=4)
def atlas_context(height: int) -> AtlasContext:
    """The precomputation of atlas height ``height`` (cached): layout, region labels and
    soft weights, texel positions and sizes. Kept on disk too (``appearance.cache``: a
    function of the template file and the code that makes it; ~0.25 s a process, with
    scipy.spatial's import, at the projector's probe height)."""
    fields = [f.name for f in dataclasses.fields(UVLayout)]
    ctx_fields = [f.name for f in dataclasses.fields(AtlasContext) if f.name != "layout"]

    def make():
        ctx = _atlas_context(height)
        arrays = {f"layout_{k}": np.asarray(getattr(ctx.layout, k)) for k in fields}
        arrays.update({k: np.asarray(getattr(ctx, k)) for k in ctx_fields})
        return arrays, {}

    code = source_key(__file__, inspect.getfile(UVLayout), inspect.getfile(region_labels),
                      inspect.getfile(read_obj))
    a = cached_arrays("atlas_context", [int(height), file_key(TEMPLATE_FILE), code], make)[0]
    lay = UVLayout(**{k: int(a[f"layout_{k}"]) if k == "height" else a[f"layout_{k}"]
                      for k in fields})
    return AtlasContext(lay, **{k: a[k] for k in ctx_fields})


def _atlas_context(height: int) -> AtlasContext:
    lay = rasterize_layout(height)
    lab = region_labels(lay)
    m = lay.mask
    # texel size per tile: median surface distance between horizontal neighbours
    d = np.linalg.norm(np.diff(lay.position, axis=1), axis=-1)
    both = m[:, 1:] & m[:, :-1]
    tcm = np.array([np.median(d[:, : height - 1][both[:, : height - 1]]),
                    np.median(d[:, height:][both[:, height:]])])
    soft = []
    for r in range(1, len(REGIONS)):
        img = (lab == r).astype(np.float32)
        sig = 0.5 / tcm  # 5 mm transitions
        out = np.zeros_like(img)
        for t, sl in enumerate((np.s_[:, :height], np.s_[:, height:])):
            out[sl] = ndimage.gaussian_filter(img[sl], sig[t])
        soft.append(out[m])
    soft = np.stack(soft)
    soft /= np.maximum(soft.sum(0, keepdims=True), 1e-6)
    soft = _blend_across_seams(lay, soft, SEAM_BLEND_CM)
    return AtlasContext(lay, lab, soft.astype(np.float32), lay.position[m].astype(np.float64), tcm)


def _blend_across_seams(lay: UVLayout, soft: np.ndarray, width_cm: float) -> np.ndarray:
    """Soft region weights made continuous across the UV seams between the two tiles.

    The weights are blurred per tile in UV space, so where the tiles meet on the surface
    (over the crown, at the temples, under the jaw, inside the lips and lids) each side
    sees only its own labels and the skin steps at the seam. A texel within ``width_cm``
    (3-D) of the other tile, on a surface facing the same way (normals within 60 degrees,
    so the lips and lids do not mix with the sockets through the tissue), mixes in the
    weights of the nearest texel there: half at the seam, so both sides meet at the same
    value, fading linearly to none at ``width_cm``.

    Args:
        lay: the atlas layout.
        soft: (R, N) weights at the N valid texels (columns sum to 1).
        width_cm: blend width on each side of a seam, cm.
    Returns:
        (R, N) blended weights (columns still sum to 1).
    """
    from scipy.spatial import cKDTree

    pos = lay.position[lay.mask].astype(np.float64)
    nrm = lay.normal[lay.mask].astype(np.float64)
    tile = lay.tile[lay.mask]
    out = soft.copy()
    for t in (0, 1):
        mine, other = np.flatnonzero(tile == t), np.flatnonzero(tile != t)
        if not len(mine) or not len(other):
            continue
        d, j = cKDTree(pos[other]).query(pos[mine], distance_upper_bound=width_cm)
        near = np.isfinite(d)
        a, b = mine[near], other[j[near]]
        w = 0.5 * (1.0 - d[near] / width_cm) * (np.sum(nrm[a] * nrm[b], axis=1) > 0.5)
        out[:, a] = (1.0 - w) * soft[:, a] + w * soft[:, b]
    return out


def _regional(ctx: AtlasContext, values: dict[str, float]) -> np.ndarray:
    """(N,) smooth blend of per-region values."""
    v = np.array([values[n] for n in REGIONS[1:]], np.float64)
    return v @ ctx.soft


def _spots(ctx: AtlasContext, rng, density: np.ndarray, count: int, radius_cm: tuple[float, float]):
    """(N,) sum of Gaussian spots (peak ~1) at ``count`` texels drawn with ``density``."""
    lay = ctx.layout
    out = np.zeros(lay.mask.shape, np.float32)
    if count <= 0 or density.sum() <= 0:
        return out[lay.mask]
    p = density / density.sum()
    idx = rng.choice(len(p), size=count, p=p)
    rad = rng.uniform(*radius_cm, size=count)
    amp = rng.uniform(0.5, 1.0, size=count)
    ij = np.argwhere(lay.mask)[idx]
    h = lay.height
    # two radius classes, so each can be splatted by one blur per tile
    small = rad < np.mean(radius_cm)
    for sel in (small, ~small):
        if not sel.any():
            continue
        imp = np.zeros_like(out)
        np.add.at(imp, (ij[sel, 0], ij[sel, 1]), amp[sel])
        r = rad[sel].mean()
        for t, sl in enumerate((np.s_[:, :h], np.s_[:, h:])):
            s = max(r / ctx.texel_cm[t], 0.5)
            out[sl] += ndimage.gaussian_filter(imp[sl], s) * (2 * np.pi * s * s)
    return np.clip(out[lay.mask], 0, 1.5)


def _heights(ctx: AtlasContext, rng, age: float, lm) -> np.ndarray:
    """(N,) skin height field in mm: wrinkles, folds and mottling."""
    pos = ctx.pos
    x, y, z = pos[:, 0], pos[:, 1], pos[:, 2]
    soft = {n: ctx.soft[i] for i, n in enumerate(REGIONS[1:])}
    h = 0.04 * fbm3(pos, rng, 0.6, octaves=3)  # bumpy skin, 40 um
    wob = fbm3(pos, rng, 3.0, octaves=2)
    # forehead lines: horizontal furrows about 1 cm apart
    period = rng.uniform(0.8, 1.2)
    fl = -np.abs(np.sin(np.pi * (y + 0.25 * wob) / period)) ** 0.3
    h += age * 0.4 * (fl + 0.8) * soft["forehead"] * np.clip(1 - (np.abs(x) / 6) ** 2, 0, 1)
    # crow's feet: radial lines lateral to the eyes
    for eye in (lm[36:42], lm[42:48]):
        c = eye.mean(0)
        dx, dy = x - c[0], y - c[1]
        side = np.sign(c[0])
        ang = np.arctan2(dy, dx * side)
        r = np.hypot(dx, dy)
        w = np.exp(-((r - 2.4) / 0.7) ** 2) * (dx * side > 1.0)
        h += age * 0.25 * w * (-np.abs(np.sin(7 * ang + wob)) ** 0.5 + 0.6)
    # nasolabial folds: groove from the nose ala to beyond the mouth corner
    for a, b in ((lm[31], lm[48]), (lm[35], lm[54])):
        a = a[:2] + [np.sign(a[0]) * 0.4, 0.2]
        b = b[:2] + [np.sign(b[0]) * 0.5, -0.8]
        ab = b - a
        t = np.clip(((pos[:, :2] - a) @ ab) / (ab @ ab), 0, 1)
        d = np.linalg.norm(pos[:, :2] - (a + t[:, None] * ab), axis=1)
        h -= (0.1 + 0.25 * age) * np.exp(-(d / 0.25) ** 2) * (z > 5)
    # neck rings
    h += age * 0.3 * (-np.abs(np.sin(np.pi * (y + 0.3 * wob) / 1.6)) ** 0.4 + 0.7) * soft["neck"]
    return h


def _height_to_normals(ctx: AtlasContext, h_valid: np.ndarray) -> np.ndarray:
    """Tangent-space unit normals (H, 2H, 3) from a height field (mm) on valid texels."""
    lay = ctx.layout
    hh = np.zeros(lay.mask.shape, np.float64)
    hh.reshape(-1)[np.flatnonzero(lay.mask)] = h_valid
    hh = hh.reshape(-1)[lay.fill].reshape(lay.mask.shape)  # fill so borders get no cliffs
    hgt = lay.height
    out = np.zeros(lay.mask.shape + (3,))
    for t, sl in enumerate((np.s_[:, :hgt], np.s_[:, hgt:])):
        step_mm = ctx.texel_cm[t] * 10.0
        gy, gx = np.gradient(hh[sl], step_mm)
        # +u is +column, +v is -row (row 0 is v = 1): dh/dv = -dh/drow
        out[sl] = np.stack([-gx, gy, np.ones_like(gx)], -1)
    return (out / np.linalg.norm(out, axis=-1, keepdims=True)).astype(np.float32)


def _fill(ctx: AtlasContext, values: np.ndarray) -> np.ndarray:
    """(N, C) valid-texel values to a dilated (H, 2H, C) image."""
    lay = ctx.layout
    img = np.zeros((lay.mask.size, values.shape[1]), np.float32)
    img[np.flatnonzero(lay.mask)] = values
    return img[lay.fill].reshape(lay.mask.shape + (values.shape[1],))


def subject_params(seed: int, cal: Calibration) -> dict:
    """The scalar draws of subject ``seed`` (base chromophores and style parameters)."""
    base = draw_chromophores(subject_uniforms(seed)[None], cal.population)
    rng = np.random.default_rng([int(seed), 1])
    light = float(np.clip(1 - base["c_m"][0] / cal.population.cm_hi, 0, 1))
    return {
        "seed": int(seed), "c_m": float(base["c_m"][0]), "c_h": float(base["c_h"][0]),
        "b_m": float(base["b_m"][0]),
        "age": float(rng.beta(2.0, 2.5)),
        "male": bool(rng.random() < 0.5),
        "stubble": float(rng.beta(1.2, 2.0)),
        "freckles": float(rng.beta(0.6, 3.0) * light ** 4),
        "moles": int(rng.poisson(4)),
        "flush": float(rng.lognormal(0.0, 0.25)),
        "oiliness": float(rng.lognormal(0.0, 0.2)),
        "rough_offset": float(rng.normal(0.0, 0.04)),
        "hair_darkness": float(np.clip(0.35 + 0.6 * (1 - light) + rng.normal(0, 0.2), 0.1, 1)),
        "mottle": float(rng.uniform(0.05, 0.2)),
        "vessels": float(rng.beta(1.5, 4.0)),
        "region_jitter": rng.normal(0.0, 0.1, (len(REGIONS) - 1, 2)).tolist(),
    }


def generate_subject(seed: int, height: int = 256, calibration: Calibration | None = None
                     ) -> TextureSet:
    """One procedural subject's texture set, deterministic in (seed, height, calibration).

    Args:
        seed: non-negative subject id.
        height: atlas height H (maps are H x 2H).
    """
    cal = calibration or load_calibration()
    ctx = atlas_context(int(height))
    prm = subject_params(seed, cal)
    rng = np.random.default_rng([int(seed), 2])
    lm = default_template().vertices[LANDMARK_VERTICES]
    pos = ctx.pos
    soft = {n: ctx.soft[i] for i, n in enumerate(REGIONS[1:])}
    jit = np.exp(np.asarray(prm["region_jitter"]))
    rp = {n: REGION_PARAMS[n] for n in REGIONS[1:]}
    fm = _regional(ctx, {n: rp[n][0] * jit[i, 0] for i, n in enumerate(REGIONS[1:])})
    fh = _regional(ctx, {n: rp[n][1] * jit[i, 1] for i, n in enumerate(REGIONS[1:])})
    fh = 1 + (fh - 1) * prm["flush"]
    # low-frequency mottling of both chromophores
    c_m = prm["c_m"] * fm * np.exp(prm["mottle"] * fbm3(pos, rng, 4.0, octaves=3))
    c_h = prm["c_h"] * fh * np.exp(prm["mottle"] * fbm3(pos, rng, 3.0, octaves=3))
    # freckles: cheeks, nose and forehead; moles anywhere
    dens = soft["cheeks"] + soft["nose"] + 0.5 * soft["forehead"] + 0.2
    n_fr = int(prm["freckles"] * 2500 * (height / 256) ** 0)
    c_m = c_m * (1 + 1.5 * _spots(ctx, rng, dens, n_fr, (0.08, 0.2)))
    mole_dens = 1.0 - soft["sockets"] - soft["lips"]
    c_m = c_m * (1 + 4.0 * _spots(ctx, rng, np.clip(mole_dens, 0, None), prm["moles"],
                                  (0.12, 0.25)))
    # vessels: ridged noise lines on nose, cheeks, eyelids and neck
    ridge = np.clip(1 - np.abs(fbm3(pos, rng, 1.5, octaves=3)) / 0.25, 0, 1) ** 3
    vw = soft["nose"] + soft["cheeks"] + 1.5 * soft["eyelids"] + 0.6 * soft["neck"]
    c_h = c_h * (1 + 2.0 * prm["vessels"] * ridge * vw)
    alb = albedo_lut(cal.optics)(c_m, c_h, np.full_like(c_m, prm["b_m"]))
    # hair: brows, scalp (short hair / shaved look), stubble on the beard area
    strands = np.clip(0.5 + 0.5 * fbm3(pos * [1, 1, 1], rng, 0.15, octaves=2), 0, 1)
    beard = soft["upper_lip"] + soft["chin"] + soft["jaw"] + 0.5 * np.clip(
        soft["neck"] * (pos[:, 1] > lm[8, 1] - 4) * (ctx.layout.tile[ctx.layout.mask] == 0),
        0, 1)
    hair = (0.75 * soft["brows"] + 0.55 * soft["scalp"]
            + (0.35 * prm["stubble"] * beard if prm["male"] else 0.0))
    hair = np.clip(hair * (0.6 + 0.4 * strands), 0, 0.9)
    hair_rgb = np.array([0.09, 0.06, 0.04]) * (1.6 - 1.4 * prm["hair_darkness"])
    alb = alb * (1 - hair[:, None]) + hair[:, None] * hair_rgb
    # specular and roughness
    spec = _regional(ctx, {n: rp[n][2] for n in REGIONS[1:]}) * prm["oiliness"]
    spec = spec * (1 + 0.1 * fbm3(pos, rng, 2.0, octaves=2)) * (1 - 0.5 * hair)
    rough = (_regional(ctx, {n: rp[n][3] for n in REGIONS[1:]}) + prm["rough_offset"]
             + 0.03 * fbm3(pos, rng, 2.0, octaves=2) + 0.1 * hair)
    nrm = _height_to_normals(ctx, _heights(ctx, rng, prm["age"], lm))
    return TextureSet(
        diffuse=_fill(ctx, np.clip(alb, 0.0, 1.0)),
        specular=_fill(ctx, np.clip(spec, 0.0, 1.0)[:, None]),
        roughness=_fill(ctx, np.clip(rough, 0.2, 0.95)[:, None]),
        normal=nrm, params=prm)


def representative_albedo(ts: TextureSet, height: int) -> np.ndarray:
    """(3,) median linear sRGB over the forehead texels (a standard measurement site)."""
    ctx = atlas_context(int(height))
    sel = ctx.labels == REGION_ID["forehead"]
    return np.median(ts.diffuse[sel], axis=0)
