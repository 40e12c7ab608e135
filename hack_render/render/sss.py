"""Subsurface scattering for final renders: the skin's diffuse light diffused in screen
space by a measured skin profile.

Light that enters skin scatters in the dermis and leaves it up to millimetres away, red
light (which blood absorbs least) furthest: shadow edges on skin turn red, pores and
fine wrinkles soften, and the surface stops reading as painted plastic. Path tracing it
volumetrically costs 75x the surface BSDF here (``bench_render.py --only sss``), so final
renders approximate it the way production real-time skin does (Jimenez et al., "Screen-
Space Perceptual Rendering of Human Skin", 2009), with d'Eon and Luebke's sum-of-
Gaussians fit of the three-layer skin profile ("Advanced Techniques for Realistic
Real-Time Skin Rendering", GPU Gems 3, ch. 14, table 14-1):

1. ``HeadScene.render(sss=True)`` (:func:`render_scattered`) renders the skin's diffuse
   light apart: with ``hack_path`` (the default) in the same pass as the image, as an AOV
   of the light whose first scattering event is the skin's diffuse lobe
   (:func:`combine_split`); with the other integrators in two renders, the ``hack_skin``
   BSDF's lobe weights (1, 0), then (0, 1) (the other materials go with both;
   :func:`combine`), same samples per pixel each.
2. The diffuse image is divided by the albedo (:func:`hack_render.render.footprint.sss_features`,
   averaged over each pixel's footprint), so the profile diffuses light, not the
   texture: the albedo is applied after the scattering ("post-scatter texturing").
3. Each Gaussian of the profile is applied in two 1-D passes. The distance between two
   pixels is the 3-D distance between their surface points: their offset at the
   receiving pixel's depth (metres per pixel = depth / focal length in pixels) and their
   depth difference. For a Gaussian, exp(-(dx^2 + dz^2) / 2v) = exp(-dx^2 / 2v)
   exp(-dz^2 / 2v), so the depth term keeps the passes separable, and light does not
   jump a silhouette (the chin to the neck below it, the nose to the cheek). Only skin
   pixels send and receive light; the weights are normalised, so a uniformly lit patch
   stays as it is.
4. The result times the albedo, plus the specular pass on the skin (:func:`combine`);
   other materials (eyes, teeth, lashes, the bust cap) come from the diffuse pass.

What this leaves out: light that crosses thin parts (ears, nostrils' edges) from behind
(no transmission), and the profile is the same for every skin tone (melanin changes it
little: it absorbs in the epidermis, above where the light spreads). Approximations:
the 3-D distance is measured along the pixel grid (a separable blur), and the specular
pass carries the few paths that bounce from one lobe into the other.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError
from hack_render.render.engine import release_parked
from hack_render.render.footprint import sss_features


@dataclass(frozen=True)
class Profile:
    """A radial diffusion profile R(r) = sum_i w_i G(v_i, r), per RGB channel, with
    G(v, r) = exp(-r^2 / 2v) / (2 pi v) the normalised 2-D Gaussian.

    Attributes:
        variances_mm2: (n,) Gaussian variances v_i, mm^2.
        weights: (n, 3) weights w_i per channel; each column sums to 1 (the profile moves
            light, the albedo says how much comes back out).
        source: where the numbers come from.
    """

    variances_mm2: tuple[float, ...]
    weights: tuple[tuple[float, float, float], ...]
    source: str

    def mean_radius_mm(self) -> np.ndarray:
        """(3,) mean distance travelled, mm: sum_i w_i sqrt(pi v_i / 2) per channel."""
        w = np.asarray(self.weights)
        return (w * np.sqrt(np.pi * np.asarray(self.variances_mm2) / 2.0)[:, None]).sum(0)


#: d'Eon & Luebke 2007 (GPU Gems 3, table 14-1): the three-layer skin model's profile
#: (Donner & Jensen 2005) fitted by six Gaussians.
SKIN = Profile(
    variances_mm2=(0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41),
    weights=((0.233, 0.455, 0.649), (0.100, 0.336, 0.344), (0.118, 0.198, 0.0),
             (0.113, 0.007, 0.007), (0.358, 0.004, 0.0), (0.078, 0.0, 0.0)),
    source="d'Eon & Luebke 2007, GPU Gems 3 ch. 14, table 14-1 (three-layer skin)")

#: Gaussians narrower than this (standard deviation, pixels, at the nearest skin) are
#: left out of the blur: they move light by less than a fifth of a pixel.
MIN_SIGMA_PX = 0.2


def combine(diffuse: np.ndarray, specular: np.ndarray, features: dict, focal_px: float,
            profile: Profile = SKIN, scale: float = 1.0) -> np.ndarray:
    """The final RGB (H, W, 3) from the two passes of ``HeadScene.render(sss=True)``:
    the skin's scattered diffuse light (:func:`scatter`), the specular pass on the skin's
    share of each pixel, and the diffuse pass on the rest.

    Other materials render in both passes; the diffuse pass is the one to take them
    from, as it holds the light the skin's diffuse lobe reflects onto them (the eyes'
    pixels: within 0.6 % of a one-pass render, against 9 % darker from the specular
    pass; skin pixels 0.5 % darker, the paths that bounce from one lobe into the other;
    pixels mixing skin and lashes ~8 % brighter: the lashes' own light is in both).

    Args:
        diffuse, specular: (H, W, 3) the passes (premultiplied, linear).
        features: :func:`hack_render.render.footprint.sss_features` of the same view.
        focal_px, profile, scale: see :func:`scatter`.
    """
    a, sa, m = features["albedo"], features["skin_albedo"], features["skin"]
    unscattered = sa * np.where(a > 1e-4, diffuse / np.maximum(a, 1e-4), 0.0)
    scattered = scatter(diffuse, a, sa, m, features["depth"], focal_px, profile, scale)
    m = np.clip(m, 0.0, 1.0)[..., None]
    return (scattered + m * specular + np.maximum(diffuse - unscattered, 0.0)).astype(
        np.float32)


def combine_split(total: np.ndarray, skin_diffuse: np.ndarray, features: dict,
                  focal_px: float, profile: Profile = SKIN, scale: float = 1.0) -> np.ndarray:
    """The final RGB (H, W, 3) from one ``hack_path`` render with its skin split
    (``render/integrator.py``): ``total`` (H, W, 3), the image, less the skin's diffuse
    light ``skin_diffuse`` (H, W, 3, its AOV), plus that light scattered (:func:`scatter`,
    its irradiance taken over the skin's own albedo). Light the scattering cannot carry
    (skin albedo under 1e-4) is kept as it was."""
    sa = features["skin_albedo"]
    d = np.asarray(skin_diffuse, np.float32)
    scattered = scatter(d, sa, sa, features["skin"], features["depth"], focal_px, profile,
                        scale)
    kept = np.where(sa > 1e-4, 0.0, d)
    return (np.asarray(total, np.float32) - d + scattered + kept).astype(np.float32)


def scatter(diffuse: np.ndarray, albedo: np.ndarray, skin_albedo: np.ndarray,
            skin: np.ndarray, depth: np.ndarray, focal_px: float,
            profile: Profile = SKIN, scale: float = 1.0) -> np.ndarray:
    """The skin's diffuse light after scattering (steps 2-4 of the module docstring):
    (H, W, 3), the skin's share of each pixel only (0 where no skin is seen), to add to
    the specular pass, which carries every other material.

    Args:
        diffuse: (H, W, 3) the skin's diffuse pass (premultiplied, linear; pixels of
            other materials are ignored).
        albedo: (H, W, 3) albedo of whatever each pixel sees, averaged over its footprint
            (0 for misses), as the diffuse pass saw it.
        skin_albedo: (H, W, 3) the same with only the skin's hits counted.
        skin: (H, W) fraction of the pixel's footprint on skin.
        depth: (H, W) distance to the skin seen in the pixel, metres (any value where
            ``skin`` is 0).
        focal_px: the camera's focal length, pixels.
        profile: the diffusion profile.
        scale: multiplies the profile's radii (1: skin as measured).
    """
    diffuse = np.asarray(diffuse, np.float32)
    h, w = skin.shape
    for name, a in (("diffuse", diffuse), ("albedo", albedo), ("skin_albedo", skin_albedo)):
        if a.shape != (h, w, 3):
            raise HackError(f"sss: expected {name} of shape {(h, w, 3)}, found {a.shape}.")
    if depth.shape != (h, w):
        raise HackError(f"sss: expected depth of shape {(h, w)}, found {depth.shape}.")
    if not (focal_px > 0 and scale >= 0):
        raise HackError(f"sss: expected a positive focal length and scale >= 0, found "
                        f"{focal_px}, {scale}.")
    m = np.clip(skin, 0.0, 1.0).astype(np.float32)
    irr_all = np.where(albedo > 1e-4, diffuse / np.maximum(albedo, 1e-4), 0.0)
    res = (skin_albedo * irr_all).astype(np.float32)  # the skin's light, unscattered
    if scale == 0 or not (m > 0).any():
        return res
    ys, xs = np.nonzero(m > 0)
    pad = 2  # keep a margin so the crop's edge is not skin
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    win = (slice(y0, y1), slice(x0, x1))
    mw = m[win]
    z = np.where(mw > 0, depth[win], 0.0).astype(np.float32)
    px = z / np.float32(focal_px)  # metres per pixel at each pixel's depth
    irr = irr_all[win].astype(np.float32)
    out = np.zeros_like(irr)
    px_min = float(px[mw > 0].min())
    for v_mm2, wts in zip(profile.variances_mm2, profile.weights, strict=True):
        wts = np.asarray(wts, np.float32)
        if not wts.any():
            continue
        var = np.float32(v_mm2 * 1e-6 * scale ** 2)  # m^2
        radius = int(np.ceil(3.0 * np.sqrt(var) / px_min))
        if np.sqrt(var) / px_min < MIN_SIGMA_PX:
            out += wts * irr
            continue
        b = _gauss_pass(irr, mw, z, px, var, radius, axis=1)
        b = _gauss_pass(b, mw, z, px, var, radius, axis=0)
        out += wts * b
    res[win] = skin_albedo[win] * out
    return res


def _gauss_pass(img, m, z, px, var, radius, axis):
    """One 1-D pass of a Gaussian of variance ``var`` (m^2) over the 3-D distance between
    skin pixels along ``axis``, normalised by the weights received."""
    num = img * m[..., None]
    den = m.copy()
    n = img.shape[axis]
    inv = np.float32(-0.5) / var
    for k in range(1, min(radius, n - 1) + 1):
        base = np.exp(inv * (k * px) ** 2)
        for sign in (1, -1):
            src = _shift(slice(k, None) if sign > 0 else slice(None, -k), axis)
            dst = _shift(slice(None, -k) if sign > 0 else slice(k, None), axis)
            wgt = base[dst] * m[src] * np.exp(inv * (z[src] - z[dst]) ** 2)
            num[dst] += wgt[..., None] * img[src]
            den[dst] += wgt
    return np.where(den[..., None] > 0, num / np.maximum(den, 1e-12)[..., None], img)


def _shift(s: slice, axis: int):
    return (slice(None), s) if axis == 1 else (s, slice(None))


# --- the skin's passes of a HeadScene ----------------------------------------------------
def render_scattered(head, base: int, progress: bool = False) -> np.ndarray:
    """``head`` (a :class:`hack_render.render.scene.HeadScene`) rendered with subsurface
    scattering in the skin, premultiplied (H, W, 4): ``hack_path``'s one-pass skin split
    (:func:`combine_split`), else the two lobe passes (:func:`combine`); seeds from
    ``base`` as ``HeadScene.render``'s."""
    focal = float(head.camera.K[0, 0])
    if head.integrator_name == "hack_path":  # one pass, the skin's diffuse as an AOV
        img = head.render_passes(base, progress, integrator=split_integrator(head))
        f = sss_features(head, head.skin_bsdf, head.see_through_cards)
        out = img[..., :4].copy()
        out[..., :3] = combine_split(img[..., :3], img[..., 4:7], f, focal)
        return out
    diffuse, rest = lobe_passes(head, base, progress)
    f = sss_features(head, head.skin_bsdf, head.see_through_cards)
    out = diffuse.copy()
    out[..., :3] = combine(diffuse[..., :3], rest[..., :3], f, focal)
    return out


def set_lobe_weights(head, diffuse: float, specular: float) -> None:
    """Weight ``head``'s skin material's diffuse and specular lobes (1, 1: the material
    as it is; a lobe weighted 0 is neither evaluated nor sampled). No recompilation."""
    import drjit as dr
    import mitsuba as mi

    if head.skin_bsdf is None:
        raise HackError("lobe weights: this scene's skin is not the hack_skin material "
                        "(a JIT variant's); found the scalar variant's stand-in.")
    w = (mi.Float(float(diffuse)), mi.Float(float(specular)))
    dr.make_opaque(*w)
    head.skin_bsdf.lobe_weights = w


def lobe_passes(head, seed: int | None = None,
                progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The two passes of ``render(sss=True)`` with ``volpath`` or ``path``, premultiplied
    (H, W, 4) each: the skin's diffuse lobe alone, then its specular lobe alone (other
    materials in both); the lobe weights are restored afterwards."""
    release_parked()
    base = head.settings.seed if seed is None else int(seed)
    try:
        set_lobe_weights(head, 1.0, 0.0)
        diffuse = head.render_passes(base, progress, "render passes (skin diffuse)")
        set_lobe_weights(head, 0.0, 1.0)
        rest = head.render_passes(base, progress, "render passes (specular, rest)")
    finally:
        set_lobe_weights(head, 1.0, 1.0)
    return diffuse, rest


#: each scene's split integrator, made once (dropped with the scene)
_SPLIT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def split_integrator(head):
    """``head``'s ``hack_path`` with the skin split (AOVs skin_diffuse.RGB,
    skin_specular.RGB after RGBA; ``render/integrator.py``), made once per scene."""
    if head not in _SPLIT:
        import mitsuba as mi

        integ = mi.load_dict({"type": "hack_path", "hide_emitters": True,
                              "max_depth": head.settings.max_depth, "split_skin": True,
                              **getattr(head, "integrator_extra", {})})
        integ.set_skin(head.skin_bsdf)
        _SPLIT[head] = integ
    return _SPLIT[head]
