"""The scalp under the fitted hair layer: the skin the photo's hair hides, shaded by the
hair that covers it.

Where the photo shows hair, the bake does not see the scalp, so its texels take the
fallback skin (``atlas.tone_matched_prior``: A(alpha) in the face's tone), and between
the hair layer's strands ``render.png`` showed a bare, face-coloured scalp: a peach crown
under a dark crew cut, a light line along the parting. Real hair hides the scalp and
shades it; a groom's scalp texture is painted in the hair's colour for the same reason.
Here the fallback skin under the roots of the hair layer's scalp strands (their density
in the atlas, :func:`root_density`) is blended towards the hair's albedo
(:func:`shade_scalp`): by ``strength`` where the roots are as dense as the groom's
median texel, less at the hairline, not at all where the photo saw the skin (the bake's
confidence) or where no strand is rooted. Derived, not measured: the report says so
(``final.diffuse``; ``final.hair.scalp_shaded_share``, the atlas's share changed).
"""

from __future__ import annotations

import numpy as np

#: the roots' density is smoothed over this share of the atlas's height (a few strands'
#: spacing at lod 0.5: the hairline fades over it instead of ending in a dotted edge)
DENSITY_SIGMA = 0.006


def root_density(model, groom, height: int, group: str = "scalp") -> np.ndarray:
    """(H, 2H) float32 in [0, 1]: the density of ``groom``'s ``group`` roots over the
    skin atlas (u in [0, 2], row 0 at v = 1), smoothed by :data:`DENSITY_SIGMA`, over
    its median where roots are (1: as dense as the groom's typical texel)."""
    from scipy.ndimage import gaussian_filter

    H = int(height)
    out = np.zeros((H, 2 * H), np.float64)
    groups = [g for g in groom.groups if g.name == group]
    if not groups or len(groups[0].tri) == 0:
        return out.astype(np.float32)
    g = groups[0]
    uvf = np.asarray(model.uv_faces)[np.asarray(g.tri)]
    uv = (np.asarray(model.uvs, np.float64)[uvf] * np.asarray(g.bary)[..., None]).sum(1)
    xi = np.clip((uv[:, 0] * H).astype(int), 0, 2 * H - 1)
    yi = np.clip(((1.0 - uv[:, 1]) * H).astype(int), 0, H - 1)
    np.add.at(out, (yi, xi), 1.0)
    out = gaussian_filter(out, max(DENSITY_SIGMA * H, 0.5), mode="constant")
    rooted = out[yi, xi]
    return np.clip(out / max(float(np.median(rooted)), 1e-12), 0.0, 1.0).astype(np.float32)


def shade_scalp(diffuse: np.ndarray, confidence: np.ndarray, density: np.ndarray,
                albedo, strength: float) -> tuple[np.ndarray, float]:
    """(``diffuse`` with its unseen texels under the roots blended towards ``albedo``
    (linear RGB) by ``strength`` x density x (1 - confidence), the share of the atlas's
    texels changed by more than 1 %)."""
    w = (float(strength) * np.clip(density, 0.0, 1.0)
         * (1.0 - np.clip(confidence, 0.0, 1.0)))[..., None].astype(np.float32)
    hair = np.asarray(albedo, np.float32).reshape(1, 1, 3)
    out = diffuse * (1.0 - w) + hair * w
    return out.astype(diffuse.dtype), float((w[..., 0] > 0.01).mean())
