"""The person's iris colour from the photo(s), for the fit's renders and texture folder.

The renderer's iris (``render.materials.iris_vertex_colors``) is one linear RGB colour
``c`` shaped by a fixed pattern (pupil, striations, limbal ring). A pixel's radiance is
affine in ``c``: ``L(c) = c * D + S``, where ``S`` is what does not come from the iris's
diffuse reflection (the corneal gloss, the neighbours the pixel filter mixes in). Two
renders with one seed, the default colour ``c0`` and a black iris, give ``S = L(0)`` and
``D = (L(c0) - S) / c0``; then ``c = c0 * sum(photo - S) / sum(L(c0) - S)`` per channel
over the pixels below: one step of inverse rendering, exact for this light transport,
with the fitted geometry, camera and lighting held. Which pixels:

- the render's iris, as its G-buffer labels it (region ``iris``, fully covered), without
  its pupil and its sclera ring (by the G-buffer's albedo there);
- of those, the photo's pixels between the 10th and 75th percentile of luminance: the
  brighter quarter is where the model's iris falls on her sclera, lids or a catchlight
  (a gaze or aperture the model does not share), the darkest tenth her pupil;
- the same pixels of the renders, so that the ratio compares like with like.

``render.png``'s residual (photo over render, luminance, the same pixels) is reported. A
grey photo says nothing of the colour: the luminance is matched, the hue kept. Too few
pixels (closed or tiny eyes), or an estimate beyond :data:`RGB_BOUNDS` (e.g. a photo's iris
darker than the render's corneal gloss alone: the fitted light is smooth, so the cornea
reflects it as a veil where the photo has a dark iris and one catchlight): the colour is
kept and the report says so.
"""

from __future__ import annotations

import numpy as np

#: Fewer iris pixels than this (over all views) and the colour is left as it was.
MIN_PIXELS = 8
#: Luminance percentiles of the photo's iris pixels kept (see the module docstring).
KEEP_PERCENTILES = (10.0, 75.0)
#: The colour's bounds, linear RGB: an estimate beyond them is a failed one (kept as it was).
RGB_BOUNDS = (0.005, 0.6)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def iris_mask(gbuffer: dict, rgba: np.ndarray) -> np.ndarray:
    """(h, w) bool: the render's iris proper (no pupil, no sclera ring), fully covered."""
    from hack_render.render.materials import SCLERA_RGB
    from hack_render.render.parts import REGIONS

    seg = gbuffer["segmentation"] == REGIONS.index("iris")
    lum = gbuffer["albedo"][..., :3] @ _LUMA
    sclera = float(np.asarray(SCLERA_RGB) @ _LUMA)
    return seg & (rgba[..., 3] > 0.999) & (lum > 0.02) & (lum < 0.6 * sclera)


def kept_pixels(photo: np.ndarray, render, allowed: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: ``render``'s iris pixels (:func:`iris_mask`, within ``allowed``) whose
    photo luminance lies within ``KEEP_PERCENTILES`` (see the module docstring)."""
    m = iris_mask(render.gbuffer, render.rgba)
    if allowed is not None:
        m &= allowed
    if m.any():
        lum = photo[m] @ _LUMA
        lo, hi = np.percentile(lum, KEEP_PERCENTILES)
        m[m] = (lum >= lo) & (lum <= hi)
    return m


def estimate(photos: list[np.ndarray], renders: list, zero_renders: list, current,
             grey: bool = False, allowed: list | None = None
             ) -> tuple[tuple[float, float, float], dict]:
    """The iris colour that makes the renders match ``photos`` (linear RGB, each at its
    render's size) over the iris pixels (and ``allowed``'s, e.g. not the photo's
    occluders). ``renders`` (``texture.PhotoRender``) have the iris colour ``current``,
    ``zero_renders`` the same with a black iris and the same seed: their difference is the
    iris's own share of each pixel, the rest (the corneal gloss, the neighbours a pixel's
    filter mixes in) is left out of the ratio. Returns (rgb, report)."""
    current = np.asarray(current, np.float64)
    num, den, n = np.zeros(3), np.zeros(3), 0
    for photo, r, r0, ok in zip(photos, renders, zero_renders, allowed or [None] * len(photos)):
        keep = kept_pixels(photo, r, ok)
        p, q, q0 = (x[keep].astype(np.float64) for x in (photo, r.rgba[..., :3],
                                                         r0.rgba[..., :3]))
        num += (p - q0).sum(0)
        den += (q - q0).sum(0)
        n += int(keep.sum())
    report = {"pixels": n, "start": current.tolist()}
    if n < MIN_PIXELS or not np.all(den > 0):
        report["source"] = f"kept: {n} iris pixels seen (fewer than {MIN_PIXELS})"
        return tuple(float(x) for x in current), report
    ratio = num / den
    if grey:  # the luminance only
        ratio = np.full(3, float(num @ _LUMA / (den @ _LUMA)))
    rgb = current * ratio
    if not np.all((rgb >= RGB_BOUNDS[0]) & (rgb <= RGB_BOUNDS[1])):
        # e.g. the photo's iris darker than the render's corneal gloss alone: the fitted
        # light (smooth) reflects as a veil where the photo has a dark iris and a catchlight
        report["source"] = (f"kept: the estimate {np.round(rgb, 4).tolist()} is beyond "
                            f"{list(RGB_BOUNDS)} (a photo the render's iris cannot explain)")
        return tuple(float(x) for x in current), report
    report.update(source="photo (grey: luminance only)" if grey else "photo",
                  rgb=rgb.tolist())
    return tuple(float(x) for x in rgb), report


def _at_render_size(state, renders: list, allowed: list | None):
    """The views' photos and ``allowed`` masks (photo-size, or None) at each render's size."""
    from hack_render.fit import texture

    sizes = [r.rgba.shape[:2] for r in renders]
    photos = [texture.photo_at(v, *hw) for v, hw in zip(state.views, sizes)]
    masks = [None if a is None else texture.mask_at(a, *hw)
             for a, hw in zip(allowed or [None] * len(sizes), sizes)]
    return photos, masks


def fit_colour(state, cfg, allowed: list | None = None, spp: int = 16, maps=None
               ) -> tuple[tuple[float, float, float], dict]:
    """The iris colour of the state's views (:func:`estimate`), from two renders per view
    at the photo's size (at most ``cfg.final.max_side``), ``spp`` samples, one seed: the
    default iris and a black one, with ``maps`` (default: the fitted skin maps).
    ``allowed``: per view a photo-size bool mask of the pixels it may use, or None."""
    import dataclasses

    from hack_render.fit import texture
    from hack_render.render.materials import DEFAULT_IRIS_RGB

    maps = maps if maps is not None else texture._skin_maps(state)
    renders, zeros = [], []
    for v in state.views:
        for rgb, out in ((DEFAULT_IRIS_RGB, renders), ((0.0, 0.0, 0.0), zeros)):
            out.append(texture.render_at_photo(state, cfg, v, spp=spp,
                                               max_side=cfg.final.max_side,
                                               maps=dataclasses.replace(maps, iris_rgb=rgb)))
    photos, masks = _at_render_size(state, renders, allowed)
    grey = all(v.photo.is_grey for v in state.views)
    return estimate(photos, renders, zeros, DEFAULT_IRIS_RGB, grey, masks)


def residual(state, renders: list, allowed: list | None = None) -> float | None:
    """photo / render luminance over the kept iris pixels of ``renders`` (the state's
    views, e.g. ``render.png``'s; 1: matched); ``allowed`` as :func:`fit_colour`'s."""
    photos, masks = _at_render_size(state, renders, allowed)
    num = den = 0.0
    for photo, r, ok in zip(photos, renders, masks):
        keep = kept_pixels(photo, r, ok)
        if keep.sum() >= MIN_PIXELS:
            num += float((photo[keep] @ _LUMA).sum())
            den += float((r.rgba[..., :3][keep] @ _LUMA).sum())
    return num / den if den > 0 else None
