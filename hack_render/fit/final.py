"""The fit's final stage, at the photo's size: the views rendered with the fitted maps (the
bake's divisor), the baked skin (``texture.bake_diffuse``), the highlights' gain
(``specular_bake``, with ``final.specular``), the iris's and the eye whites' colours
(``iris.py``), the views re-rendered with the baked maps (``render.png``) and the
refinement passes (``final.refine``). :meth:`hack_render.fit.fitter.Fitter.run` runs it
last (it needs the photometric stage's lighting) and the result carries it
(``FitResult.final``); ``outputs.py`` only writes it."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from hack_render.fit import face_mesh, iris, part_bake, part_solve, scalp, texture
from hack_render.fit.bake_weights import PhotoRender, mask_at, photo_at
from hack_render.fit.hair_style import colour_pixels, hair_style_from_photo
from hack_render.fit.specular_bake import bake_specular
from hack_render.fit.state import FitState
from hack_render.hair.groom import grow_cached
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import HairStyle, albedo_melanin
from hack_render.render.parts import REGIONS


@dataclass
class FinalRenders:
    """What the final stage made: ``fitted`` (the renders with the fitted maps, one per
    view), ``baked`` (:class:`~hack_render.fit.texture.Bake`: the diffuse map, its
    confidence and the per-pixel weights), ``maps`` (the skin maps the renders used:
    baked diffuse, specular, the eyes' colours), ``renders`` (``render.png``'s, one per
    view), ``specular_confidence`` (with ``final.specular``), ``iris`` and ``specular``
    (their reports) and ``report`` (the fit report's ``final`` entry)."""

    fitted: list
    baked: object
    maps: object
    renders: list
    iris: dict
    specular: dict
    specular_confidence: np.ndarray | None = None
    report: dict = field(default_factory=dict)
    #: the photo's hair as a style (``final.hair``; None: off, or no hair segmentation),
    #: the groom rendered and ``render.png``'s renders with it (one per view)
    hair_style: object = None
    hair_renders: list | None = None


def wanted(state: FitState, cfg) -> bool:
    """Whether the final stage runs: ``final.enabled`` and every view has the fitted
    lighting (the photometric stage's); without it the textures are the model's maps."""
    return bool(cfg.final.enabled) and all(v.lighting is not None for v in state.views)


def run(state: FitState, cfg, progress: bool = False) -> FinalRenders:
    """The final stage (the module's docstring) on the state's views."""
    st = state
    specular = cfg.final.specular and not all(v.photo.is_grey for v in st.views)
    bar = tqdm(total=2 * len(st.views) + 2 + int(cfg.final.refine) + int(specular)
               + int(cfg.final.part_bake) + int(cfg.final.part_solve),
               desc="fit final (renders, bake)", unit="step", disable=not progress,
               leave=False)
    t0 = time.perf_counter()
    # the person's eye openings (the face mesh's lid contours): the eyes' colours are
    # solved over them (final.eye_colours) and the bake's lid band reaches them
    # (final.lids_from_mesh); and the mouth's (the teeth the segmentation calls "not
    # skin" are baked there, final.part_bake): one face mesh per view for both
    eyes_wanted = cfg.final.eye_colours == "opening" or cfg.final.lids_from_mesh
    found = (face_mesh.views_openings(st) if eyes_wanted or cfg.final.part_bake
             else [None] * len(st.views))
    for v, f in zip(st.views, found):
        v.eye_opening = f[0] if f is not None and eyes_wanted else None
        v.mouth_opening = f[1] if f is not None and cfg.final.part_bake else None
    opening = [v.eye_opening for v in st.views] if eyes_wanted else None
    fitted = []
    for v in st.views:
        fitted.append(texture.render_at_photo(st, cfg, v, max_side=cfg.final.max_side))
        bar.update()
    baked = texture.bake_diffuse(st, cfg, fitted)
    base = texture.skin_maps(st, cfg.final.atlas_height)
    # the photo's hair as the hair layer (final.hair), and the scalp its roots cover
    # shaded towards its colour where the photo did not see the skin (fit/scalp.py)
    hair_style, groom, hair_report = _hair_style(st, cfg, baked)
    density = (scalp.root_density(st.model, groom, baked.diffuse.shape[0])
               if groom is not None and cfg.final.scalp_shade > 0 else None)

    def shaded(bk) -> np.ndarray:
        if density is None:
            return bk.diffuse
        out, share = scalp.shade_scalp(bk.diffuse, bk.confidence, density,
                                       hair_report["hair_albedo"], cfg.final.scalp_shade)
        hair_report["scalp_shaded_share"] = round(share, 4)
        return out

    spec = base.specular
    spec_report = {"source": "the fitted map (final.specular off)"}
    spec_conf = None
    if specular:  # the highlights' gain (fit/specular_bake.py): a render without specular
        m0 = texture.skin_maps(st)
        m0 = dataclasses.replace(m0, specular=np.zeros_like(m0.specular))
        flat = [texture.render_at_photo(st, cfg, v, maps=m0, max_side=cfg.final.max_side)
                for v in st.views]
        spec, spec_conf, spec_report = bake_specular(st, cfg, fitted, flat,
                                                     baked.pixel_weights, spec)
        bar.update()
    # the person's iris and eye-white colours (fit/iris.py): not under the photo's occluders
    allowed = [None if v.occluder is None else ~np.asarray(v.occluder, bool)
               for v in st.views]
    # and the person's own irises and whites in the photo (the face mesh's iris landmarks)
    person = iris.views_eyes(st) if cfg.final.photo_irises else None
    # or every pixel of the render's eyes inside the photo's lid contours
    rgb, eyes = iris.fit_colour(st, cfg, allowed, person=person,
                                opening=opening if cfg.final.eye_colours == "opening"
                                else None)
    bar.update()
    t1 = time.perf_counter()
    maps = dataclasses.replace(base, diffuse=shaded(baked), specular=spec, iris_rgb=rgb,
                               sclera_rgb=tuple(eyes["sclera_rgb"]),
                               eye_gloss=eyes.get("eye_gloss"))
    renders = []
    for v in st.views:
        renders.append(texture.render_at_photo(st, cfg, v, maps=maps,
                                               max_side=cfg.final.max_side))
        bar.update()
    # refinement: the photo over the re-render, divided out again (what the renderer's
    # lighting, filter and denoiser change in the baked skin is corrected)
    for _ in range(int(cfg.final.refine)):
        baked = texture.bake_diffuse(st, cfg, renders, prior=baked.diffuse,
                                     weights=baked.pixel_weights)
        maps = dataclasses.replace(maps, diffuse=shaded(baked))
        renders = [texture.render_at_photo(st, cfg, v, maps=maps, max_side=cfg.final.max_side)
                   for v in st.views]
        bar.update()
    part_report, veils = None, None
    passes = int(cfg.final.part_bake)
    # the passes before the last render the parts' box alone (final.part_box)
    # (their scenes kept, the parts' colours changed in place: texture.PartRenders)
    shown = [part_bake.parts_box(r) for r in renders]
    boxes = shown if cfg.final.part_box else [None] * len(shown)
    box_renders = [texture.PartRenders(st, cfg, v, b) if b is not None else None
                   for v, b in zip(st.views, boxes)]
    steps = int(cfg.final.part_solve) if passes else 0

    def render_pass(v, br, m, last):
        if br is None or last:
            return texture.render_at_photo(st, cfg, v, maps=m, max_side=cfg.final.max_side)
        return br(m)

    for k in range(passes):  # eyes, teeth, mouth: the photo per vertex
        if veils is None and cfg.final.part_veil and maps.part_rgb:
            # the renders with the parts black: the geometry's and the light's alone, the
            # same in every later pass, so rendered once
            veils = [render_pass(v, br, _coloured(maps, 0.0), False)
                     for v, br in zip(st.views, box_renders)]
        part_rgb, part_report = part_bake.bake_parts(st, cfg, maps, renders, veils)
        if part_rgb is None:
            if k > 0:  # (the last pass's renders were the box's)
                renders = [texture.render_at_photo(st, cfg, v, maps=maps,
                                                   max_side=cfg.final.max_side)
                           for v in st.views]
            steps = 0
            break
        maps = dataclasses.replace(maps, part_rgb=part_rgb)
        renders = [render_pass(v, br, maps, k == passes - 1 and not steps)
                   for v, br in zip(st.views, box_renders)]
        bar.update()
    if steps and maps.part_rgb:  # then all the parts' colours at once (final.part_solve)
        maps, renders, part_report["solve"] = _solve_parts(
            st, cfg, maps, renders, veils, [br if br is not None or b is None
                                            else texture.PartRenders(st, cfg, v, None)
                                            for v, br, b in zip(st.views, box_renders, shown)],
            steps, bar)
    hair_renders = None
    if groom is not None:
        t2 = time.perf_counter()
        hair_renders = []
        for v in st.views:
            pr = texture.render_at_photo(st, cfg, v, maps=maps, max_side=cfg.final.max_side,
                                         hair=groom)
            if cfg.final.hair_depth > texture.MAX_DEPTH:  # the strands' own scattering
                pr = hair_composite(pr, texture.render_at_photo(
                    st, cfg, v, maps=maps, max_side=cfg.final.max_side, hair=groom,
                    max_depth=cfg.final.hair_depth))
            hair_renders.append(pr)
        if cfg.final.hair_depth > texture.MAX_DEPTH:  # the colour against the photo
            hair_style, hair_renders = _colour_steps(st, cfg, maps, hair_style,
                                                     hair_renders, hair_report)
        hair_report["seconds"] = round(hair_report["seconds"] + time.perf_counter() - t2, 2)
    bar.close()
    # photo / render.png over the iris's pixels (luminance; 1: matched)
    eyes["residual"] = iris.residual(st, renders, allowed, person=person)
    eyes["sclera_residual"] = iris.residual(st, renders, allowed, "sclera", person)
    report = {"spp": renders[0].spp, "denoised": renders[0].denoised,
              "atlas_height": cfg.final.atlas_height, "seen_fraction": baked.seen_fraction,
              "bake_s": t1 - t0, "render_s": time.perf_counter() - t1,
              "size": [list(r.rgba.shape[1::-1]) for r in renders],
              "iris": eyes, "specular": spec_report,
              "diffuse": "derived: the photo(s) with the fitted lighting divided out where "
                         "seen (confidence.png)"
                         + (", and the shadow of occluders and hair beside them "
                            f"(final.occluder_shadow {cfg.final.occluder_shadow:g})"
                            if cfg.final.occluder_shadow > 0 else "")
                         + ", the mirrored face or the appearance model A(alpha) elsewhere"
                         + (", the scalp under the hair layer's roots shaded towards the "
                            f"hair's colour (final.scalp_shade {cfg.final.scalp_shade:g})"
                            if density is not None else ""),
              "hair": hair_report, "part_bake": part_report}
    return FinalRenders(fitted, baked, maps, renders, eyes, spec_report, spec_conf, report,
                        hair_style, hair_renders)


def _hair_style(st: FitState, cfg, baked) -> tuple[object, object, dict | None]:
    """(style, groom, report) of the first view's hair (``final.hair``):
    :func:`hack_render.fit.hair_style.hair_style_from_photo` on the segmentation's hair
    and skin, with the baked skin's median albedo where the photo was seen as the skin's
    colour; (None, None, why) without a hair segmentation, (None, None, None) with the
    hair layer off."""
    if not cfg.final.hair:
        return None, None, None
    v0 = st.views[0]
    if v0.hair is None:
        return None, None, {"note": "no hair segmentation (the vision extra): render.png "
                                    "is bald"}
    t0 = time.perf_counter()
    seen = baked.confidence > 0.5
    albedo = np.median((baked.diffuse[seen] if seen.sum() > 100 else
                        baked.diffuse.reshape(-1, 3)), axis=0)
    base = HairStyle(lod=cfg.final.hair_lod, seed=int(cfg.seed))
    style, report = hair_style_from_photo(v0.photo.linear(), np.asarray(v0.hair, bool),
                                          None if v0.skin is None else
                                          np.asarray(v0.skin, bool),
                                          v0.detection.points, albedo, base)
    # the brows the bake holds (final.features: baked as the photo has them) are not
    # drawn again as strands over them in render.png (the style keeps its brows)
    drawn = dataclasses.replace(style, brow_density=0.0) if cfg.final.features else style
    groom = grow_cached(HeadSurface.from_model(st.model), drawn)
    report.update({"strands": groom.num_strands, "lod": style.lod,
                   "seconds": round(time.perf_counter() - t0, 2),
                   "derived": "the hair layer's style read from the photo's hair outline "
                              "and colour (fit/hair_style.py): a starting point, not a fit"})
    return style, groom, report


#: the least hair pixels (the render's strands over the photo's hair colour pixels) for
#: :func:`_colour_steps` to run, and how near the photo's colour (photo over render, per
#: channel) its steps stop
COLOUR_STEP_PIXELS = 200
COLOUR_STEP_DONE = 0.1


def _hair_pixels(view, pr, hair_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(photo, render) median linear RGB over the pixels where both show hair: the render's
    first hits on strands (fully covered) among the photo's hair colour pixels."""
    h, w = pr.rgba.shape[:2]
    m = (mask_at(hair_px, h, w) & (np.asarray(pr.gbuffer["segmentation"]) == REGIONS.index("hair"))
         & (pr.rgba[..., 3] > 0.99))
    if m.sum() < COLOUR_STEP_PIXELS:
        return None, None
    return (np.median(photo_at(view, h, w)[m], axis=0),
            np.median(pr.rgba[..., :3][m].astype(np.float64), axis=0))


def _colour_steps(st: FitState, cfg, maps, style, renders: list, report: dict):
    """Steps of the hair's colour against the photo (``final.hair_colour_steps`` at most):
    the photo's hair colour (its colour pixels, ``hair_style.colour_pixels``) over the
    first view's render of it, per channel, scales the albedo (first the one the colour
    was read as), and the strands are grown again with its melanin and rendered (the
    depth-``hair_depth`` render only: the skin's pixels are the first render's). With
    paths that deep the strands' colour follows their albedo (at depth 2 it did not:
    docs/hair.md). Stops early once every channel is within :data:`COLOUR_STEP_DONE` of
    the photo's, or the melanin no longer changes (the table's bound: a render brighter
    than the darkest hair can be). (style, renders); the report's ``colour_steps``."""
    v0 = st.views[0]
    hair_px, _ = colour_pixels(v0.photo.linear(), np.asarray(v0.hair, bool),
                               None if v0.skin is None else np.asarray(v0.skin, bool))
    albedo = np.asarray(report["hair_albedo"], np.float64)
    photo, render = _hair_pixels(v0, renders[0], hair_px)
    steps: list = []
    report["colour_steps"] = steps
    if photo is None:
        report["colour_steps"] = {"note": f"fewer than {COLOUR_STEP_PIXELS} pixels where the "
                                          "render's strands meet the photo's hair: kept"}
        return style, renders
    for _ in range(int(cfg.final.hair_colour_steps)):
        ratio = photo / np.maximum(render, 1e-6)
        if np.all(np.abs(ratio - 1.0) < COLOUR_STEP_DONE):
            break
        albedo = np.clip(albedo * ratio, 1e-3, 1.0)
        eu, pheo = albedo_melanin(albedo)
        if (eu, pheo) == (style.eumelanin, style.pheomelanin):  # at the table's bound
            break
        style = dataclasses.replace(style, eumelanin=eu, pheomelanin=pheo)
        drawn = dataclasses.replace(style, brow_density=0.0) if cfg.final.features else style
        groom = grow_cached(HeadSurface.from_model(st.model), drawn)
        renders = [hair_composite(pr, texture.render_at_photo(
            st, cfg, v, maps=maps, max_side=cfg.final.max_side, hair=groom,
            max_depth=cfg.final.hair_depth)) for v, pr in zip(st.views, renders)]
        photo, render = _hair_pixels(v0, renders[0], hair_px)
        steps.append({"photo_over_render": [round(float(x), 3) for x in ratio],
                      "albedo": [round(float(x), 4) for x in albedo],
                      "eumelanin": round(eu, 3), "pheomelanin": round(pheo, 3),
                      "photo_over_render_after": None if photo is None else
                      [round(float(x), 3) for x in photo / np.maximum(render, 1e-6)]})
        if photo is None:
            break
    return style, renders


def _coloured(maps, value: float):
    """``maps`` with every baked part's vertex colours ``value`` (0: the veil's render,
    1: the shading's, fit/part_solve.py)."""
    return dataclasses.replace(maps, part_rgb={k: np.full_like(c, value)
                                               for k, c in maps.part_rgb.items()})


def _solve_parts(st, cfg, maps, renders, veils, solvers, steps: int, bar):
    """``final.part_solve``'s steps (fit/part_solve.py) after the part bake's passes:
    (maps, the views' renders, the last as the whole view's, report). ``solvers``: each
    view's :class:`texture.PartRenders` (None: the view shows no part); ``veils``: the
    passes' renders with the parts black (None: rendered here)."""
    t0 = time.perf_counter()
    whites = [None if pr is None else pr(_coloured(maps, 1.0)) for pr in solvers]
    if veils is None:
        veils = [None if pr is None else pr(_coloured(maps, 0.0)) for pr in solvers]
    heads = [pr.head for pr in solvers if pr is not None]
    if not heads:
        return maps, renders, {"steps": [], "note": "no view shows a baked part"}
    layout = part_solve.Layout.of(heads[0])
    rows = [None if pr is None else part_solve.ViewRows(
        v, pr.hits(), pr.head, layout, wh.rgba, vl.rgba, pr.head.settings.pixel_filter)
            for v, pr, wh, vl in zip(st.views, solvers, whites, veils)]
    reports = []
    for k in range(steps):
        part_rgb, rep = part_solve.solve_step(st, maps.part_rgb, rows,
                                              [r.rgba for r in renders], layout)
        reports.append(rep)
        maps = dataclasses.replace(maps, part_rgb=part_rgb)
        renders = [texture.render_at_photo(st, cfg, v, maps=maps, max_side=cfg.final.max_side)
                   if pr is None or k == steps - 1 else pr(maps)
                   for v, pr in zip(st.views, solvers)]
        bar.update()
    return maps, renders, {"steps": reports, "seconds": round(time.perf_counter() - t0, 2)}


def hair_composite(shallow: PhotoRender, deep: PhotoRender) -> PhotoRender:
    """``shallow`` (the photometric stage's path depth: the skin as the bake assumed it)
    with the pixels whose first surface is the hair layer's taken from ``deep`` (a longer
    path: the light the strands scatter to each other, which the hair's melanin
    calibration counts, ``bench/hair_albedo.py``): blended by the share of hair among
    each pixel's 3 x 3 neighbours' first hits (strands are thinner than a pixel), so the
    skin keeps the bake's shading and the hair its colour."""
    from scipy.ndimage import uniform_filter

    hair = (np.asarray(deep.gbuffer["segmentation"]) == REGIONS.index("hair"))
    share = uniform_filter(hair.astype(np.float32), 3, mode="nearest")[..., None]
    rgba = shallow.rgba + share * (deep.rgba - shallow.rgba)
    return PhotoRender(rgba.astype(shallow.rgba.dtype), shallow.gbuffer, shallow.spp,
                       shallow.seconds + deep.seconds, shallow.denoised)
