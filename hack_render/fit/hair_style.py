"""The photo's hair as a style of the hair layer (issue 61): archetype, volume, hairline
and melanin picked from the segmentation's hair mask and the hair's colour.

A starting point, not a hair fit: what a single photo shows of hair is its outline and its
colour, so that is what is read, in units of the outer-eye distance ``d`` and in a frame
turned with the face (``u`` to the photo's right, ``w`` up, from the chin to the brows):

- **none**: fewer hair pixels than ``0.25 d^2`` -> ``bald``;
- **length**: the lowest hair beside the face (``|u|`` past 80 % of the jaw's half width):
  below the chin by ``0.4 d`` -> ``long``; below the mouth -> ``bob``; otherwise ``short``,
  or ``crew`` when the hair on top is thinner than ``0.25 d`` over the brows' level +
  ``0.95 d`` (where a bald head's top is, on the model's mean head) and narrower than
  1.25 face widths at the forehead (a crew cut is not parted: ``parting`` none);
- **afro**: hair wider than 2.2 face widths at the forehead, above the brows;
- **volume**: the hair's width at the forehead over the face's: 1.05 -> 0, 1.65 -> 1;
- **hairline**: the lowest hair over the forehead's middle, 0.75 d over the brows -> 0 ...
  1.35 d -> 1 (a fringe reads as a full hairline);
- **colour**: the hair pixels' median linear RGB divided by the light the skin shows
  (the photo's skin over the fitted skin albedo) is the hair's albedo, turned into
  melanin by the renderer's own calibration (:func:`hack_render.hair.style.albedo_melanin`).
  Highlights (the brightest 15 % of hair pixels) are left out, and so are the hair
  mask's pixels that look like the face's own skin (:func:`colour_pixels`: the
  segmentation calls a bare upper forehead, the temples and the ears "hair" where they
  are not the face's skin mask: on obama's portrait 2,118 of the mask's 18,386 pixels,
  his hair's albedo (0.069, 0.046, 0.032) with them, (0.061, 0.042, 0.030) without),
  unless too few would remain (blond hair on light skin); only the parts joined to the
  skin mask, so the hair's own highlights of the skin's colour stay (the astronaut's:
  44 pixels left out, her colour unchanged).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hack_render.hair.style import HairStyle, albedo_melanin

MIN_HAIR_AREA = 0.25  # in d^2
TOP_OF_HEAD = 0.95  # the mean head's top over the brows, in d (85 mm over 90 mm)
HAIRLINE_FULL, HAIRLINE_RECEDED = 0.75, 1.35
CREW_WIDTH = 1.25  # a crew cut's hair at the forehead, face widths, at most
#: a hair pixel within this many robust spreads (1.4826 MAD) of the face's skin median in
#: every colour feature (log luminance; the r and b shares in a colour photo) is the
#: skin's: left out of the hair's colour (:func:`colour_pixels`) ...
SKIN_LIKE_SPREADS = 2.5
#: ... unless fewer than this share of the hair pixels would remain
MIN_HAIR_SHARE = 0.25
#: the spreads' floors (log luminance, shares): a flat-lit face's skin is not a point
FEATURE_FLOOR = np.array([0.08, 0.01, 0.01])
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(origin, u, w, d): the eyes' centre, the face's right and up unit vectors, the
    outer-eye distance, from 68 points (x right, y down)."""
    left, right = points[36], points[45]
    d = float(np.linalg.norm(right - left))
    origin = (left + right) / 2
    u = (right - left) / max(d, 1e-9)
    w = np.array([u[1], -u[0]])  # up in the photo (y down)
    if np.dot(points[8] - origin, w) > 0:
        w = -w
    return origin, u, w, d


def hair_style_from_photo(photo: np.ndarray, hair: np.ndarray, skin: np.ndarray | None,
                          points: np.ndarray, skin_albedo, base: HairStyle | None = None
                          ) -> tuple[HairStyle, dict]:
    """(style, report) from a photo's hair.

    photo: (H, W, 3) linear RGB; hair, skin: (H, W) bool masks (the segmentation's); points:
    (68, 2) pixel coordinates of the 68 landmarks; skin_albedo: (3,) linear RGB of the
    fitted skin (the face's mean diffuse albedo); base: the other fields (brows, beard,
    lod, seed), the default style when None."""
    base = base or HairStyle()
    origin, u_axis, w_axis, d = _frame(np.asarray(points, np.float64))
    ys, xs = np.nonzero(hair)
    report: dict = {"hair_pixels": len(xs), "eye_distance_px": round(d, 2)}
    if len(xs) < MIN_HAIR_AREA * d * d:
        report["archetype_reason"] = f"hair area {len(xs) / d ** 2:.2f} d^2 < {MIN_HAIR_AREA}"
        return replace(HairStyle.archetype_style("bald", **_keep(base))), report
    rel = np.stack([xs + 0.5, ys + 0.5], -1) - origin
    u, w = rel @ u_axis / d, rel @ w_axis / d
    p = (np.asarray(points, np.float64) - origin)
    pu, pw = p @ u_axis / d, p @ w_axis / d
    half = (pu[16] - pu[0]) / 2
    brow = float(np.mean(pw[17:27]))
    chin, mouth = float(pw[8]), float(pw[57])
    side = np.abs(u) > 0.8 * half
    lowest = float(w[side].min()) if side.any() else brow
    forehead = (w > brow) & (w < brow + 1.0)
    width = float(np.ptp(u[forehead])) / (2 * half) if forehead.sum() > 10 else 1.0
    top = float(w.max())
    centre = (np.abs(u) < 0.5 * half) & (w > brow)
    line = float(np.percentile(w[centre], 2)) - brow if centre.sum() > 10 else HAIRLINE_FULL
    if width > 2.2:
        archetype, why = "afro", f"hair {width:.2f} face widths wide at the forehead"
    elif lowest < chin - 0.4:
        archetype, why = "long", f"hair reaches {lowest - chin:+.2f} d from the chin"
    elif lowest < mouth:
        archetype, why = "bob", f"hair reaches {lowest - mouth:+.2f} d from the mouth"
    elif top - (brow + TOP_OF_HEAD) < 0.25 and width < CREW_WIDTH:
        archetype, why = "crew", f"hair {top - brow - TOP_OF_HEAD:+.2f} d over the head's top"
    else:
        archetype, why = "short", f"hair {top - brow - TOP_OF_HEAD:+.2f} d over the head's top"
    volume = float(np.clip((width - 1.05) / 0.6, 0.0, 1.0))
    hairline = float(np.clip((line - HAIRLINE_FULL) / (HAIRLINE_RECEDED - HAIRLINE_FULL),
                             0.0, 1.0))
    eu, pheo, albedo, picked = _melanin(photo, hair, skin, skin_albedo)
    kw = {**_keep(base), "hairline": hairline, "eumelanin": eu, "pheomelanin": pheo}
    if archetype != "afro":
        kw["volume"] = volume
    if archetype == "crew":  # too short to part: combed back, no scalp line on top
        kw["parting"] = "none"
    style = HairStyle.archetype_style(archetype, **kw)
    report.update({"archetype": archetype, "archetype_reason": why,
                   "lowest_beside_face_d": round(lowest - chin, 3),
                   "width_over_face": round(width, 3), "hairline_over_brows_d": round(line, 3),
                   "hair_albedo": [round(float(x), 4) for x in albedo],
                   "eumelanin": round(eu, 3), "pheomelanin": round(pheo, 3), **picked})
    return style, report


def _keep(base: HairStyle) -> dict:
    """The fields a photo's hair does not decide."""
    return {k: getattr(base, k) for k in ("brow_density", "brow_thickness", "brow_arch",
                                          "lash_length", "lash_curl", "beard",
                                          "beard_length", "lod", "seed", "parting")}


def _features(px: np.ndarray, grey: bool) -> np.ndarray:
    """(n, 1 or 3) colour features of linear RGB pixels (n, 3): log luminance, and in a
    colour photo the r and b shares of r + g + b."""
    logl = np.log(np.maximum(px @ LUMA, 1e-4))[:, None]
    if grey:
        return logl
    total = np.maximum(px.sum(-1, keepdims=True), 1e-6)
    return np.concatenate([logl, px[:, :1] / total, px[:, 2:] / total], 1)


def colour_pixels(photo: np.ndarray, hair: np.ndarray, skin: np.ndarray | None
                  ) -> tuple[np.ndarray, int]:
    """((H, W) bool, how many skin-like pixels were left out): the hair mask's pixels the
    hair's colour is read from: without the parts joined to the face's skin mask that lie
    within :data:`SKIN_LIKE_SPREADS` of its colour in every feature (where at least
    :data:`MIN_HAIR_SHARE` of the mask remains), and without the brightest 15 %
    (highlights)."""
    from scipy import ndimage

    photo = np.asarray(photo, np.float64)
    hair = np.asarray(hair, bool)
    keep = hair.copy()
    left_out = 0
    if skin is not None and skin.sum() > 50 and hair.any():
        grey = bool(np.ptp(photo[hair], axis=1).max() < 1e-6)
        fs = _features(photo[skin], grey)
        mu = np.median(fs, 0)
        spread = np.maximum(1.4826 * np.median(np.abs(fs - mu), 0),
                            FEATURE_FLOOR[:fs.shape[1]])
        like = np.zeros_like(hair)
        like[hair] = np.all(np.abs(_features(photo[hair], grey) - mu)
                            < SKIN_LIKE_SPREADS * spread, axis=1)
        # only the skin-like parts that join the face's skin (a forehead, the ears): the
        # hair's own highlights of the skin's colour, inside the hair, stay
        lab, _ = ndimage.label(like)
        ids = np.unique(lab[ndimage.binary_dilation(skin, iterations=2) & like])
        like = np.isin(lab, ids[ids > 0])
        if 1.0 - like.sum() / hair.sum() >= MIN_HAIR_SHARE:
            keep &= ~like
            left_out = int(like.sum())
    if keep.any():
        lum = photo[keep] @ LUMA
        keep[keep] = lum <= np.percentile(lum, 85)
    return keep, left_out


def _melanin(photo, hair, skin, skin_albedo) -> tuple[float, float, np.ndarray, dict]:
    keep, left_out = colour_pixels(photo, hair, skin)
    px = np.asarray(photo, np.float64)[keep if keep.any() else np.asarray(hair, bool)]
    colour = np.median(px, axis=0)
    light = np.ones(3)
    if skin is not None and skin.sum() > 50:
        light = np.median(np.asarray(photo, np.float64)[skin], axis=0) / \
            np.maximum(np.asarray(skin_albedo, np.float64), 1e-3)
    albedo = np.clip(colour / np.maximum(light, 1e-4), 0.0, 1.0)
    eu, pheo = albedo_melanin(albedo)
    return eu, pheo, albedo, {"colour_pixels": int(keep.sum()), "skin_like_left_out": left_out}
