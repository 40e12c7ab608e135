"""The photo baked onto the parts that are not skin (``final.part_bake``): the fronts of
the eyeballs (iris, pupil and the whites about them), the whites' and the tear film's
shells, the teeth, the gums and the tongue.

Each such part then carries one colour per vertex (``SkinMaps.part_rgb``; the eyes'
fronts have 800 vertices an eye, the teeth 4,412). Where a view's camera sees a vertex
(nothing else within :data:`TOLERANCE_M` before it on the ray from the camera; the lash
cards are seen through) and the render shows the part at the vertex's pixel, the photo at the vertex's pixel over the render at that pixel
(the fitted lighting, geometry and BSDF: shading, the lids' and lips' shadows and the
highlights cancel to first order) scales the vertex's colour. So the photo's iris
pattern, the whites' shading under the lids, the lash line where the model's opening is
wider than the person's, the teeth's own colour and the mouth's dark inside are baked,
as the skin's bake does for the skin (``texture.bake_diffuse``). A vertex no view sees
keeps the colour it had (the fitted iris and whites, ``fit/iris.py``; the teeth's and
the gums' defaults). Several views: the mean of the seen ones, weighted by the cosine of
the view angle squared.

Derived data: the colours are the photo's with the fitted lighting divided out, at the
fitted pose, gaze and jaw; another gaze or jaw shows them where they were.
"""

from __future__ import annotations

import numpy as np

from hack_render.fit import texture
from hack_render.fit.bake_weights import mask_at, photo_at
from hack_render.fit.state import FitState
from hack_render.io.image import sample_bilinear
from hack_render.render.materials import VERTEX_COLOUR_PARTS, material_base_colours
from hack_render.render.parts import (
    PART_SPECS,
    PUPIL_RADIUS,
    REGIONS,
    radial_eye_distance,
)

#: the ratio photo / render per vertex held within these (a glint the render has where
#: the photo has none, or the reverse, and the mouth's unlit inside are not colours)
RATIO_RANGE = (0.05, 8.0)
#: visibility: nothing nearer the camera than this before the vertex (metres; the lids
#: and lips are millimetres in front of what they cover)
TOLERANCE_M = 5e-4
def view_samples(state: FitState, cfg, view, maps, render, veil=None) -> dict:
    """One view's samples per part: {name: (the colours rendered (n, 3), the colours the
    vertices would need (n, 3), weights (n,) >= 0; 0: not seen)}. ``render`` is the
    view's :class:`~hack_render.fit.bake_weights.PhotoRender` made with ``maps``;
    ``veil``, where given, the same render with the parts' vertex colours black: the
    light a vertex's colour does not scale (the cornea's reflections above all), which
    :func:`affine_ratio` takes off the photo before the ratio."""
    head, window = texture.photo_scene(state, cfg, view, maps, 1, cfg.final.max_side)
    h, w = render.rgba.shape[:2]
    photo = photo_at(view, h, w)
    rgb, alpha = render.rgba[..., :3], render.rgba[..., 3]
    region = render.gbuffer["segmentation"]
    cam = head.camera
    occ = None if view.occluder is None else np.asarray(view.occluder, bool)
    for opening in (view.eye_opening, view.mouth_opening):
        if occ is not None and opening is not None:
            # not inside the person's own eye and mouth openings (the face mesh's lid and
            # inner lip contours): the segmentation calls much of a shaded or turned eye,
            # and the teeth, "not skin", so "occluder" (on obama's smile 1,684 of the
            # opening's 2,278 pixels, which kept 477 of the 672 teeth vertices facing the
            # camera there from the bake)
            occ = occ & ~(np.asarray(opening, bool) if opening.shape == occ.shape
                          else mask_at(opening, *occ.shape))
    # a part without vertex colours yet renders its material's one colour
    base = material_base_colours(state.model.material_names, maps.iris_rgb, maps.sclera_rgb)
    out = {}
    for name in VERTEX_COLOUR_PARTS:
        if f"{name}.vertex_positions" not in head.params:
            continue   # (a model without this part)
        pos = np.asarray(head.params[f"{name}.vertex_positions"], np.float64).reshape(-1, 3)
        if f"{name}.vertex_color" in head.params:
            cur = np.asarray(head.params[f"{name}.vertex_color"], np.float64).reshape(-1, 3)
        else:
            cur = np.tile(np.asarray(base[PART_SPECS[name][0][0]], np.float64), (len(pos), 1))
        nrm = np.asarray(head.params[f"{name}.vertex_normals"], np.float64).reshape(-1, 3)
        _, seen = head.visibility(pos, tolerance=TOLERANCE_M)
        xy = cam.project(pos)
        if window is not None:
            xy = xy + np.array(window[:2], np.float64)
        col, row = xy[:, 0] - 0.5, xy[:, 1] - 0.5   # (pixel centres at k + 0.5)
        p, r = sample_bilinear(photo, col, row), sample_bilinear(rgb, col, row)
        cover = sample_bilinear(alpha, col, row)
        v0 = None if veil is None else sample_bilinear(veil.rgba[..., :3], col, row)
        ratio = affine_ratio(p, r, v0, view.photo.is_grey)
        to_cam = cam.center[None] - pos
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        cos = np.abs((nrm * to_cam).sum(1))  # (the tear film is two-sided)
        # and the part is what the render shows at the vertex's pixel (the eyes' fronts
        # run on beyond the limbus under the whites' shell, a fraction of a millimetre
        # behind it)
        px = np.clip(xy.astype(int), 0, [w - 1, h - 1])
        shown = region[px[:, 1], px[:, 0]] == REGIONS.index(PART_SPECS[name][1])
        ok = seen & shown & (cover > 0.99)
        if name == "iris":
            ok &= ~pupil(pos, head.eye_axes)
        if occ is not None:  # a hand, a glasses' frame: not the part's colour
            s = occ.shape[1] / w
            ok &= ~occ[np.clip((xy[:, 1] * s).astype(int), 0, occ.shape[0] - 1),
                       np.clip((xy[:, 0] * s).astype(int), 0, occ.shape[1] - 1)]
        out[name] = (cur, np.clip(cur * ratio, 0.0, 1.0), np.where(ok, cos ** 2, 0.0))
    return out


#: the part's own share of the render (render - veil, linear) below which the affine
#: ratio is not taken (the part's colour nearly black: its shading is not measured)
AFFINE_MIN = 2e-3


def affine_ratio(p: np.ndarray, r: np.ndarray, veil: np.ndarray | None,
                 grey: bool = False) -> np.ndarray:
    """(n, 3) factors of the vertices' colours that make the render ``r`` the photo ``p``
    at their pixels ((n, 3) linear RGB each). The render is affine in a vertex's colour:
    ``r = colour * shading + veil``, ``veil`` the render with the colours black. With
    it, the factor is ``(p - veil) / (r - veil)``: exact to first order where the veil is
    bright beside the part (a reflection over a dark iris), where photo / render (the
    factor without it) converges only slowly, leaving the colour too light after the
    passes the bake runs. (The veil blacks every part at once, so the light a neighbour
    part spreads over this one's pixels through the pixel filter, the whites' over an
    iris, counts as this part's own.) Without
    ``veil``, or where the part's own share is under :data:`AFFINE_MIN`: photo / render.
    ``grey``: a photo without colour, one luminance factor for the three channels. Held
    within :data:`RATIO_RANGE` (the affine factor down to 0: the photo darker than the
    veil alone)."""
    def lum(x):
        luma = np.array([0.2126, 0.7152, 0.0722])
        return np.repeat((x @ luma)[:, None], 3, 1)
    if grey:
        p, r, veil = lum(p), lum(r), None if veil is None else lum(veil)
    ratio = np.clip(p / np.maximum(r, 1e-4), *RATIO_RANGE)
    if veil is not None:
        own = r - veil
        ok = own > AFFINE_MIN
        aff = np.clip((p - veil) / np.where(ok, own, 1.0), 0.0, RATIO_RANGE[1])
        ratio = np.where(ok, aff, ratio)
    return ratio


#: :func:`parts_box`'s margin about the parts' pixels: the pixel filter's reach and the
#: denoiser's context (pixels)
BOX_MARGIN_PX = 12


def parts_box(render) -> tuple[int, int, int, int] | None:
    """(x0, y0, width, height): the box of a render's pixels whose first hit is one of the
    baked parts (eyes, teeth, mouth), grown by :data:`BOX_MARGIN_PX`, which the part
    bake's passes before the last render alone (``final.part_box``); None where the
    render shows none of them."""
    region = np.asarray(render.gbuffer["segmentation"])
    ids = [REGIONS.index(PART_SPECS[n][1]) for n in VERTEX_COLOUR_PARTS]
    ys, xs = np.nonzero(np.isin(region, ids))
    if len(xs) == 0:
        return None
    h, w = region.shape
    x0, y0 = max(int(xs.min()) - BOX_MARGIN_PX, 0), max(int(ys.min()) - BOX_MARGIN_PX, 0)
    x1 = min(int(xs.max()) + 1 + BOX_MARGIN_PX, w)
    y1 = min(int(ys.max()) + 1 + BOX_MARGIN_PX, h)
    return x0, y0, x1 - x0, y1 - y0


def pupil(pos: np.ndarray, axes) -> np.ndarray:
    """(n,) bool: the iris part's vertices inside the pupil (``pos`` (n, 3); ``axes``: the
    eyes' optical axes, ``HeadScene.eye_axes``). The pupil is a hole, black whatever the
    photo shows over it (a catchlight of the light on the cornea, which the fitted light
    does not reproduce; the iris blurred into it): the bake leaves it out. Baked, a
    catchlight spread over the pupil's few vertices as a grey-blue pupil (the
    astronaut's)."""
    r, _ = radial_eye_distance(pos, axes)
    return r < PUPIL_RADIUS


def bake_parts(state: FitState, cfg, maps, renders, veils=None) -> tuple[dict | None, dict]:
    """(``part_rgb`` for ``SkinMaps``, report): every view's samples
    (:func:`view_samples`) against its render ``renders[i]`` made with ``maps`` (and
    ``veils[i]``, the same with the parts black, where given), weighted; parts no view
    sees keep their colours. None where the model has none of these parts."""
    acc: dict = {}
    for i, (view, render) in enumerate(zip(state.views, renders)):
        veil = None if veils is None else veils[i]
        for name, (cur, col, wgt) in view_samples(state, cfg, view, maps, render,
                                                  veil).items():
            a = acc.setdefault(name, [cur, np.zeros_like(cur), np.zeros(len(cur))])
            a[1] += col * wgt[:, None]
            a[2] += wgt
    if not acc:
        return None, {"note": "the model has none of the parts baked"}
    out, report = {}, {}
    for name, (cur, total, wsum) in acc.items():
        seen = wsum > 1e-6
        col = cur.copy()
        col[seen] = total[seen] / wsum[seen, None]
        out[name] = col.astype(np.float32)
        report[name] = {"seen_vertices": int(seen.sum()), "vertices": len(col)}
    return out, report
