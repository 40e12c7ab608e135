"""The fit's ``final`` section (:class:`FinalConfig`): the photo-size renders, the bake
and the parts', the hair layer of ``render.png``. Split from ``fit/config.py`` (which
re-exports it) for its length; loaded and merged there as every section."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hack_render.errors import HackError


@dataclass
class FinalConfig:
    """After the stages: the fit re-rendered at the photo's size (``render.png``) and the
    photo(s) baked into a per-texel diffuse map (``texture.py``)."""

    # false: no render.png and no baked diffuse map (the fitted maps are written as they
    # are), which saves the final stage (~21 s wall of the astronaut's 512 px fit, docs/fit.md)
    enabled: bool = True
    # samples per pixel of render.png (and of the render the bake divides the photo by)
    # without the denoiser (with Intel OIDN, texture.SPP_DENOISED, denoised): more, less
    # noise in the render and the bake, time in proportion (the tests run 8-32)
    spp: int = 256
    # render.png's long side at most (the photo's size below it), the bake's photo pixels
    # too: higher, more of a large photo's detail, time and memory ~ pixels
    max_side: int = 1024
    # the baked diffuse map: atlas_height x 2 atlas_height texels: higher, more of the
    # photo's detail kept where its pixels are finer than the texels; memory and bake time
    # ~ texels (the tests run 128-256)
    atlas_height: int = 1024
    # robust rejection of pixels the render cannot explain (occluders, clothes): the log
    # ratio photo / render and the chromaticity beyond this many MADs of the skin's. Higher
    # bakes more of the photo, its shading and highlights too: 5 scored the same view +0.5
    # and +0.2 dB, but a turntable shows that light twice (docs/fit.md)
    reject_sigma: float = 3.0
    # bake the brows, lips and lids (bands about their landmarks) as the photo has them:
    # the skin test and the robust rejection would drop them (their colour is not the
    # skin's), leaving the model's browless mean skin there; what the landmarks misplace is
    # baked too
    features: bool = True
    # passes that bake the photo over the re-render once more (render.png's own light
    # transport, pixel filter and denoiser divided out), each a re-render: 0 bakes against
    # the fitted maps' render only; 2 gained 0.09 dB over 1 (docs/fit.md)
    refine: int = 1
    # the parts that are not skin (the eyes' fronts, whites and tear film, the teeth, gums
    # and tongue) baked from the photo per vertex (fit/part_bake.py): passes, each a
    # re-render of the views; 0: the fitted iris's and whites' colours on the model's
    # pattern (eye_colours), the teeth's and gums' defaults. On six real photos' kept fits
    # the eyes' figure rose 0.9-6.9 dB with 2 passes; with the veil (below, rendered once
    # for the later passes) 4 passes gained another 0.2-1.1 dB over 2, 8 (with part_box)
    # up to 0.3 more (docs/fit.md)
    part_bake: int = 8
    # the part bake's later passes solve each vertex's colour from the render as an affine
    # function of it (fit/part_bake.py): the light a part's colour does not scale (the
    # cornea's and tear film's reflections, the lids' inter-reflections; measured with the
    # parts black, one more render a pass) is taken off the photo first, instead of
    # scaling the colour by photo / render, which leaves a dark iris under a bright
    # reflection too light after two passes. On six real photos' kept fits the eyes rose
    # 0.01-0.24 dB (median 19.72 -> 19.84), the oval 0.00-0.05 (docs/fit.md)
    part_veil: bool = True
    # the part bake's passes before the last (and the veil) render only the box of the
    # parts' pixels (fit/part_bake.py, ``parts_box``: 12 px about them), the last the
    # whole view: a pass costs ~1.2 s instead of ~4.7 s on a 1,024-px photo
    part_box: bool = True
    # after the passes, steps that solve the parts' colours together by bounded least
    # squares against the photo (fit/part_solve.py: the render linear in them, from one
    # more render with them white), each a re-render of the parts' box; 0: the passes'
    # colours. On six real photos' kept fits the eyes' median rose 20.46 -> 21.92 dB with
    # 2 steps, 22.02 with 3; 4 passes before the 3 steps instead of 8 lost up to 0.16 dB
    # (docs/fit.md)
    part_solve: int = 3
    # bake the neck's skin the photo shows below the jaw (hack_render.vision.neck: a
    # looser skin test there, joined to the face's skin; not in grey photos), as the face;
    # off: the neck is the tone-matched A(alpha), the face's colour without its detail
    neck: bool = True
    # the eyes left out of the bake: their landmark rings scaled by this about their
    # centres; with features, the lids' band from bake_weights.LID_INNER to it is baked.
    # Smaller bakes more of the lids and less of the model's eyes (1.0: the astronaut 22.22
    # -> 22.49 dB, the others within 0.01; docs/fit.md)
    eye_hole: float = 1.8
    # the fallback map (A(alpha)) where the photo does not see, tone-matched to the baked
    # skin by a smooth gain field (atlas.tone_matched_prior): "all" (outside the seen
    # face, and the holes it encloses: the lids inside the eyes' rings, the inner lips,
    # the nostrils), "outside" (the scalp, neck and ears only: the holes keep A(alpha),
    # lighter than a dark or shadowed face around them; the cameraman's eyes 21.57 ->
    # 20.53 dB, docs/fit.md) or "off" (A(alpha) as it is: the model's pinker skin meets
    # the bake in a seam)
    tone_match: str = "all"
    # the occluders (hair, hands, glasses) grown by this share of the eyes' outer-corner
    # distance before the bake leaves them out (a fringe's strands and shadow): higher, no
    # dark rim along a fringe, less of the skin baked. 0.08 cost the astronaut's face region
    # 0.4 dB, Grace Hopper's 1.1 dB (docs/fit.md)
    occluder_margin: float = 0.0
    # the shadow the occluders and the hair cast on the skin beside them (a fringe's on
    # the forehead), looked for up to this share of the eyes' outer-corner distance and
    # divided out of the bake (fit/occluder_shadow.py): the hairless render has no such
    # shadow, so baked it is a dark rim along the fringe; 0 bakes it as the photo has it
    # (the same view's PSNR is higher so, a turntable shows the rim: docs/fit.md)
    occluder_shadow: float = 0.1
    # the bake's confidence at its edges faded (min with itself blurred by a Gaussian of this
    # many pixel footprints): the skin meets the fallback softly, not along a jagged edge;
    # wider costs the same view's PSNR (2: the astronaut 19.92 dB, 4: 19.85; docs/fit.md)
    edge_feather: float = 4.0
    # the specular map times a gain per region where the photo's highlights identify it
    # (fit/specular_bake.py), one more render per view. Off: the fitted light's error is
    # read as gloss (docs/fit.md)
    specular: bool = False
    # the iris's and the whites' colours (fit/iris.py) from the render's iris and whites
    # where the photo's own are (MediaPipe's face mesh with its iris landmarks: the pixels
    # of both), else from the render's alone (photo luminance percentiles). Off by
    # default: on the astronaut it took her brown iris to near black, eyes -0.3 dB
    # (docs/fit.md)
    photo_irises: bool = False
    # which pixels the eyes' colours are solved over: "opening", every pixel of the
    # render's iris and whites inside the photo's two lid contours (the face mesh's), none
    # trimmed: the least squares over the openings in sRGB-encoded values, what the eyes'
    # figure scores, the whites down to 0.005 (the eyes' figure: Grace Hopper 15.43 ->
    # 16.51 dB, the astronaut 13.39 -> 13.82, docs/fit.md); where the face mesh finds no
    # face, "pixels": those chosen above (the render's iris and whites, trimmed by
    # luminance percentiles or by the photo's own irises), the default before
    eye_colours: str = "opening"
    # the bake's lid band reaches the photo's own eye openings (the face mesh's lid
    # contours, grown by a pixel) instead of LID_INNER times the 68 points' eye rings:
    # the lid skin the render shows up to the person's opening is baked as the photo has
    # it (the lash line's dark rim); with the eyes' stage closing the lids, that skin
    # would otherwise come from the mirror or A(alpha) (docs/fit.md)
    lids_from_mesh: bool = False
    # the photo's dark mouth corners (a broad smile's inside beside the teeth, in the 68
    # points' inner ring scaled 1.2 or the face mesh's opening) within this share of the
    # inner corners' chord from either corner, where the render shows the model's lips
    # meeting, baked onto the lips as the photo has it (bake_weights.dark_corners); 0:
    # off (the lips' fallback colour there); 0.5: the whole opening
    mouth_corners: float = 0.35
    # thin dark lines over the skin (hair strands, a frame's edge) left out of the bake
    # (bake_weights.thin_dark_lines): those narrower than this share of the eyes'
    # outer-corner distance; 0: off (strands the segmentation misses are baked as streaks)
    strands: float = 0.0
    # render_over_photo.png keeps the photo's hair and occluders (the segmentation's) in
    # front of the render (outputs.photo_layer): the model has no hair, so a fringe is the
    # person's, not the model's bare forehead; render.png is the model alone either way
    photo_hair: bool = True
    # the photo's hair as a style of the hair layer (fit/hair_style.py: archetype, volume,
    # hairline and melanin from the segmentation's hair mask and colour), written to
    # params.json's hair section and rendered in render.png; render_over_photo.png keeps the
    # photo's own hair (photo_hair). Off: render.png is bald, as before
    hair: bool = True
    # the hair's level of detail in render.png (1: >= 50k scalp strands; growing and
    # rendering cost ~ strands)
    hair_lod: float = 0.5
    # the scalp under the hair layer's roots, where the photo did not see the skin (the
    # photo's hair hides it), blended towards the hair's colour by this share at the
    # groom's median root density (fit/scalp.py): no bare, face-coloured crown or parting
    # between the strands of render.png; 0: the fallback skin (A(alpha)) as it is
    scalp_shade: float = 0.8
    # the path depth of render.png's hair layer: its pixels come from a render this deep
    # (the light the strands scatter to each other, which the hair's melanin was
    # calibrated with, bench/hair_albedo.py: at 2, direct light only, the astronaut's
    # golden brown hair rendered dark grey), the skin's from one at the photometric
    # stage's 2 (what the bake assumed; render_over_photo.png's too); 2: one render
    hair_depth: int = 8
    # steps of the hair's colour against the photo, at most (at hair_depth > 2): the
    # photo's hair over render.png's, per channel, scales the albedo; the strands grown
    # again with that melanin and rendered once more each (fit/final.py); 0: none
    hair_colour_steps: int = 2

    def check(self) -> None:
        """HackError naming the first key out of range (``FitConfig.validate``'s part for
        this section)."""
        fc = self
        if not 1 <= fc.spp <= 4096:
            raise HackError(f"config final.spp: expected 1..4096, found {fc.spp}.")
        if not 64 <= fc.atlas_height <= 4096 or not 16 <= fc.max_side <= 8192:
            raise HackError(f"config final: expected atlas_height 64..4096 and max_side "
                            f"16..8192, found {fc.atlas_height} and {fc.max_side}.")
        if isinstance(fc.refine, bool) or not isinstance(fc.refine, int) or not 0 <= fc.refine <= 4:
            raise HackError(f"config final.refine: expected 0..4 passes, found {fc.refine!r}.")
        if isinstance(fc.part_bake, bool) or not isinstance(fc.part_bake, int) \
                or not 0 <= fc.part_bake <= 8:
            raise HackError(f"config final.part_bake: expected 0..8 passes, found "
                            f"{fc.part_bake!r}.")
        if not isinstance(fc.neck, bool):
            raise HackError(f"config final.neck: expected true or false, found {fc.neck!r}.")
        if isinstance(fc.part_solve, bool) or not isinstance(fc.part_solve, int) \
                or not 0 <= fc.part_solve <= 4:
            raise HackError(f"config final.part_solve: expected 0..4 steps, found "
                            f"{fc.part_solve!r}.")
        if not isinstance(fc.part_box, bool):
            raise HackError(f"config final.part_box: expected true or false, found "
                            f"{fc.part_box!r}.")
        if not isinstance(fc.part_veil, bool):
            raise HackError(f"config final.part_veil: expected true or false, found "
                            f"{fc.part_veil!r}.")
        if not (isinstance(fc.eye_hole, (int, float)) and math.isfinite(fc.eye_hole)
                and 0 < fc.eye_hole <= 4):
            raise HackError(f"config final.eye_hole: expected a scale in (0, 4], found "
                            f"{fc.eye_hole!r}.")
        for key, hi, unit in (("edge_feather", 32, "photo pixels' footprints"),
                              ("occluder_shadow", 1, "of the eyes' corner distance"),
                              ("occluder_margin", 1, "of the eyes' corner distance"),
                              ("strands", 0.2, "of the eyes' corner distance"),
                              ("mouth_corners", 0.5, "of the mouth's width"),
                              ("scalp_shade", 1, "of the hair's colour")):
            x = getattr(fc, key)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and 0 <= x <= hi):
                raise HackError(f"config final.{key}: expected 0..{hi} ({unit}), found {x!r}.")
        if isinstance(fc.hair_depth, bool) or not isinstance(fc.hair_depth, int) \
                or not 2 <= fc.hair_depth <= 64:
            raise HackError(f"config final.hair_depth: expected a path depth in 2..64, "
                            f"found {fc.hair_depth!r}.")
        if isinstance(fc.hair_colour_steps, bool) or not isinstance(fc.hair_colour_steps, int) \
                or not 0 <= fc.hair_colour_steps <= 4:
            raise HackError(f"config final.hair_colour_steps: expected 0..4 steps, found "
                            f"{fc.hair_colour_steps!r}.")
        if fc.tone_match not in ("outside", "all", "off"):
            raise HackError(f"config final.tone_match: expected 'outside', 'all' or 'off', "
                            f"found {fc.tone_match!r}.")
