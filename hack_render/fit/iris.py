"""The person's eyes from the photo(s): the iris's colour, the whites' colour and the
eyes' wet gloss, for the fit's renders and texture folder.

The renderer's iris (``render.materials.iris_vertex_colors``) is one linear RGB colour
``c`` shaped by a fixed pattern (pupil, striations, limbal ring), the eye whites (the
sclera, and the lacrimal film by the same ratio) one colour ``s``, and the eyes' wet
gloss (the whites' coat, the cornea's clearcoat, the iris's own gloss) one share ``g``
of its default. A pixel's radiance is affine in each: ``L = S + c D_i + s D_s + g G``,
``S`` what comes from none of them (the neighbours the pixel filter mixes in). Four
renders with one seed (the defaults, a black iris, black whites, no gloss) give the
three shares; per channel ``c`` and ``s`` then solve one linear least-squares problem
over the pixels below: one step of inverse rendering, exact for this light transport,
with the fitted geometry, camera and lighting held. Which pixels:

- the render's iris, as its G-buffer labels it (region ``iris``, fully covered; seen
  through the lash cards: a pixel behind a card is still affine in ``c``), without
  its pupil and its sclera ring (by the G-buffer's albedo there), and of those the
  photo's pixels between the 10th and 75th percentile of luminance: the brighter quarter
  is where the model's iris falls on her sclera, lids or a catchlight (a gaze or aperture
  the model does not share), the darkest tenth her pupil;
- the render's whites (the sclera shell, the inner eye beyond the limbus), and of those
  the photo's brighter half without the brightest twentieth: where the model's whites
  fall on her iris, lids or lashes the photo is darker, the brightest are catchlights;
- the same pixels of the renders, so that the fit compares like with like.

Why the gloss: the photo cannot tell the light's scale from the skin albedo's, and a fit
may take a bright light and a dark skin; the eyes' fixed colours then glow under that
light. Where the whites come out darker than the default, the light over-lights the
eyes' gloss by as much, so ``g`` is the whites' luminance gain (at most 1), solved in
turn with the colours.

``render.png``'s residuals (photo over render, luminance, the same pixels) are reported.
A grey photo says nothing of the colours: the luminance is matched, the hue kept. Too few
pixels of a part (closed or tiny eyes) keep its default; an iris brighter than
:data:`RGB_BOUNDS` allows keeps the default (the model's iris fell on the photo's
sclera or a glint), one darker is held at the lower bound (the photo's eyes in shadow);
the whites are held within :data:`SCLERA_BOUNDS`. The report says which.
"""

from __future__ import annotations

import numpy as np

from hack_render.fit import face_mesh, texture
from hack_render.fit.bake_weights import mask_at, photo_at
from hack_render.fit.eye_gains import (
    FREE_GLOSS_BELOW,
    SCLERA_BOUNDS,
    SCLERA_BOUNDS_OPENING,
    encoded_gains,
    gains,
)
from hack_render.render.materials import DEFAULT_IRIS_RGB, SCLERA_RGB
from hack_render.render.parts import REGIONS

#: Fewer iris pixels than this (over all views) and the colour is left as it was.
MIN_PIXELS = 8
#: Luminance percentiles of the photo's iris pixels kept (see the module docstring).
KEEP_PERCENTILES = (10.0, 75.0)
#: The iris colour's bounds (linear RGB, per channel): an estimate below is held at the
#: lower one, one above is a failed estimate (the default is kept).
RGB_BOUNDS = (0.005, 0.6)
#: Luminance percentiles of the photo's pixels under the render's eye whites that are kept.
SCLERA_PERCENTILES = (50.0, 95.0)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


#: The person's iris in the photo (:func:`photo_eyes`): the annulus of each iris's radius
#: kept (inside it the pupil, outside the limbus's blur into the whites); the whites are
#: the lids' opening beyond WHITES_BEYOND radii of the iris.
IRIS_ANNULUS = (0.35, 0.9)
WHITES_BEYOND = 1.25
#: The photo's own iris pixels (:func:`photo_eyes`) under the render's iris: luminance
#: percentiles kept (the brightest tenth: catchlights).
PERSON_PERCENTILES = (0.0, 90.0)
def photo_eyes(rgb8: np.ndarray, points: np.ndarray | None = None, shape=None
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """(iris, whites): (H, W) bool masks of the person's irises and eye whites in the
    photo, from the face mesh's iris landmarks (``face_mesh.iris_landmarks``): each iris's
    annulus :data:`IRIS_ANNULUS` of its radius (the mean distance of its four rim points
    from its centre) inside that eye's lid contour (FACEMESH_LEFT_EYE / RIGHT_EYE), and
    the lids' opening beyond :data:`WHITES_BEYOND` radii. ``shape``: at this (H, W)
    instead of the photo's (the points scaled). None where no face is found."""
    from skimage.draw import polygon

    found = face_mesh.mesh_at(rgb8, points, shape)
    if found is None:
        return None
    pts, h, w = found
    iris = np.zeros((h, w), bool)
    whites = np.zeros((h, w), bool)
    # 468-472: the subject's right iris (the photo's left eye ring: FACEMESH_RIGHT_EYE is
    # the subject's right); each iris is matched to the lid ring nearest its centre
    rings = [pts[face_mesh.mesh_loops(n)[0]]
             for n in ("FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE")]
    for c in (468, 473):
        centre = pts[c]
        r = float(np.linalg.norm(pts[c + 1:c + 5] - centre, axis=1).mean())
        lids = min(rings, key=lambda q: float(np.linalg.norm(q.mean(0) - centre)))
        opening = np.zeros((h, w), bool)
        rr, cc = polygon(lids[:, 1] - 0.5, lids[:, 0] - 0.5, (h, w))
        opening[rr, cc] = True
        d = np.full((h, w), np.inf)
        d[rr, cc] = np.hypot(cc + 0.5 - centre[0], rr + 0.5 - centre[1])
        iris |= opening & (d >= IRIS_ANNULUS[0] * r) & (d <= IRIS_ANNULUS[1] * r)
        whites |= opening & (d >= WHITES_BEYOND * r)
    return iris, whites


def iris_mask(gbuffer: dict, rgba: np.ndarray) -> np.ndarray:
    """(h, w) bool: the render's iris proper (no pupil, no sclera ring), fully covered."""
    seg = gbuffer["segmentation"] == REGIONS.index("iris")
    lum = gbuffer["albedo"][..., :3] @ _LUMA
    sclera = float(np.asarray(SCLERA_RGB) @ _LUMA)
    return seg & (rgba[..., 3] > 0.999) & (lum > 0.02) & (lum < 0.6 * sclera)


def kept_pixels(photo: np.ndarray, render, allowed: np.ndarray | None = None,
                person: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: ``render``'s iris pixels (:func:`iris_mask`, within ``allowed``) that
    are the person's iris in the photo too (``person``: :func:`photo_eyes`' iris, at the
    render's size), the brightest tenth (catchlights) left out; where those are fewer than
    :data:`MIN_PIXELS` (or no ``person``), those whose photo luminance lies within
    ``KEEP_PERCENTILES`` (see the module docstring)."""
    m = iris_mask(render.gbuffer, render.rgba)
    if person is not None:
        both = m & person & (True if allowed is None else allowed)
        if both.sum() >= MIN_PIXELS:
            return _kept(both, photo, None, PERSON_PERCENTILES)
    return _kept(m, photo, allowed, KEEP_PERCENTILES)


def sclera_mask(gbuffer: dict, rgba: np.ndarray) -> np.ndarray:
    """(h, w) bool: the render's eye whites (the sclera shell and the inner eye beyond the
    limbus), fully covered."""
    seg = gbuffer["segmentation"]
    lum = gbuffer["albedo"][..., :3] @ _LUMA
    sclera = float(np.asarray(SCLERA_RGB) @ _LUMA)
    white = (seg == REGIONS.index("sclera")) | ((seg == REGIONS.index("iris"))
                                                  & (lum >= 0.6 * sclera))
    return white & (rgba[..., 3] > 0.999)


def _kept(mask: np.ndarray, photo: np.ndarray, allowed, percentiles) -> np.ndarray:
    m = mask if allowed is None else mask & allowed
    if m.any():
        lum = photo[m] @ _LUMA
        lo, hi = np.percentile(lum, percentiles)
        m = m.copy()
        m[m] = (lum >= lo) & (lum <= hi)
    return m


def kept_sclera_pixels(photo: np.ndarray, render, allowed: np.ndarray | None = None,
                       person: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: ``render``'s eye-white pixels (:func:`sclera_mask`, within ``allowed``,
    and within ``person``, the photo's own whites (:func:`photo_eyes`), where that leaves
    :data:`MIN_PIXELS`) whose photo luminance lies within ``SCLERA_PERCENTILES``: the
    brighter half of them (where the model's sclera falls on the person's iris, lids or
    lashes the photo is darker), without the brightest twentieth (catchlights)."""
    m = sclera_mask(render.gbuffer, render.rgba)
    if person is not None:
        both = m & person & (True if allowed is None else allowed)
        if both.sum() >= MIN_PIXELS:
            return _kept(both, photo, None, SCLERA_PERCENTILES)
    return _kept(m, photo, allowed, SCLERA_PERCENTILES)


def _eye_rows(photos, renders, zero_renders, white_renders, matte_renders, allowed,
              person=None, opening=None):
    """The kept iris and eye-white pixels of every view (see :func:`estimate`): (photo,
    the rest, the iris's share, the whites' share, the gloss's share), each (n, 3), the
    two pixel counts and which rows are the iris's (n,). ``opening``: per view the
    photo's eye openings (``face_mesh.opening_masks``' first, or None): where given, every
    pixel of the render's iris and whites inside them, none left out (the solve then minimises the
    squared error over the openings, what the eyes' figure scores)."""
    rows: dict[str, list] = {k: [] for k in ("p", "s", "di", "ds", "dg")}
    n = n_white = 0
    iris_rows, from_person = [], []
    for i, (photo, r, r0) in enumerate(zip(photos, renders, zero_renders)):
        ok = (allowed or [None] * len(photos))[i]
        eyes = (person or [None] * len(photos))[i]
        lids = (opening or [None] * len(photos))[i]
        if lids is not None:
            both = lids & (True if ok is None else ok)
            keep = iris_mask(r.gbuffer, r.rgba) & both
            kw = sclera_mask(r.gbuffer, r.rgba) & both & ~keep if white_renders \
                else np.zeros_like(keep)
            if keep.sum() >= MIN_PIXELS:
                from_person.append(i)
                _rows_of(rows, photo, r, r0, i, keep | kw, white_renders, matte_renders)
                n += int(keep.sum())
                n_white += int(kw.sum())
                iris_rows.append(keep[keep | kw])
                continue
        keep = kept_pixels(photo, r, ok, None if eyes is None else eyes[0])
        if eyes is not None and (iris_mask(r.gbuffer, r.rgba) & eyes[0] & (
                True if ok is None else ok)).sum() >= MIN_PIXELS:
            from_person.append(i)
        kw = kept_sclera_pixels(photo, r, ok, None if eyes is None else eyes[1]) & ~keep \
            if white_renders else np.zeros_like(keep)
        _rows_of(rows, photo, r, r0, i, keep | kw, white_renders, matte_renders)
        n += int(keep.sum())
        n_white += int(kw.sum())
        iris_rows.append(keep[keep | kw])
    arrays = [np.concatenate(rows[k]) if rows[k] else np.zeros((0, 3))
              for k in ("p", "s", "di", "ds", "dg")]
    return arrays, n, n_white, (np.concatenate(iris_rows) if iris_rows
                                else np.zeros(0, bool)), from_person


def _rows_of(rows: dict, photo, r, r0, i: int, m: np.ndarray, white_renders,
             matte_renders) -> None:
    """Append the pixels ``m`` of view ``i`` to ``rows`` (:func:`_eye_rows`)."""
    q, q0 = (x.rgba[..., :3][m].astype(np.float64) for x in (r, r0))
    ds = q - white_renders[i].rgba[..., :3][m] if white_renders else np.zeros_like(q)
    rows["p"].append(photo[m].astype(np.float64))
    rows["s"].append(q0 - ds)          # neither part's diffuse share
    rows["di"].append(q - q0)
    rows["ds"].append(ds)
    rows["dg"].append(q - matte_renders[i].rgba[..., :3][m] if matte_renders
                      else np.zeros_like(q))


def estimate(photos: list[np.ndarray], renders: list, zero_renders: list, current,
             grey: bool = False, allowed: list | None = None, white_renders: list | None = None,
             sclera=None, matte_renders: list | None = None, person: list | None = None,
             opening: list | None = None) -> tuple[tuple[float, float, float], dict]:
    """The iris colour, and with ``white_renders`` the eye whites' too, that make the
    renders match ``photos`` (linear RGB, each at its render's size) over the iris's and
    the whites' pixels (and ``allowed``'s, e.g. not the photo's occluders). ``renders``
    (``bake_weights.PhotoRender``) have the iris colour ``current`` and the sclera colour
    ``sclera`` (default :data:`~hack_render.render.materials.SCLERA_RGB`),
    ``zero_renders`` the same with a black iris, ``white_renders`` with a black sclera
    (and lacrimal film), ``matte_renders`` without the eyes' wet gloss, one seed: the
    differences are each part's own share of a pixel (radiance is affine in each), the
    rest (the neighbours a pixel's filter mixes in) stays. Per channel, the two colour
    gains solve one linear least-squares problem over both parts' pixels (the iris's at
    least 0, the whites' within :data:`SCLERA_BOUNDS`); an iris darker than
    :data:`RGB_BOUNDS` allows is held at its lower bound (the photo's eyes in shadow), one
    brighter keeps the default (the model's iris fell on the photo's sclera, lids or a
    glint). Too few pixels of a part keep its default. Where the whites come out darker than
    the default (the fitted light, whose scale the photo cannot tell from the skin's
    albedo, lights the eyes brighter than the photo's), the same light makes the eyes'
    gloss too bright by as much: with ``matte_renders`` the gloss is scaled by the whites'
    luminance gain (at most 1), solved in turn with the colours, and capped where the
    iris comes out black in a channel (the gloss's veil alone brighter than the photo's
    iris: a broad light over a dark iris; :func:`eye_gains.iris_gloss`). Returns (rgb, report),
    the report with ``sclera_rgb`` (and ``eye_gloss``) where the whites were estimated."""
    current = np.asarray(current, np.float64)
    s0 = np.asarray(SCLERA_RGB if sclera is None else sclera, np.float64)
    whites = white_renders is not None
    rows, n, n_white, iris_rows, from_person = _eye_rows(
        photos, renders, zero_renders, white_renders, matte_renders, allowed, person,
        opening)
    if grey:  # the luminance only: one gain per part for all channels
        rows = [np.repeat((x @ _LUMA)[:, None], 3, 1) for x in rows]
    iris_ok = n >= MIN_PIXELS and bool(np.all(rows[2].sum(0) > 0))
    white_ok = whites and n_white >= MIN_PIXELS and bool(np.all(rows[3].sum(0) > 0))
    tied = bool(matte_renders)
    sb = SCLERA_BOUNDS_OPENING if opening is not None and from_person else SCLERA_BOUNDS
    gain_i, gain_w, gloss = gains(rows, s0, iris_ok, white_ok, tied, not iris_ok, iris_rows,
                                   sb)
    freed = False
    if opening is not None and from_person and iris_ok and white_ok and not grey:
        freed = tied and 1e-6 < gloss < FREE_GLOSS_BELOW
        gain_i, gain_w, gloss = encoded_gains(rows, s0, gain_i, gain_w, gloss, sb,
                                               free_gloss=freed)
    rgb = current * gain_i
    report = {"pixels": n, "start": current.tolist(),
              "pixels_from": ("the render's iris and whites inside the photo's lid "
                              f"contours (the face mesh's), views {from_person}"
                              if from_person and opening is not None else
                              "the photo's irises (the face mesh's iris landmarks) under "
                              f"the render's, views {from_person}" if from_person else
                              "the render's iris (photo luminance percentiles "
                              f"{list(KEEP_PERCENTILES)})")}
    how = "photo (grey: luminance only)" if grey else "photo"
    if not iris_ok:
        report["source"] = f"kept: {n} iris pixels seen (fewer than {MIN_PIXELS})"
        rgb = current
    elif np.any(rgb > RGB_BOUNDS[1]):
        # brighter than any iris: the model's iris on the photo's sclera, lids or a glint;
        # the whites solved again with the iris held
        report["source"] = (f"kept: the estimate {np.round(rgb, 4).tolist()} is beyond "
                            f"{list(RGB_BOUNDS)} (a photo the render's iris cannot explain)")
        rgb = current
        _, gain_w, gloss = gains(rows, s0, iris_ok, white_ok, tied, True, None, sb)
        freed = False
    else:
        # darker than the darkest allowed (the photo's eyes in shadow, or darker than the
        # render's gloss alone): held there
        held = bool(np.any(rgb < RGB_BOUNDS[0]))
        rgb = np.maximum(rgb, RGB_BOUNDS[0])
        report.update(source=how + (f"; held at {RGB_BOUNDS[0]} (the estimate "
                                    f"{np.round(current * gain_i, 4).tolist()})"
                                    if held else ""), rgb=rgb.tolist())
    if whites:
        report.update(sclera_pixels=n_white, sclera_start=s0.tolist())
        if white_ok:
            sc = np.clip(s0 * gain_w, *sb)
            held = np.any(np.isclose(sc, sb[0]) | np.isclose(sc, sb[1]))
            report.update(sclera_rgb=sc.tolist(), sclera_source=how + (
                f"; held within {list(sb)}" if held else ""))
            if tied:
                report["eye_gloss"] = gloss
                report["eye_gloss_source"] = (
                    f"solved with the colours over the lid openings (the whites' tied "
                    f"gloss below {FREE_GLOSS_BELOW})" if freed else
                    "the whites' luminance gain (capped where the iris came out black)")
        else:
            report.update(sclera_rgb=s0.tolist(), sclera_source=(
                f"kept: {n_white} eye-white pixels seen (fewer than {MIN_PIXELS})"))
    return tuple(float(x) for x in rgb), report


def _at_render_size(state, renders: list, allowed: list | None, person: list | None = None,
                    opening: list | None = None):
    """The views' photos, ``allowed`` masks (photo-size, or None), ``person``'s eyes
    (photo-size (iris, whites), or None) and ``opening``'s masks at each render's size
    (the last only where ``opening`` is given)."""
    sizes = [r.rgba.shape[:2] for r in renders]
    photos = [photo_at(v, *hw) for v, hw in zip(state.views, sizes)]
    masks = [None if a is None else mask_at(a, *hw)
             for a, hw in zip(allowed or [None] * len(sizes), sizes)]
    eyes = [None if e is None else (mask_at(e[0], *hw), mask_at(e[1], *hw))
            for e, hw in zip(person or [None] * len(sizes), sizes)]
    if opening is None:
        return photos, masks, eyes
    lids = [None if o is None else mask_at(o, *hw)
            for o, hw in zip(opening, sizes)]
    return photos, masks, eyes, lids


def views_eyes(state) -> list:
    """Per view the person's eyes in its photo (:func:`photo_eyes`: (iris, whites) at the
    photo's size, near the view's detected points), or None where the face mesh finds
    none."""
    return [photo_eyes(v.photo.uint8(), v.detection.points) for v in state.views]


def fit_colour(state, cfg, allowed: list | None = None, spp: int = 16, maps=None,
               whites: bool = True, person: list | None = None,
               opening: list | None = None) -> tuple[tuple[float, float, float], dict]:
    """The iris colour of the state's views (:func:`estimate`), from renders per view at
    the photo's size (at most ``cfg.final.max_side``), ``spp`` samples, one seed: the
    default eyes, a black iris, and (``whites``) a black sclera and eyes without their wet
    gloss, with ``maps`` (default: the fitted skin maps). ``allowed``: per view a
    photo-size bool mask of the pixels it may use, or None; ``person``: per view the
    photo's own (iris, whites) (:func:`views_eyes`), or None; ``opening``: per view the
    photo's eye openings (``face_mesh.views_openings``), or None. The report's
    ``sclera_rgb`` and ``eye_gloss`` are the eye whites' colour and the eyes' gloss."""
    maps = maps if maps is not None else texture.skin_maps(state)
    black = (0.0, 0.0, 0.0)
    variants = [(DEFAULT_IRIS_RGB, SCLERA_RGB, None), (black, SCLERA_RGB, None)]
    if whites:
        variants += [(DEFAULT_IRIS_RGB, black, None), (DEFAULT_IRIS_RGB, SCLERA_RGB, 0.0)]
    per_view = [texture.render_eye_variants(state, cfg, v, maps, variants, spp,
                                            cfg.final.max_side) for v in state.views]
    out = [list(r) for r in zip(*per_view)]       # per variant, the views' renders
    photos, masks, eyes, *lids = _at_render_size(state, out[0], allowed, person, opening)
    grey = all(v.photo.is_grey for v in state.views)
    return estimate(photos, out[0], out[1], DEFAULT_IRIS_RGB, grey, masks,
                    out[2] if whites else None, SCLERA_RGB, out[3] if whites else None,
                    eyes, lids[0] if lids else None)


def residual(state, renders: list, allowed: list | None = None, part: str = "iris",
             person: list | None = None) -> float | None:
    """photo / render luminance over the kept iris (``part="iris"``) or eye-white
    (``"sclera"``) pixels of ``renders`` (the state's views, e.g. ``render.png``'s; 1:
    matched); ``allowed`` and ``person`` as :func:`fit_colour`'s."""
    photos, masks, eyes = _at_render_size(state, renders, allowed, person)
    kept = kept_pixels if part == "iris" else kept_sclera_pixels
    k = 0 if part == "iris" else 1
    num = den = 0.0
    for photo, r, ok, e in zip(photos, renders, masks, eyes):
        keep = kept(photo, r, ok, None if e is None else e[k])
        if keep.sum() >= MIN_PIXELS:
            num += float((photo[keep] @ _LUMA).sum())
            den += float((r.rgba[..., :3][keep] @ _LUMA).sum())
    return num / den if den > 0 else None
