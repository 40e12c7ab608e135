"""The shadow an occluder casts on the skin next to it, for the bake.

Hair over the forehead (the segmentation's occluders and its hair: the caller passes
both), a hat's brim, a hand or glasses darken the skin just beside them: a contact
shadow (and, within a pixel or two, the occluder's own strands mixed into the pixel). The
fitted render has no hair, so the photo / render ratio reads that shadow as darker skin,
and the bake writes it into the albedo: a dark rim along the fringe's edge, which
``render.png`` and a turntable show as a line across the forehead.

:func:`occluder_shadow` takes each skin pixel's log ratio against the level of the skin
farther from the occluders (a normalised Gaussian average of the pixels beyond ``reach``),
and where a pixel within ``reach`` of an occluder is darker than that level by more than
the skin's own texture (``FLOOR``), it takes the darkening for the shadow's: the bake
divides it out, in full to half the reach and less towards the reach. The shadow is
uneven along a fringe (deeper where the hair lies closer), so it is taken pixel by pixel,
not as one profile. Pixels darker than ``MIXED`` are the occluder's own strands in the
pixel: they leave the bake. Specks of occluder (a dark iris or a lip's corner the
segmentation calls one) cast no shadow: only occluders of ``MIN_AREA`` count. The
brows and lips (the caller's features) keep their darkness.
"""

from __future__ import annotations

import numpy as np

#: a pixel beside an occluder darker than the skin's level by more than this (0.7x) is
#: the occluder's own strands mixed into the pixel: left out of the bake, not brightened
MIXED = float(np.log(0.7))
#: the fewest pixels a distance bin needs for its median (the reported profile), and the
#: fewest skin pixels beyond the reach the level is taken from
MIN_BIN = 12
#: darkenings shallower than this (3 %) are the skin's own texture, not a shadow: the
#: shadow's depth is taken less this
FLOOR = 0.03
#: the smallest occluder (connected pixels, in units of reach^2) whose shadow is measured
MIN_AREA = 2.0


def occluder_shadow(lr: np.ndarray, ok: np.ndarray, occluded: np.ndarray, reach: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log gain (h, w) <= 0 the occluders' shadow puts on each pixel, pixels too dark to
    be shadow (h, w) bool, the profile per one-pixel distance bin) of one view.

    ``lr``: each pixel's log ratio photo / render; ``ok``: the skin pixels it is measured
    on; ``occluded``: the occluders' mask; ``reach``: the farthest the shadow is looked for,
    in pixels (no gain beyond; the skin's level is taken from there)."""
    from scipy.ndimage import distance_transform_edt, gaussian_filter, label

    h, w = lr.shape
    zero = np.zeros((h, w)), np.zeros((h, w), bool), np.zeros(0)
    n = int(np.ceil(reach))
    if n < 2 or not occluded.any() or not ok.any():
        return zero
    # the occluders that can cast a shadow this wide: specks (a dark iris or a lip's
    # corner the segmentation calls an occluder) have dark features, not shadows, around
    lab, k = label(occluded)
    area = np.bincount(lab.ravel(), minlength=k + 1)
    big = area >= MIN_AREA * reach * reach
    big[0] = False
    if not big.any():
        return zero
    d = distance_transform_edt(~big[lab])
    far = ok & (d > reach)
    if far.sum() < MIN_BIN:
        return zero
    sigma = max(1.0, reach)
    cnt = gaussian_filter(far.astype(np.float64), sigma)
    level = gaussian_filter(np.where(far, lr, 0.0), sigma) / np.maximum(cnt, 1e-6)
    # (no level where no skin beyond the reach is near enough: no shadow taken there)
    delta = np.where(cnt > 1e-3, lr - level, 0.0)
    # each pixel's darkening below that level, less the skin's own texture (FLOOR), full
    # to half the reach and tapering to 0 at the reach: a fringe shades the forehead
    # under it unevenly (deeper where the hair lies closer), so no one profile fits
    taper = np.clip(2.0 - 2.0 * d / reach, 0.0, 1.0)
    gain = np.where(ok & (d > 0), np.minimum(delta + FLOOR, 0.0) * taper, 0.0)
    prof = np.zeros(n + 1)      # the median darkening per one-pixel distance bin (a report)
    bins = np.where(ok, np.ceil(d), 0).astype(int)
    for k in range(1, n + 1):
        sel = bins == k
        if sel.sum() >= MIN_BIN:
            prof[k] = min(float(np.median(delta[sel])), 0.0)
    mixed = (d <= n) & (gain < MIXED)   # darker than a shadow: strands in the pixel
    return np.where(mixed, 0.0, gain), mixed, prof
