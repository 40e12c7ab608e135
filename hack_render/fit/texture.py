"""The person's own skin: the photo(s) baked into the model's skin atlas, and the fit
re-rendered at the photo's size.

:func:`render_at_photo` renders a view through its fitted camera at the photo's own size
(the fitted geometry, skin maps and lighting; ``final.spp`` samples per pixel) with the
G-buffer of the same camera (model UV, normal, albedo and region per pixel).

:func:`bake_diffuse` makes a per-texel diffuse map of ``final.atlas_height`` rows (the
model's UV layout, u in [0, 2] over two tiles, row 0 at v = 1):

- seen texels: every skin pixel of every view, with its weight and the albedo it
  observes (the photo with the fitted lighting divided out), as
  :mod:`hack_render.fit.bake_weights` chooses them; each view's per-pixel weight is
  written out as its occlusion mask. They are splatted into
  the atlas bilinearly and spread by a normalised Gaussian of a quarter of the widest
  footprint in texels of the pixel's band of footprint (:mod:`hack_render.fit.atlas`:
  ``FOOTPRINT_BANDS`` bands, each
  ``FOOTPRINT_STEP`` = sqrt(2) wide, from the median footprint to 16 times it: oblique
  skin and stretched UVs take wider pixels, which a single width left as stripes of
  gaps); a pixel's weight counts for the confidence by its area in median pixels.
- unseen texels: the same texel of the mirrored face (the atlas is left-right symmetric
  within each tile: u -> 1 - u), else the appearance model's A(alpha), tone-matched to
  the baked skin by a smooth gain field (``final.tone_match``,
  :func:`~hack_render.fit.atlas.tone_matched_prior`) so that the face does not end in a
  seam.
- the confidence (H, 2H) in [0, 1]: 1 where the photo(s) saw the texel at full weight,
  half the mirrored confidence where the mirror image fills it, 0 where A(alpha) does;
  held under itself blurred (``final.edge_feather``) so that the bake's edge fades.
- the occluders' and the hair's shadow on the skin beside them is divided out of the
  observations first (:mod:`hack_render.fit.occluder_shadow`, ``final.occluder_shadow``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from hack_render.fit.atlas import atlas_samples, splat, splat_confidence, tone_matched_prior
from hack_render.fit.bake_weights import PhotoRender, pixel_weights
from hack_render.fit.camera import R0
from hack_render.fit.config import FitConfig
from hack_render.fit.state import FitState, View
from hack_render.hair.pose import pose_groom
from hack_render.render import denoise as dn
from hack_render.render.emitters import cropped
from hack_render.render.materials import SkinMaps
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from scenes.cameras import Camera
from scenes.lights import LightRig


@dataclass
class BakedSkin:
    """The baked diffuse map (H, 2H, 3) linear, its confidence (H, 2H) in [0, 1], the
    source of each texel (0: A(alpha), 1: photo, 2: mirrored photo; the larger weight),
    each view's pixel weights (h, w) in [0, 1] (0: not skin, occluded or unseen), and the
    share of the face tile's skin texels seen (confidence > 0.5)."""

    diffuse: np.ndarray
    confidence: np.ndarray
    source: np.ndarray
    pixel_weights: list
    seen_fraction: float


def photo_camera(view: View, width: int | None = None, height: int | None = None):
    """The view's fitted camera at the photo's size (or scaled to ``width`` x ``height``)."""
    ph = view.photo
    w, h = width or ph.width, height or ph.height
    s = w / ph.width
    f = float(view.focal.detach()) * s
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    return Camera(K, R0.numpy().astype(np.float64), view.transl.detach().numpy().astype(np.float64),
                  w, h, f"{ph.name}_photo")


def skin_maps(state: FitState, height: int | None = None):
    """The fitted maps (torch -> numpy SkinMaps), resampled to ``height`` rows."""
    with torch.no_grad():
        m = {k: (x.detach().numpy().astype(np.float32) if x is not None else None)
             for k, x in state.maps().items()}
    if height is not None and m["albedo"].shape[0] != height:
        m = {k: (resize_atlas(x, height) if x is not None else None) for k, x in m.items()}
        if m["normal"] is not None:
            m["normal"] /= np.linalg.norm(m["normal"], axis=-1, keepdims=True).clip(1e-6)
    return SkinMaps(m["albedo"], m["specular"], m["roughness"], m["normal"])


#: the name before issue 62 (tests/synthetic.py, bench/bench_eye_renders.py)
_skin_maps = skin_maps


def resize_atlas(img: np.ndarray, height: int) -> np.ndarray:
    """Bilinear resampling of an (H, 2H, C) atlas to (height, 2 height, C)."""
    from skimage.transform import resize

    return resize(img, (height, 2 * height, img.shape[2]), order=1, mode="edge",
                  anti_aliasing=img.shape[0] > height).astype(np.float32)


#: render.png's (and the bake's render's) denoiser: "auto" (Intel OIDN, the denoise extra,
#: with the render's albedo and normals, where it is installed) or "off"; denoised, the
#: render takes SPP_DENOISED samples instead of final.spp
DENOISE = "auto"
SPP_DENOISED = 64
#: the final renders' path depth: the photometric stage's (direct light)
MAX_DEPTH = 2

#: What the final renders' G-buffer sees through (:func:`render_at_photo`): the lash cards,
#: so that the skin behind their gaps is baked (their first hits hid a band of lid skin
#: around each eye from the bake).
SEE_THROUGH = ("eyelashes",)


def render_at_photo(state: FitState, cfg: FitConfig, view: View, maps=None,
                    spp: int | None = None, max_side: int | None = None,
                    hair=None, max_depth: int = MAX_DEPTH) -> PhotoRender:
    """Render the view through its fitted camera at the photo's size (the long side at
    most ``max_side``): the fitted vertices, ``maps`` (default: the fitted maps), the
    view's lighting, the photometric stage's path depth; ``final.spp`` samples, or
    :data:`SPP_DENOISED` denoised by OIDN where it is installed (:data:`DENOISE`);
    ``hair``: a groom (``hack_render.hair``) rendered with the head; ``max_depth``: the
    path depth (default the photometric stage's, :data:`MAX_DEPTH`)."""
    t0 = time.perf_counter()
    dn = _denoiser() if spp is None and DENOISE == "auto" else None
    denoised = dn is not None
    spp = int(spp or (SPP_DENOISED if denoised else cfg.final.spp))
    head, window = photo_scene(state, cfg, view, maps, spp, max_side, hair, max_depth)
    return _render_head(head, window, cfg, spp, denoised, t0)


def _render_head(head, window, cfg, spp: int, denoised: bool, t0: float) -> PhotoRender:
    """:func:`render_at_photo`'s render of a built scene: the image, its G-buffer,
    denoised where ``denoised``, pasted into the whole image."""
    rgba = head.render(seed=cfg.seed * 1000 + 4242, backdrop=False)
    gb = head.aovs(see_through=SEE_THROUGH)
    if denoised:  # with the renderer's own footprint features (through the lashes)
        rgba = head.denoise(rgba, fallback=True)
    return PhotoRender(_paste(rgba, window), _paste(gb, window), spp,
                       time.perf_counter() - t0, denoised)


class PartRenders:
    """:func:`render_at_photo` of one view's ``box`` (the part bake's passes before the
    last, ``final.part_box``) with the scene kept: a later call with maps that differ in
    the parts' vertex colours alone (``SkinMaps.part_rgb``) changes them in place
    (``HeadScene.set_part_colours``) instead of building the scene again."""

    def __init__(self, state: FitState, cfg: FitConfig, view: View, box):
        self.state, self.cfg, self.view, self.box = state, cfg, view, box
        self.head = self.window = None

    def __call__(self, maps) -> PhotoRender:
        t0 = time.perf_counter()
        denoised = DENOISE == "auto" and _denoiser() is not None
        spp = SPP_DENOISED if denoised else int(self.cfg.final.spp)
        if self.head is None:
            self.head, self.window = photo_scene(self.state, self.cfg, self.view, maps, spp,
                                                 self.cfg.final.max_side, box=self.box)
        else:
            self.head.set_part_colours(maps.part_rgb)
        return _render_head(self.head, self.window, self.cfg, spp, denoised, t0)

    def hits(self) -> dict:
        """The kept scene's G-buffer with each pixel's triangle and hit point
        (``render.aov.gbuffer(hits=True)``, through the lash cards), in the whole image
        (after a first call)."""
        return _paste(self.head.aovs(see_through=SEE_THROUGH, hits=True), self.window)


def render_eye_variants(state: FitState, cfg: FitConfig, view: View, maps, eyes: list,
                        spp: int, max_side: int | None = None) -> list[PhotoRender]:
    """:func:`render_at_photo` (``spp`` samples, not denoised) once per ``eyes`` entry
    (iris, sclera, gloss: as ``maps.iris_rgb``, ``sclera_rgb``, ``eye_gloss``), from one
    scene whose eyes are changed in place (``HeadScene.set_eyes``), with one seed: the
    eye estimates' renders differ by the eyes alone. Each render's G-buffer is the first
    one's (the same geometry), seen through the lash cards (``SEE_THROUGH``): the eye
    behind a card is the eye's pixel too, its radiance still affine in the eye's colours
    (the card's share is in what comes from neither)."""
    t0 = time.perf_counter()
    head, window = photo_scene(state, cfg, view, maps, spp, max_side)
    gb, out = None, []
    for iris, sclera, gloss in eyes:
        head.set_eyes(iris, sclera, gloss)
        rgba = head.render(seed=cfg.seed * 1000 + 4242, backdrop=False)
        gb = gb if gb is not None else _paste(head.aovs(see_through=SEE_THROUGH), window)
        out.append(PhotoRender(_paste(rgba, window), gb, spp, time.perf_counter() - t0))
        t0 = time.perf_counter()
    return out


#: the window rendered of a photo (:func:`photo_scene`): the model's projected box
#: grown by this many pixels (the pixel filter's reach, the lash cards' tips) and by
#: CROP_GROW of its size
CROP_MARGIN_PX = 8
CROP_GROW = 0.02


def photo_scene(state: FitState, cfg: FitConfig, view: View, maps, spp: int,
                 max_side: int | None, hair=None, max_depth: int = MAX_DEPTH, box=None):
    """The HeadScene of :func:`render_at_photo` and the window of the image it renders:
    only the model's projected box (with a margin), where it covers under 90 % of the
    image: (x0, y0, width, height, image width, image height), else None. The rays
    through its pixels are the whole image's (``render.emitters.cropped``); the rest
    of the image is background, so renders and G-buffers are pasted into it
    (:func:`_paste`): a full-length photo renders its head, not its frame. ``box``
    (x0, y0, width, height), clipped to the image: that window instead."""
    ph = view.photo
    s = 1.0 if max_side is None else min(1.0, max_side / max(ph.width, ph.height))
    w, h = max(1, round(ph.width * s)), max(1, round(ph.height * s))
    cam = photo_camera(view, w, h)
    with torch.no_grad():
        verts = state.forward(view).vertices[0].numpy()
        env = view.lighting.env_map().detach().numpy().astype(np.float32)
    window = None
    if box is not None:
        x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
        x1, y1 = min(int(box[0] + box[2]), w), min(int(box[1] + box[3]), h)
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"photo_scene: the box {box} is outside the {w}x{h} image")
        window = (x0, y0, x1 - x0, y1 - y0, w, h)
        cam = cropped(cam, *window[:4])
    else:
        # the box holds the hair's strands too (their posed control points; collisions
        # move them by millimetres)
        extent = verts if hair is None else np.concatenate(
            [verts] + [p.reshape(-1, 3)
                       for p in pose_groom(hair, verts, collide=False).values()])
        front = (extent @ cam.R.T + cam.t)[:, 2] > 1e-3
        if front.all():   # (a vertex behind the camera: no box; the whole image)
            xy = cam.project(extent.astype(np.float64))
            grow = CROP_MARGIN_PX + CROP_GROW * float((xy.max(0) - xy.min(0)).max())
            x0, y0 = np.floor(np.maximum(xy.min(0) - grow, 0)).astype(int)
            x1, y1 = np.ceil(np.minimum(xy.max(0) + grow, (w, h))).astype(int)
            if x1 > x0 and y1 > y0 and (x1 - x0) * (y1 - y0) < 0.9 * w * h:
                window = (int(x0), int(y0), int(x1 - x0), int(y1 - y0), w, h)
                cam = cropped(cam, *window[:4])
    maps = maps if maps is not None else skin_maps(state)
    rig = LightRig(name="fit", env_map=env)
    head = HeadScene(Topology.from_model(state.model), verts, rig, cam,
                     RenderSettings(cam.width, cam.height, spp, int(max_depth), cfg.seed), maps,
                     hair=hair)
    return head, window


def _paste(x, window):
    """A window's render (H', W', C) or G-buffer (a dict of them) in its whole image:
    zeros (the background's values: no coverage, region 0) outside the window."""
    if window is None:
        return x
    if isinstance(x, dict):
        return {k: _paste(v, window) for k, v in x.items()}
    x0, y0, ww, hh, w, h = window
    out = np.zeros((h, w) + x.shape[2:], x.dtype)
    out[y0:y0 + hh, x0:x0 + ww] = x
    return out


def _denoiser():
    """The render package's OIDN denoiser module where it and pyoidn are installed."""
    return dn if dn.available() else None


def _mirror(a: np.ndarray) -> np.ndarray:
    """The atlas mirrored left-right within each of its two tiles (u -> 1 - u)."""
    h = a.shape[0]
    return np.concatenate([a[:, :h][:, ::-1], a[:, h:][:, ::-1]], axis=1)


def bake_diffuse(state: FitState, cfg: FitConfig, renders: list[PhotoRender],
                 prior: np.ndarray | None = None, weights: list | None = None) -> BakedSkin:
    """The per-texel diffuse map from every view's photo and its :func:`render_at_photo`
    (see the module's docstring). ``prior``: the map unseen texels fall back to (default
    A(alpha)); ``weights``: each view's pixel weights (default :func:`pixel_weights`'),
    as the refinement passes of ``fit/final.py`` keep the first bake's."""
    H = int(cfg.final.atlas_height)
    given = weights
    weights, samples = [], []
    for i, (v, pr) in enumerate(zip(state.views, renders)):
        wgt, obs = pixel_weights(v, pr, cfg)
        if given is not None:
            wgt = given[i]
        weights.append(wgt)
        samples.append(atlas_samples(pr, wgt, obs, H))
    obs, dens, fp = splat(samples, H)
    conf = splat_confidence(dens, fp, cfg.final.edge_feather)
    conf_m = _mirror(conf)
    obs_m = _mirror(obs)
    # (a refinement pass's prior, the first bake, is tone-matched already)
    tone = cfg.final.tone_match != "off" and prior is None
    prior = (skin_maps(state, H).diffuse if prior is None else prior).astype(np.float64)
    c1 = conf
    c2 = (1.0 - conf) * conf_m
    c3 = 1.0 - c1 - c2
    if tone:
        photo = (c1[..., None] * obs + c2[..., None] * obs_m) / np.maximum(c1 + c2, 1e-9)[..., None]
        prior = tone_matched_prior(prior, photo, c1 + c2,
                                   inside=cfg.final.tone_match == "all")
    diffuse = c1[..., None] * obs + c2[..., None] * obs_m + c3[..., None] * prior
    source = np.argmax(np.stack([c3, c1, c2]), 0).astype(np.uint8)
    confidence = (c1 + 0.5 * c2).astype(np.float32)
    seen_fraction = face_seen_fraction(state, conf)
    return BakedSkin(np.clip(diffuse, 0.0, 1.0).astype(np.float32), confidence, source,
                     weights, seen_fraction)


def face_seen_fraction(state: FitState, conf: np.ndarray) -> float:
    """The share of the face material's vertices (at their UV) whose texel the photo(s)
    saw (confidence > 0.5)."""
    m = state.model
    names = list(m.material_names)
    if "M_Face" not in names:
        return 0.0
    uvf = m.uv_faces.numpy()[m.face_material.numpy() == names.index("M_Face")]
    uv = m.uvs.numpy()[np.unique(uvf)]
    H = conf.shape[0]
    xi = np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1)
    yi = np.clip(((1.0 - uv[:, 1]) * H).astype(int), 0, H - 1)
    return float((conf[yi, xi] > 0.5).mean())
