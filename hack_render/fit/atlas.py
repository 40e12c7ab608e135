"""Photo pixels into the model's skin atlas (the bake of :mod:`hack_render.fit.texture`):
each view's weighted pixels as atlas samples at their model UV (:func:`atlas_samples`,
with each pixel's footprint in texels), splatted by footprint band
(:func:`splat`: bilinearly, then a Gaussian of the band's footprint, so wide pixels leave
no gaps), the confidence from the splat's density (:func:`splat_confidence`), and the
fallback map tone-matched to what was baked (:func:`tone_matched_prior`, with the wide
constant-mode Gaussian :func:`wide_gaussian`)."""

from __future__ import annotations

import numpy as np

from hack_render.fit.bake_weights import PhotoRender

#: footprint bands of the bake's splat (:func:`bake_diffuse`): band b holds the pixels
#: FOOTPRINT_STEP^b to ^(b+1) times the median footprint, the last those beyond
FOOTPRINT_BANDS = 8
FOOTPRINT_STEP = 2.0 ** 0.5
#: each band's splat: a Gaussian of this share of its widest footprint (its widest
#: pixels leave no gaps), at least SPLAT_MIN texels. Bands of 2x and a Gaussian of half
#: the narrowest footprint (the same at the widest) blurred the photo's densest pixels:
#: bands of sqrt(2) bake the astronaut's pixels 33.3 -> 34.7 dB; narrower splats are
#: sharper still in the photo's own view but leave wide pixels as discs in the atlas,
#: which other views show (docs/fit.md)
SPLAT_SIGMA = 0.25
SPLAT_MIN = 0.7


def pixel_footprints(x: np.ndarray, y: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """(h, w) each selected pixel's footprint in texels: the larger of its horizontal and
    vertical extents, each the smaller of the uv distances to its two neighbours on that
    axis that are selected too (a neighbour across a UV seam is far: the other is taken);
    NaN where a pixel has no selected neighbour on an axis."""
    out = []
    for axis in (1, 0):
        d = np.hypot(np.diff(x, axis=axis), np.diff(y, axis=axis))
        pair = sel[:, :-1] & sel[:, 1:] if axis == 1 else sel[:-1] & sel[1:]
        d = np.where(pair, d, np.inf)
        fwd, bwd = np.full(x.shape, np.inf), np.full(x.shape, np.inf)
        if axis == 1:
            fwd[:, :-1], bwd[:, 1:] = d, d
        else:
            fwd[:-1], bwd[1:] = d, d
        out.append(np.minimum(fwd, bwd))
    f = np.maximum(out[0], out[1])
    return np.where(np.isfinite(f), f, np.nan)


def atlas_samples(pr: PhotoRender, wgt: np.ndarray, obs: np.ndarray, H: int):
    """One view's pixels of weight > 0 as atlas samples for :func:`splat`: (x, y) in the
    atlas's pixels (H rows), weight, observation (n, C) and footprint in texels; None
    where no pixel has weight."""
    sel = wgt > 0
    if not sel.any():
        return None
    uv = pr.gbuffer["uv"]
    x = uv[..., 0] * H - 0.5          # atlas pixel coordinates (centres at +0.5)
    y = (1.0 - uv[..., 1]) * H - 0.5
    f = pixel_footprints(x, y, sel)
    obs = obs.reshape(*wgt.shape, -1)
    return x[sel], y[sel], wgt[sel], obs[sel], f[sel]


def splat(samples: list, H: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The views' atlas samples (:func:`atlas_samples`; None entries skipped) splatted
    into an (H, 2H) atlas (see the module's docstring): the weighted mean observation
    (H, 2H, C) (0 where unseen), the spread area-weighted density (the confidence's,
    :func:`splat_confidence`), and the median photo pixel's footprint in texels."""
    from scipy.ndimage import gaussian_filter

    W = 2 * H
    samples = [s for s in samples if s is not None]
    C = samples[0][3].shape[1] if samples else 1
    # the photo pixel's footprint in texels: the views' median (neighbours' uv distance)
    fps = [float(np.median(f[np.isfinite(f)])) for *_, f in samples if np.isfinite(f).any()]
    fp = float(np.median(fps)) if fps else 1.0
    # per footprint band b (a pixel spanning fp 2^b texels and more): weighted sums
    num = np.zeros((FOOTPRINT_BANDS, H, W, C), np.float32)
    den = np.zeros((FOOTPRINT_BANDS, H, W), np.float32)
    area = np.zeros((FOOTPRINT_BANDS, H, W), np.float32)   # den x (footprint / median)^2
    for xs, ys, ws, os_, f in samples:
        rel = np.clip(np.nan_to_num(f, nan=fp) / fp, 1.0, FOOTPRINT_STEP ** FOOTPRINT_BANDS)
        band = np.minimum(np.floor(np.log(rel) / np.log(FOOTPRINT_STEP)),
                          FOOTPRINT_BANDS - 1).astype(int)
        x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
        fx, fy = xs - x0, ys - y0
        # the 4 bilinear corners of every sample, summed per texel over the texels they
        # reach (a few percent of the bands' 10 M: no atlas-sized bincount per term)
        flat = np.concatenate([band * (H * W) + np.clip(y0 + oy, 0, H - 1) * W
                               + np.clip(x0 + ox, 0, W - 1)
                               for ox, oy in ((0, 0), (1, 0), (0, 1), (1, 1))])
        kw = np.concatenate([ws * (1 - fx) * (1 - fy), ws * fx * (1 - fy),
                             ws * (1 - fx) * fy, ws * fx * fy])
        texels, at = np.unique(flat, return_inverse=True)
        n = len(texels)
        den.reshape(-1)[texels] += np.bincount(at, kw, n)
        area.reshape(-1)[texels] += np.bincount(at, kw * np.tile(rel * rel, 4), n)
        for c in range(C):
            num.reshape(-1, C)[texels, c] += np.bincount(at, kw * np.tile(os_[:, c], 4), n)
    # each band spread by a normalised Gaussian of half its footprint, so that wider
    # pixels (oblique skin, stretched UVs) leave no gaps between their splats; for the
    # confidence each pixel's weight counts by its area (in median pixels), so a texel
    # seen by fewer, wider pixels is as sure as one seen by more, narrower ones
    den_b = np.zeros((H, W))
    num_b = np.zeros((H, W, C))
    dens = np.zeros((H, W))
    for b in range(FOOTPRINT_BANDS):
        if not den[b].any():
            continue
        sigma = max(SPLAT_MIN, SPLAT_SIGMA * fp * FOOTPRINT_STEP ** (b + 1))
        # only the band's box, grown by twice the kernel's reach (clamped to the atlas):
        # everything beyond is zero in and out, the reflections at the box's inner edges
        # reflect zeros, so the result is the whole atlas's filtered, a fraction of the work
        box = _grown_box(den[b] != 0, 2 * (int(4.0 * sigma + 0.5) + 1))
        den_b[box] += gaussian_filter(den[b][box].astype(np.float64), sigma)
        dens[box] += gaussian_filter(area[b][box].astype(np.float64), sigma)
        num_b[box] += np.stack([gaussian_filter(num[b][box][..., c].astype(np.float64), sigma)
                                for c in range(C)], -1)
    seen = den_b > 1e-8
    obs = np.where(seen[..., None], num_b / np.maximum(den_b, 1e-12)[..., None], 0.0)
    return obs, dens, fp


def _grown_box(mask: np.ndarray, grow: int) -> tuple[slice, slice]:
    """The bounding box of ``mask``'s True entries grown by ``grow`` on every side,
    clamped to the array (slices)."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    h, w = mask.shape
    return (slice(max(int(rows[0]) - grow, 0), min(int(rows[-1]) + grow + 1, h)),
            slice(max(int(cols[0]) - grow, 0), min(int(cols[-1]) + grow + 1, w)))


def splat_confidence(dens: np.ndarray, fp: float, feather: float) -> np.ndarray:
    """(H, 2H) in [0, 1] from :func:`splat`'s density: full where a texel gets half the
    density a fully seen texel gets at cos = 1 (a pixel's unit weight spread over fp^2
    texels); with ``feather`` > 0 held under itself blurred by a Gaussian of that many
    footprints, so the bake's edge fades into the fallback (the segmentation's jagged
    edge, hair and occluders, is not drawn as a jagged line)."""
    from scipy.ndimage import gaussian_filter

    conf = np.clip(dens / (0.5 / max(fp * fp, 1.0)), 0.0, 1.0)
    if feather > 0:
        conf = np.minimum(conf, gaussian_filter(conf, feather * fp))
    return conf


#: The gain field's Gaussian width, a share of the atlas's height (~40 texels at 1,024).
TONE_SIGMA = 0.04


def tone_matched_prior(prior: np.ndarray, photo: np.ndarray, weight: np.ndarray,
                       inside: bool = False) -> np.ndarray:
    """``prior`` (the fallback map, A(alpha)) tone-matched to the photo's texels, so the
    baked face does not end in a seam: prior * exp(g), g a smooth per-channel log gain.
    The photo's log colour where it saw the skin (``weight`` > 0.5) is spread by
    normalised Gaussian convolution (``TONE_SIGMA``) and blends, with the share of seen
    texels around, into the seen texels' median far away (the neck, the scalp, the back
    of the head, the other UV tile); g is that over the prior's own tone (its log
    Gaussian of the same width over the atlas's texels). So the unseen skin continues
    the face's colour with the prior's detail, no new seam (A(alpha)'s neck is lighter
    than its face: it kept that 1.4x on Grace Hopper's fit). ``inside`` False: the holes
    the seen texels enclose (eyes, mouth, nostrils) keep ``prior``. Seen texels are
    unchanged by this (the bake takes the photo there)."""
    from scipy.ndimage import binary_fill_holes

    H = prior.shape[0]
    seen = weight > 0.5
    if seen.sum() < 16:
        return prior
    eps = 1e-3
    sigma = TONE_SIGMA * H
    # the prior's own tone: its log, smoothed over the atlas's texels
    lp = np.log(np.clip(prior, eps, None))
    valid = (prior.max(-1) > eps).astype(np.float64)
    vb = wide_gaussian(valid, sigma)
    tone = np.stack([wide_gaussian(lp[..., c] * valid, sigma)
                     for c in range(3)], -1) / np.maximum(vb, 1e-9)[..., None]
    lphoto = np.log(np.clip(photo, eps, None))
    g0 = np.median(lphoto[seen], axis=0) - tone
    w = seen.astype(np.float64)
    wb = wide_gaussian(w, sigma)
    # near the seen skin: its colour spread (in log) over the prior's tone, likewise
    local = np.stack([wide_gaussian(lphoto[..., c] * w, sigma)
                      for c in range(3)], -1) / np.maximum(wb, 1e-9)[..., None] - tone
    # the share of seen texels around (half the kernel's mass: the seen face's edge) -> 1
    a = np.clip(wb / 0.5, 0.0, 1.0)[..., None]
    gain = a * np.where(wb[..., None] > 1e-6, local, g0) + (1.0 - a) * g0
    out = prior * np.exp(np.clip(gain, np.log(0.25), np.log(4.0)))
    if not inside:  # the enclosed holes keep the prior (per UV tile)
        holes = np.zeros_like(seen)
        for t in (slice(0, H), slice(H, 2 * H)):
            holes[:, t] = binary_fill_holes(seen[:, t]) & ~seen[:, t]
        out = np.where(holes[..., None], prior, out)
    return out


def wide_gaussian(x: np.ndarray, sigma: float) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter(x, sigma, mode="constant")`` of a 2-D array (its
    kernel: truncated at 4 sigma, normalised) as FFT convolutions, one per axis, over the
    array padded with zeros by the kernel's reach: the same to float64 rounding (~1e-15;
    beyond the kernel's reach ~1e-18 where it gives 0), for the wide kernels of
    :func:`tone_matched_prior` (41 texels at 1,024: ~0.1 s instead of 0.5 s a channel)."""
    r = int(4.0 * sigma + 0.5)
    t = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (t / sigma) ** 2)
    k /= k.sum()
    y = np.ascontiguousarray(x, np.float64)
    for axis in (0, 1):
        n = y.shape[axis]
        size = n + 2 * r          # the whole linear convolution: no wrap-around
        f = np.fft.rfft(y, size, axis=axis)
        kf = np.fft.rfft(k, size)
        full = np.fft.irfft(f * (kf[:, None] if axis == 0 else kf[None, :]), size, axis=axis)
        y = full[r:r + n] if axis == 0 else full[:, r:r + n]
    return y
