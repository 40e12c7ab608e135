"""The skin's specular intensity where the photo identifies it: a per-texel gain on the
fitted specular map (A(alpha)'s), from the photo over two renders of the fitted view.

The skin BSDF (``render/skin_bsdf.py``) is linear in its specular intensity ``s`` to first
order (the lobe scales with ``s``, the diffuse loses ``s F``), so a pixel of a render whose
specular map is ``k s`` reads ``R0 + k G``, with ``R0`` the render without specular and
``G = R - R0`` what the fitted map adds. The photo's pixel ``P`` is then modelled as::

    P_c = l q_c R0_c + k G_c        (per channel c)

``q`` the skin's colour against the fitted albedo, smoothed (the photo less ``k G`` over
``R0``, a normalised Gaussian over the baked pixels, alternated with ``k``:
:data:`COLOUR_PASSES`; the sheen is everywhere, and left in it tints ``q``), ``l`` the
pixel's brightness and ``k`` the specular gain: two unknowns from three channels, told
apart because the highlight has the light's colour and the diffuse the skin's (the
dichromatic model). A weak pull (:data:`SHRINK`) holds ``k`` near 1 where a pixel says
little. A pixel counts by how well it knows ``k``: its bake weight times
``min(1, (SE_FULL / se)^2)``, ``se`` the gain's standard error from the part of ``G``
orthogonal to the skin's colour and what the model leaves unexplained around the pixel
(its residual, plus a noise floor :data:`NOISE`).

The gains are splatted into a coarse atlas (:data:`ATLAS_HEIGHT`, 16 rows: a region of
the face per texel, the T-zone, a cheek, the chin) as the diffuse bake's observations
(``atlas.splat``), resampled to the map's size, and the map is ``s (c g + 1 - c)``,
``c`` their confidence: the fitted map where the photo says nothing (no highlight, a grey
photo). Per pixel the split is not to be trusted: a skin's own colour texture (creases,
a film's tint, the more saturated skin in shadow) moves along the same direction as a
highlight, and at 128 rows Grace Hopper's map was a net of black and white blotches;
what the photo identifies is the gloss of a region. It is biased towards the fitted map
(a synthetic face twice as glossy comes back 1.1x, its error 0.81 of the fitted map's:
the skin's colour takes part of a sheen that is everywhere).
The diffuse bake's refinement pass (``final.refine``) then divides the re-render with
this map out of the photo, so the highlight is not baked into the albedo twice.
"""

from __future__ import annotations

import numpy as np

from hack_render.fit import atlas, texture
from hack_render.fit.bake_weights import photo_at

#: A pixel's specular share (|G| / |R|) of reference for the pull below.
FULL_SHARE = 0.1
#: A pixel whose gain's standard error is this counts fully (its weight falls as the
#: error's square beyond).
SE_FULL = 0.25
#: The photo's noise floor, a share of the pixel's value, added to the model's residual.
NOISE = 0.01
#: The share of a white highlight orthogonal to a typical skin's colour (linear RGB
#: about (0.45, 0.25, 0.15): 0.16).
SKIN_ORTHO = 0.15
#: The pull of the gain towards 1, as a share of what a pixel whose specular is
#: :data:`FULL_SHARE` of it, at :data:`SKIN_ORTHO`, knows of it (0: none).
SHRINK = 0.1
#: The gain's bounds (the map is clipped to [0, 1] after).
GAIN_BOUNDS = (0.0, 4.0)
#: The gains' atlas (rows): a region of the face per texel (the module's docstring).
ATLAS_HEIGHT = 16
#: Passes of the skin colour ``q`` (from the photo less the specular the gains give) and
#: the gains.
COLOUR_PASSES = 4
#: The Gaussian of the skin colour ``q``, as a share of the eyes' outer-corner distance.
COLOUR_SIGMA = 0.3


def gain_observations(photo: np.ndarray, rgb: np.ndarray, rgb0: np.ndarray,
                      wgt: np.ndarray, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel (h, w): the specular gain ``k`` and its weight (module docstring), from
    the photo, the render with the fitted specular (``rgb``), the one without (``rgb0``),
    all linear (h, w, 3), and the bake's pixel weights ``wgt``."""
    from scipy.ndimage import gaussian_filter

    g = rgb - rgb0
    ok = wgt > 0
    wf = ok.astype(np.float64)
    gg = (g * g).sum(-1)
    rr = (rgb * rgb).sum(-1)
    # mu: the pull towards 1 (SHRINK)
    mu = SHRINK * SKIN_ORTHO * FULL_SHARE ** 2 * rr
    den = np.stack([gaussian_filter(wf * rgb0[..., c], sigma_px) for c in range(3)], -1)
    k = np.ones(wgt.shape)
    for _ in range(COLOUR_PASSES):
        # the skin's colour: the photo without the specular the current gains give, over
        # the render without specular (the sheen is everywhere, not only in highlights)
        diffuse = photo - k[..., None] * g
        num = np.stack([gaussian_filter(wf * diffuse[..., c], sigma_px) for c in range(3)], -1)
        a = num / np.maximum(den, 1e-6) * rgb0
        aa, ag = (a * a).sum(-1), (a * g).sum(-1)
        ap, gp = (a * photo).sum(-1), (g * photo).sum(-1)
        # normal equations of min |P - l a - k g|^2 + mu (k - 1)^2
        det = aa * (gg + mu) - ag * ag
        good = ok & (det > 1e-12) & (aa > 1e-12)
        k = np.ones(wgt.shape)
        k[good] = (aa * (gp + mu) - ag * ap)[good] / det[good]
        k = np.clip(k, *GAIN_BOUNDS)
    # how well a pixel knows k: the specular's part orthogonal to the skin's colour, over
    # what the two-colour model leaves unexplained around it (its residual, one degree of
    # freedom per pixel, averaged over the colour's Gaussian): the skin's own colour
    # texture (creases, freckles, a film's tint) reads as gloss where it changes within
    # that Gaussian, and there the residual is as large
    info = np.where(good, gg - ag * ag / np.maximum(aa, 1e-12), 0.0)
    lum = np.where(good, (ap - k * ag) / np.maximum(aa, 1e-12), 0.0)
    res = ((photo - lum[..., None] * a - k[..., None] * g) ** 2).sum(-1)
    s2 = gaussian_filter(wf * res, sigma_px) / np.maximum(gaussian_filter(wf, sigma_px), 1e-6)
    se2 = (s2 + NOISE ** 2 * rr) / np.maximum(info, 1e-20)
    w = np.where(good, wgt * np.minimum(SE_FULL ** 2 / se2, 1.0), 0.0)
    return k.astype(np.float32), w.astype(np.float32)


def bake_specular(state, cfg, renders: list, renders0: list, weights: list,
                  specular: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """The specular map (H, 2H, 1) and its confidence (H, 2H) at ``specular``'s size (the
    fitted map, the renders' own), from each view's photo, its render with the fitted
    maps (``renders``), without specular (``renders0``) and its bake weights; and a
    report (the face's texels identified, their median gain). Grey photos are skipped
    (no colour to tell the highlight from the skin)."""
    H = ATLAS_HEIGHT
    samples = []
    for v, pr, pr0, wgt in zip(state.views, renders, renders0, weights):
        if v.photo.is_grey:
            continue
        h, w = wgt.shape
        pts = v.detection.points * (w / v.photo.width)
        sigma = max(1.0, COLOUR_SIGMA * float(np.linalg.norm(pts[45] - pts[36])))
        k, wk = gain_observations(photo_at(v, h, w), pr.rgba[..., :3], pr0.rgba[..., :3],
                                  wgt, sigma)
        samples.append(atlas.atlas_samples(pr, wk, k[..., None], H))
    if not any(s is not None for s in samples):
        why = "no colour photo" if not samples else "no pixel identifies it"
        return specular, np.zeros(specular.shape[:2], np.float32), \
            {"identified_fraction": 0.0, "source": f"the fitted map ({why})"}
    gain, dens, fp = atlas.splat(samples, H)
    conf = atlas.splat_confidence(dens, fp, cfg.final.edge_feather)
    gain = np.where(conf[..., None] > 0, gain, 1.0)
    full = specular.shape[0]        # the gain field, bilinear, at the map's size
    gain = texture.resize_atlas(gain.astype(np.float32), full)
    conf = np.clip(texture.resize_atlas(conf[..., None].astype(np.float32), full)[..., 0],
                   0.0, 1.0)
    out = specular * (conf[..., None] * gain + (1.0 - conf[..., None]))
    sure = conf > 0.5
    report = {"identified_fraction": texture.face_seen_fraction(state, conf),
              "median_gain": float(np.median(gain[sure, 0])) if sure.any() else None,
              "source": "derived: the fitted map times the gain the photo's highlights "
                        "give where they identify it (fit/specular_bake.py)"}
    return np.clip(out, 0.0, 1.0).astype(np.float32), conf.astype(np.float32), report
