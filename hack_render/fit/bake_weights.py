"""Which photo pixels the bake takes, and what each observes: the albedo behind every
skin pixel of a view, and its weight (:func:`pixel_weights`, used by
:func:`hack_render.fit.texture.bake_diffuse`).

- a pixel is baked where the render shows the skin (regions ``face`` and ``back_head``)
  at full coverage, away from the render's silhouette (:data:`EDGE_PX`), outside the
  eyes' and mouth's holes (:func:`feature_holes`) and the segmentation's occluders, and
  inside its skin;
- it observes the fitted albedo times the ratio photo / render (the render holds the
  same lighting, geometry and BSDF, so shading, shadows and the sheen cancel to first
  order); its weight is the cosine of the view angle, squared (grazing pixels smear);
- robust rejection: where the ratio's log or the observation's chromaticity is far from
  the skin's (occluders the segmentation missed, shadows the render does not have,
  clothes, hair), the pixel is dropped. The brows and lips (:func:`feature_bands`) and
  the lids (the band of :data:`LID_INNER`) are kept as the photo has them.
- thin dark lines (``final.strands``: hair strands across the skin, a frame's edge;
  :func:`thin_dark_lines`) are dropped, on the brows, lips and lids too; round spots
  (moles) and broad shadows stay;
- the skin behind the lash cards' gaps counts (the G-buffer of
  :func:`hack_render.fit.texture.render_at_photo` sees through them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.fit.config import FitConfig
from hack_render.fit.occluder_shadow import occluder_shadow
from hack_render.fit.state import View

SKIN_REGIONS = (1, 2)  # render regions "face" and "back_head" (render.parts.REGIONS)
#: photo pixels dropped inside the render's silhouette (its edge mixes in the background)
EDGE_PX = 2.0

#: The lids' band, baked as the photo has them with the brows and lips (``final.features``):
#: each eye's landmark ring scaled from this to ``final.eye_hole`` about its centre (the
#: opening itself, scale 1, and a margin for the lash line's detection left out).
LID_INNER = 1.1


@dataclass
class PhotoRender:
    """A view rendered through its fitted camera at the photo's size: premultiplied
    linear RGBA (h, w, 4), the G-buffer (``render.aov.gbuffer``; through the lash cards,
    ``through`` marking their pixels, in :func:`~hack_render.fit.texture.render_at_photo`),
    the spp, seconds, and whether it was denoised."""

    rgba: np.ndarray
    gbuffer: dict
    spp: int
    seconds: float
    denoised: bool = False


def photo_at(view: View, h: int, w: int) -> np.ndarray:
    """The view's photo, linear RGB, resampled to (h, w) (a render's size)."""
    from skimage.transform import resize

    photo = view.photo.linear()
    if photo.shape[:2] != (h, w):
        photo = resize(photo, (h, w), order=1, anti_aliasing=True).astype(np.float32)
    return photo


def mask_at(mask, h: int, w: int) -> np.ndarray:
    """A photo-size mask (the segmentation's) as bool at (h, w), nearest neighbour."""
    from skimage.transform import resize

    mk = np.asarray(mask, bool)
    if mk.shape != (h, w):
        mk = resize(mk.astype(np.float32), (h, w), order=0) > 0.5
    return mk


def pixel_weights(view: View, pr: PhotoRender, cfg: FitConfig) -> tuple[np.ndarray, np.ndarray]:
    """(weights (h, w) in [0, 1], albedo observations (h, w, 3)) of one view's pixels:
    skin hits away from the silhouette, cos^2 of the view angle, and robust rejection of
    what the render cannot explain (see the module's docstring)."""
    from scipy.ndimage import binary_dilation, binary_erosion

    fc = cfg.final
    gb, rgba = pr.gbuffer, pr.rgba
    h, w = rgba.shape[:2]
    photo = photo_at(view, h, w)
    rendered = np.isin(gb["segmentation"], SKIN_REGIONS) & (rgba[..., 3] > 0.999)
    points = view.detection.points * (w / view.photo.width)
    # (the render's silhouette and the eyes' and mouth's holes eroded, not the
    # segmentation's masks: their edges are the skin's, a crease or a frame beside it)
    edge = max(1, round(EDGE_PX * w / view.photo.width))
    skin = binary_erosion(rendered & ~feature_holes(points, (h, w), eye_scale=fc.eye_hole),
                          iterations=edge)
    occluded = np.zeros((h, w), bool)
    iod = float(np.linalg.norm(points[45] - points[36]))
    for mask, keep in ((view.skin, True), (view.occluder, False)):
        if mask is not None:  # the segmentation's skin, without its occluders
            mk = mask_at(mask, h, w)
            margin = round(fc.occluder_margin * iod)
            if not keep and margin > 0 and mk.any():  # and the strands at their edge
                mk = binary_dilation(mk, iterations=margin)
            skin &= mk if keep else ~mk
            if not keep:
                occluded = mk
    features = lids = np.zeros((h, w), bool)
    if fc.features:
        hole = feature_holes(points, (h, w), eye_scale=LID_INNER)
        if fc.lids_from_mesh and view.eye_opening is not None:
            # the eyes' hole is the photo's own openings (the face mesh's lid contours)
            # grown by a pixel: the lid skin the render shows up to them is baked, the
            # lash line's dark rim with it
            hole = feature_rings(points, (h, w), LID_INNER)["mouth"] | binary_dilation(
                mask_at(view.eye_opening, h, w), iterations=1)
        inside = binary_erosion(rendered, iterations=edge) & ~occluded & ~hole
        features = feature_bands(points, (h, w)) & inside
        if fc.mouth_corners > 0:   # the dark inside the person's mouth corners (in the
            # 68 points' ring or the face mesh's opening), where the model's lips close:
            # baked onto the lips as the photo has it, up to the model's own opening (its
            # inside is dark too: only the silhouette is eroded)
            opening = (None if view.mouth_opening is None
                       else mask_at(view.mouth_opening, h, w))
            seen = rendered & binary_erosion(rgba[..., 3] > 0.999, iterations=edge) & ~(
                occluded & ~opening if opening is not None else occluded)
            features = features | dark_corners(points, photo, fc.mouth_corners, opening) \
                & seen
        lids = feature_rings(points, (h, w), eye_scale=fc.eye_hole)["eyes"] & inside & ~features
    # cosine between the normal and the direction to the camera (camera frame, z forward)
    f = w / view.photo.width * float(view.focal.detach())
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    d = np.stack([(xx - w / 2) / f, (yy - h / 2) / f, np.ones_like(xx)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cos = np.clip(-(gb["normal"] * d).sum(-1), 0.0, 1.0)
    rgb = rgba[..., :3]
    if view.photo.is_grey:  # no colour in the photo: its luminance over the render's,
        luma = np.array([0.2126, 0.7152, 0.0722], np.float32)   # the skin's colour kept
        ratio = np.repeat(((photo @ luma) / np.maximum(rgb @ luma, 1e-4))[..., None], 3, -1)
    else:
        ratio = photo / np.maximum(rgb, 1e-4)
    lum = rgb.mean(-1)
    ok = skin & (lum > 0.1 * np.median(lum[skin])) if skin.any() else skin
    lr = np.log(np.clip(ratio.mean(-1), 1e-3, 1e3))
    if fc.occluder_shadow > 0:  # the occluders' shadow on the skin beside them divided
        # out (not on the brows and lips: their darkness is theirs)
        casters = occluded | (mask_at(view.hair, h, w) if view.hair is not None else False)
        gain, mixed, _ = occluder_shadow(lr, ok & ~features, casters,
                                         fc.occluder_shadow * iod)
        ratio = ratio * np.exp(-gain)[..., None]
        lr = lr - gain
        ok &= ~mixed
    thin = np.zeros((h, w), bool)
    if fc.strands > 0:   # thin dark lines over the skin (hair strands, a frame's edge)
        thin = thin_dark_lines(lr, ok | features, max(1.0, fc.strands * iod))
        ok &= ~thin
        features = features & ~thin
        lids = lids & ~thin
    obs = gb["albedo"] * ratio
    # robust rejection: the ratio's log far from the skin's median (occluders, shadows the
    # render does not have) or the observation's chromaticity far from the skin's
    ok &= robust_keep(lr, obs, ok, fc.reject_sigma)
    if lids.any() and ok.sum() >= 16:  # the lids' band: not brighter than the skin (the
        # photo's eye white or a glint where the detected ring is off), darker is theirs
        med, tol = _log_ratio_band(lr, ok, fc.reject_sigma)
        features = features | lids & (lr < med + tol)
    ok |= features & (lum > 0.1 * np.median(lum[rendered])) if rendered.any() else features
    wgt = np.where(ok, cos ** 2, 0.0).astype(np.float32)
    return wgt, np.clip(obs, 0.0, 1.0).astype(np.float32)


#: :func:`thin_dark_lines`: how much darker than the skin around it a line is (log ratio
#: photo / render; log 1.6: the skin 1.6 times as bright), and how long beside its width
STRAND_DEPTH = float(np.log(1.6))
STRAND_ELONGATION = 4.0


def thin_dark_lines(lr: np.ndarray, region: np.ndarray, width: float) -> np.ndarray:
    """(h, w) bool: the thin dark lines of ``region`` (hair strands across the skin, a
    frame's edge): where the log ratio photo / render ``lr`` lies :data:`STRAND_DEPTH`
    below its grey closing over a disc of ``width`` px (a line narrower than the disc is
    closed over; a broad shadow or a brow is not), in connected parts at least
    :data:`STRAND_ELONGATION` times as long as ``width`` (a mole or a pore, round, stays),
    grown by one pixel (the line's edge pixels mix it with the skin)."""
    from scipy import ndimage

    if not region.any():
        return np.zeros_like(region)
    r = max(1, int(np.ceil(width)))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = xx ** 2 + yy ** 2 <= r * r
    fill = float(np.median(lr[region]))
    x = np.where(region, lr, fill)
    hat = ndimage.grey_closing(x, footprint=disc) - x
    dark = region & (hat > STRAND_DEPTH)
    labels, n = ndimage.label(dark, structure=np.ones((3, 3)))
    if n == 0:
        return dark
    out = np.zeros_like(dark)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        part = labels[sl] == k
        ys, xs = np.nonzero(part)
        if len(ys) < 3:
            continue
        ev = np.linalg.eigvalsh(np.cov(np.stack([xs, ys]).astype(float)) + 1e-6 * np.eye(2))
        length = 4.0 * np.sqrt(ev[-1])        # a uniform line's length: sqrt(12 var) ~ 3.5 sd
        if length >= STRAND_ELONGATION * width:
            out[sl] |= part
    return ndimage.binary_dilation(out) & region


def feature_rings(points: np.ndarray, shape: tuple[int, int], eye_scale: float = 1.8,
                  mouth_scale: float = 1.2) -> dict[str, np.ndarray]:
    """{"eyes", "mouth"}: (h, w) bool masks of the two eyes' landmark rings scaled
    ``eye_scale`` about their centres and of the inner mouth's ring scaled
    ``mouth_scale`` (68 points; also the real-photo benchmark's eye and mouth parts)."""
    from skimage.draw import polygon

    out = {}
    for name, rings in (("eyes", ((range(36, 42), eye_scale), (range(42, 48), eye_scale))),
                        ("mouth", ((range(60, 68), mouth_scale),))):
        m = np.zeros(shape, bool)
        for ring, k in rings:
            p = points[list(ring)]
            c = p.mean(0)
            p = c + k * (p - c)
            rr, cc = polygon(p[:, 1] - 0.5, p[:, 0] - 0.5, shape)
            m[rr, cc] = True
        out[name] = m
    return out


def feature_holes(points: np.ndarray, shape: tuple[int, int],
                  eye_scale: float = 1.8) -> np.ndarray:
    """(h, w) bool: the eyes (their landmark rings scaled ``eye_scale`` about their
    centres: lashes, lids and the sockets' shadow, which the model's eyes do not match)
    and the mouth's opening (scaled 1.2), left out of the bake."""
    rings = feature_rings(points, shape, eye_scale)
    return rings["eyes"] | rings["mouth"]


#: :func:`dark_corners`: darker than this share of the lips' median luminance (linear; the
#: mouth stage's DARK, 0.55 sRGB-encoded, is 0.27 linear; 0.3 took less of the astronaut's
#: corners, her mouth 19.38 dB against 19.82)
CORNER_DARK = 0.45


def dark_corners(points: np.ndarray, photo: np.ndarray, share: float,
                 opening: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: the photo's dark pixels in the mouth's hole (the inner ring scaled 1.2:
    :func:`feature_rings`; with ``opening``, (h, w) bool, the person's own mouth opening
    too: the face mesh's inner lip contour) within ``share`` of the inner corners' chord
    (points 60 to 64) from either corner: darker than :data:`CORNER_DARK` times the median
    of the photo's lips (the outer lip ring, 48-59, outside the hole). ``photo``: (h, w, 3)
    linear. A broad smile's dark corners (the mouth's inside beside the teeth) where the
    model's lips already meet."""
    from skimage.draw import polygon

    h, w = photo.shape[:2]
    hole = feature_rings(points, (h, w))["mouth"]
    if opening is not None:
        hole = hole | opening
    lum = photo[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    ref = np.zeros((h, w), bool)
    rr, cc = polygon(points[48:60, 1] - 0.5, points[48:60, 0] - 0.5, (h, w))
    ref[rr, cc] = True
    ref &= ~hole
    if ref.sum() < 8 or not hole.any():
        return np.zeros((h, w), bool)
    a, b = points[60], points[64]
    chord = b - a
    n2 = float(chord @ chord)
    if n2 < 1e-6:
        return np.zeros((h, w), bool)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    u = ((xx - a[0]) * chord[0] + (yy - a[1]) * chord[1]) / n2
    near = (u < share) | (u > 1.0 - share)
    return hole & near & (lum < CORNER_DARK * float(np.median(lum[ref])))


def feature_bands(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: the brows (a band from 0.3 above to 0.5 below each brow's five
    points, in units of the brow-to-eye distance, towards the eye) and the lips (the
    outer lip ring), whose colour the bake keeps as the photo has it."""
    from skimage.draw import polygon

    m = np.zeros(shape, bool)
    for brow, eye in ((range(17, 22), range(36, 42)), (range(22, 27), range(42, 48))):
        b = points[list(brow)]
        down = points[list(eye)].mean(0) - b.mean(0)
        d = float(np.linalg.norm(down))
        if d < 1e-6:
            continue
        down /= d
        band = np.r_[b - 0.3 * d * down, (b + 0.5 * d * down)[::-1]]
        rr, cc = polygon(band[:, 1] - 0.5, band[:, 0] - 0.5, shape)
        m[rr, cc] = True
    lips = points[48:60]
    rr, cc = polygon(lips[:, 1] - 0.5, lips[:, 0] - 0.5, shape)
    m[rr, cc] = True
    return m


def _log_ratio_band(lr: np.ndarray, ok: np.ndarray, k: float) -> tuple[float, float]:
    """The skin's log ratio over ``ok``: its median and the rejection's half-width, ``k``
    MADs of it, at least log 1.4."""
    med = float(np.median(lr[ok]))
    mad = 1.4826 * float(np.median(np.abs(lr[ok] - med))) + 1e-3
    return med, max(k * mad, float(np.log(1.4)))


def robust_keep(lr: np.ndarray, obs: np.ndarray, ok: np.ndarray, k: float) -> np.ndarray:
    """(h, w) bool: the pixels of ``ok`` whose log ratio ``lr`` (photo over render) is
    within ``k`` MADs of the skin's median (at least log 1.4), and of those the ones
    whose observation's chromaticity (``obs``) is within ``k`` MADs of theirs (at least
    0.03)."""
    if ok.sum() < 16:
        return ok
    med, tol = _log_ratio_band(lr, ok, k)
    keep = ok & (np.abs(lr - med) < tol)
    if not keep.any():
        return keep
    chroma = obs / np.maximum(obs.sum(-1, keepdims=True), 1e-4)
    cm = np.median(chroma[keep], 0)
    cd = np.linalg.norm(chroma - cm, axis=-1)
    cmad = 1.4826 * np.median(cd[keep]) + 1e-3
    return keep & (cd < max(k * cmad, 0.03))
