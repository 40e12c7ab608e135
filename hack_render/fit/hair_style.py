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
  1.25 face widths at the forehead;
- **afro**: hair wider than 2.2 face widths at the forehead, above the brows;
- **volume**: the hair's width at the forehead over the face's: 1.05 -> 0, 1.65 -> 1;
- **hairline**: the lowest hair over the forehead's middle, 0.75 d over the brows -> 0 ...
  1.35 d -> 1 (a fringe reads as a full hairline);
- **colour**: the hair pixels' median linear RGB divided by the light the skin shows
  (the photo's skin over the fitted skin albedo) is the hair's albedo, turned into
  melanin by the renderer's own calibration (:func:`hack_render.hair.style.albedo_melanin`).
  Highlights (the brightest 15 % of hair pixels) are left out.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hack_render.hair.style import HairStyle, albedo_melanin

MIN_HAIR_AREA = 0.25  # in d^2
TOP_OF_HEAD = 0.95  # the mean head's top over the brows, in d (85 mm over 90 mm)
HAIRLINE_FULL, HAIRLINE_RECEDED = 0.75, 1.35
CREW_WIDTH = 1.25  # a crew cut's hair at the forehead, face widths, at most


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
    report: dict = {"hair_pixels": int(len(xs)), "eye_distance_px": round(d, 2)}
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
    eu, pheo, albedo = _melanin(photo, hair, skin, skin_albedo)
    kw = {**_keep(base), "hairline": hairline, "eumelanin": eu, "pheomelanin": pheo}
    if archetype != "afro":
        kw["volume"] = volume
    style = HairStyle.archetype_style(archetype, **kw)
    report.update({"archetype": archetype, "archetype_reason": why,
                   "lowest_beside_face_d": round(lowest - chin, 3),
                   "width_over_face": round(width, 3), "hairline_over_brows_d": round(line, 3),
                   "hair_albedo": [round(float(x), 4) for x in albedo],
                   "eumelanin": round(eu, 3), "pheomelanin": round(pheo, 3)})
    return style, report


def _keep(base: HairStyle) -> dict:
    """The fields a photo's hair does not decide."""
    return {k: getattr(base, k) for k in ("brow_density", "brow_thickness", "brow_arch",
                                          "lash_length", "lash_curl", "beard",
                                          "beard_length", "lod", "seed", "parting")}


def _melanin(photo, hair, skin, skin_albedo) -> tuple[float, float, np.ndarray]:
    px = np.asarray(photo, np.float64)[hair]
    lum = px @ np.array([0.2126, 0.7152, 0.0722])
    px = px[lum <= np.percentile(lum, 85)]
    colour = np.median(px, axis=0)
    light = np.ones(3)
    if skin is not None and skin.sum() > 50:
        light = np.median(np.asarray(photo, np.float64)[skin], axis=0) / \
            np.maximum(np.asarray(skin_albedo, np.float64), 1e-3)
    albedo = np.clip(colour / np.maximum(light, 1e-4), 0.0, 1.0)
    eu, pheo = albedo_melanin(albedo)
    return eu, pheo, albedo
