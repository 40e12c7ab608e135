"""Dataset labels: the segmentation table, soft per-class masks, landmarks and the larynx peak.

Segmentation (:data:`LABELS`, id = index, stored in ``segmentation.png``): the renderer
reports a coarse region per hit (``render.parts.REGIONS``: skin of the face / back atlas
tile, mouth, teeth, sclera, iris, lacrimal film, lashes) and the model UV of the hit. Skin
hits are refined by looking their UV up in a label atlas built once from the appearance
layer's geometric region labels (``appearance.regions.region_labels``): lips, brows,
scalp, ears, neck; everything else on the skin (forehead, lids, nose, cheeks, chin, jaw)
is face skin; the mouth and eye sockets (skin inside the lips and lids) count as
gums/tongue and eyes. The labels are geometric approximations, not painted masks.

Soft masks (``masks.exr``, one channel per label): the fraction of each pixel covered
by each class, from k x k sub-pixel rays. A ray that hits the half-transparent lash cards
gives the lashes their opacity and the surface behind them the rest, so overlaps (eye
under lashes) are not lost. The channels sum to 1 (background included).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from hack_render.errors import HackError

#: Dataset segmentation labels; the id is the index.
LABELS: tuple[str, ...] = ("background", "face_skin", "neck_skin", "scalp", "ears", "lips",
                           "eyebrows", "eyes", "iris", "teeth", "gums_tongue", "eyelashes",
                           "bust_cap")
LABEL_ID = {n: i for i, n in enumerate(LABELS)}
LABEL_DESCRIPTIONS = {
    "background": "no surface",
    "face_skin": "skin of the face: forehead, eyelids, nose, cheeks, philtrum, chin, jaw",
    "neck_skin": "skin below the jaw line: neck, nape, and the top of chest and shoulders",
    "scalp": "skin above the hairline (no hair geometry is rendered)",
    "ears": "pinnae",
    "lips": "red of the lips, inside the outer lip contour",
    "eyebrows": "the brow region (skin; brow hair is not modelled)",
    "eyes": "sclera, lacrimal film, and the eye-socket skin inside the lids",
    "iris": "iris and pupil (visible cornea)",
    "teeth": "teeth",
    "gums_tongue": "gums, tongue and the mouth socket",
    "eyelashes": "eyelash cards (rendered 50 % opaque)",
    "bust_cap": "the matte grey cap closing the cut of the chest and shoulders (not anatomy)",
}
#: Appearance atlas region -> dataset label (sockets are split by vertex group).
_ATLAS_TO_LABEL = {"none": "face_skin", "forehead": "face_skin", "brows": "eyebrows",
                   "eyelids": "face_skin", "nose": "face_skin", "cheeks": "face_skin",
                   "lips": "lips", "upper_lip": "face_skin", "chin": "face_skin",
                   "jaw": "face_skin", "ears": "ears", "scalp": "scalp", "neck": "neck_skin",
                   "sockets": "eyes"}
#: Render region (``parts.REGIONS``) -> dataset label; skin regions use the atlas.
_RENDER_TO_LABEL = {"background": "background", "mouth": "gums_tongue", "teeth": "teeth",
                    "sclera": "eyes", "iris": "iris", "lacrimal": "eyes",
                    "eyelashes": "eyelashes", "bust": "bust_cap"}
SKIN_RENDER_REGIONS = ("face", "back_head")
#: Atlas height of the label lookup (texel ~ 1 mm on the face).
ATLAS_HEIGHT = 256
#: Neck-front window for the larynx peak: half height (m) around the C4-C5 level and
#: half width (m) about the midline. ANATOMY.md: laryngeal prominence at C4-C5.
LARYNX_WINDOW = (0.015, 0.012)


@lru_cache(maxsize=2)
def skin_label_atlas(height: int = ATLAS_HEIGHT) -> np.ndarray:
    """(H, 2H) uint8 dataset label per texel of the skin atlas, filled past the islands."""
    from appearance.regions import REGIONS as ATLAS_REGIONS
    from appearance.regions import region_labels
    from appearance.uv import rasterize_layout
    from hack_render.geometry import load_default_model

    lay = rasterize_layout(height)
    atlas = region_labels(lay)
    lut = np.array([LABEL_ID[_ATLAS_TO_LABEL[n]] for n in ATLAS_REGIONS], np.uint8)
    out = lut[atlas]
    model = load_default_model()
    groups = model.vertex_group.numpy()
    sockets = (atlas == ATLAS_REGIONS.index("sockets")) & lay.mask
    vert = np.clip(lay.vertex[sockets], 0, len(groups) - 1)
    mouth = model.group_names.index("mouth_socket") if "mouth_socket" in model.group_names else -1
    out[sockets] = np.where(groups[vert] == mouth, LABEL_ID["gums_tongue"], LABEL_ID["eyes"])
    return out.ravel()[lay.fill].reshape(out.shape)


def to_labels(region: np.ndarray, uv: np.ndarray, atlas: np.ndarray | None = None) -> np.ndarray:
    """Dataset label ids (H, W) uint8 from render region ids (H, W) and model UVs (H, W, 2)."""
    from hack_render.render.parts import REGIONS

    atlas = skin_label_atlas() if atlas is None else atlas
    h = atlas.shape[0]
    lut = np.zeros(len(REGIONS), np.uint8)
    skin = np.zeros(len(REGIONS), bool)
    for rid, name in enumerate(REGIONS):
        if name in SKIN_RENDER_REGIONS:
            skin[rid] = True
        else:
            lut[rid] = LABEL_ID[_RENDER_TO_LABEL[name]]
    out = lut[region]
    m = skin[region]
    if m.any():
        u, v = uv[..., 0][m], uv[..., 1][m]
        j = np.clip(np.floor(u * h).astype(np.int64), 0, 2 * h - 1)
        i = np.clip(np.floor((1.0 - v) * h).astype(np.int64), 0, h - 1)
        out[m] = atlas[i, j]
    return out


def render_region_labels() -> np.ndarray:
    """Dataset label of each render region (``parts.REGIONS``); skin regions use the atlas."""
    from hack_render.render.parts import REGIONS

    return np.array([0 if n in SKIN_RENDER_REGIONS else LABEL_ID[_RENDER_TO_LABEL[n]]
                     for n in REGIONS], np.uint8)


def label_images(head, k: int, atlas: np.ndarray | None = None):
    """G-buffer, segmentation and soft masks of a head scene's current view, one ray batch.

    Returns:
        (aov, seg, masks): ``aov`` the pixel-centre G-buffer (``render.aov.gbuffer``'s
        keys), ``seg`` (H, W) uint8 labels at the pixel centres, ``masks`` (H, W, L)
        float32 coverage over k x k sub-pixel rays (one-hot ``seg`` for k = 0); a ray that
        meets the lash cards counts EYELASH_OPACITY for the lashes and the rest for what is
        behind them.
    """
    from hack_render.render.materials import EYELASH_OPACITY

    atlas = skin_label_atlas() if atlas is None else atlas
    out = head.label_pass(k, render_region_labels(), atlas, SKIN_RENDER_REGIONS,
                          see_through=("eyelashes",), num_labels=len(LABELS),
                          see_through_opacity=EYELASH_OPACITY)
    seg = out.pop("centre_label")
    masks = out.pop("coverage")
    if k == 0:
        return out, seg, np.eye(len(LABELS), dtype=np.float32)[seg]
    return out, seg, masks


def subpixel_offsets(k: int) -> list[tuple[float, float]]:
    """k x k stratified sub-pixel points; for odd k the pixel centre is one of them."""
    return [((a + 0.5) / k, (b + 0.5) / k) for b in range(k) for a in range(k)]


def soft_masks(head, k: int, atlas: np.ndarray | None = None) -> np.ndarray:
    """(H, W, L) float32 coverage of each label over k x k sub-pixel rays; sums to 1.

    The slow reference of :func:`label_images` (one ray pass per sub-pixel point, labels
    in numpy); the dataset uses :func:`label_images`.
    """
    from hack_render.render.materials import EYELASH_OPACITY

    h, w = head.camera.height, head.camera.width
    n_lab = len(LABELS)
    acc = np.zeros(h * w * n_lab, np.float64)
    base = np.arange(h * w) * n_lab
    for off in subpixel_offsets(k):
        hits = head.region_hits(off, see_through=("eyelashes",))
        front = to_labels(hits["region"], hits["uv"], atlas).ravel()
        lash = front == LABEL_ID["eyelashes"]
        # bincount is the fast scatter-add (np.add.at is several times slower)
        acc += np.bincount(base + front, np.where(lash, EYELASH_OPACITY, 1.0), len(acc))
        if lash.any():
            behind = to_labels(hits["region_behind"], hits["uv_behind"], atlas).ravel()
            acc += np.bincount(base[lash] + behind[lash],
                               np.full(int(lash.sum()), 1.0 - EYELASH_OPACITY), len(acc))
    return (acc / k ** 2).reshape(h, w, n_lab).astype(np.float32)


def larynx_candidates(model) -> np.ndarray:
    """Indices of the neck-front skin vertices near the midline (rest template)."""
    t = model.template.numpy()
    region = model.vertex_region.numpy()
    if "neck" not in model.region_names:
        raise HackError("larynx peak: expected a 'neck' vertex region in the model, found "
                        f"{', '.join(model.region_names)}.")
    neck = region == model.region_names.index("neck")
    joints = model.joints_template.numpy()
    front = t[:, 2] > joints[:, 2].max()
    return np.flatnonzero(neck & front & (np.abs(t[:, 0]) < LARYNX_WINDOW[1]))


def larynx_peak(model, out, tau: float, candidates: np.ndarray | None = None,
                beta=None) -> tuple[int, np.ndarray]:
    """The larynx-peak landmark of one posed sample: (vertex index, posed position (3,)).

    Definition. With a larynx basis (the shipped v2 model): the larynx-region vertex that
    the mean-size larynx of this identity, slid by ``tau``, displaces most,
    ``argmax_j |L(beta, 1, tau)_j|``. It follows ``tau`` (the prominence slides under the
    skin) and does not depend on ``eta`` (which scales the larynx's size, not its place),
    so the label exists even for a flat neck (eta = 0). Without a larynx basis: among the
    midline neck-front skin vertices (|x| < 1.2 cm) whose rest-pose height lies within
    1.5 cm of the C4-C5 joint (the laryngeal prominence's level, ANATOMY.md), the most
    anterior one (largest z) in the sample's rest shape. The landmark is that vertex's
    posed position. ``beta``: the sample's (1, S) identity (zeros when omitted).
    """
    if model.has_larynx:
        import torch

        dt = model.template.dtype
        b = None if beta is None else torch.as_tensor(beta, dtype=dt).reshape(1, -1)
        with torch.no_grad():
            d = model.larynx_displacement(b, tau=torch.tensor([float(tau)], dtype=dt))[0]
        k = int(model.larynx_vertices[int(torch.linalg.norm(d, dim=1).argmax())])
        return k, out.vertices[0, k].detach().numpy().astype(np.float64)
    cand = larynx_candidates(model) if candidates is None else candidates
    rest = out.rest_vertices[0].detach().numpy()
    c45 = out.rest_joints[0, model.joint_names.index("c4-c5")].detach().numpy()
    sel = cand[np.abs(rest[cand, 1] - c45[1]) < LARYNX_WINDOW[0]]
    if not len(sel):
        sel = cand
    k = int(sel[np.argmax(rest[sel, 2])])
    return k, out.vertices[0, k].detach().numpy().astype(np.float64)


def landmark_record(head, cam, landmarks: np.ndarray, joints: np.ndarray,
                    larynx: np.ndarray) -> dict:
    """2D/3D landmarks with in-image and visibility flags for the current camera.

    Returns a JSON-ready dict with ``points_3d`` (world, metres), ``points_cam`` (OpenCV
    camera frame, metres), ``points_2d`` (pixels, K applied: pixel column c spans
    [c, c + 1), so the centre of pixel (0, 0) is (0.5, 0.5); subtract 0.5 for the
    centre-at-integer convention), ``in_image`` and ``visible`` per group.
    """
    groups = (("face68", landmarks), ("joints8", joints), ("larynx_peak", larynx[None]))
    allpts = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for _, p in groups])
    inside_all, vis_all = head.visibility(allpts)  # one ray batch for every point
    out, start = {}, 0
    for name, pts in groups:
        pts = np.asarray(pts, np.float64).reshape(-1, 3)
        sl = slice(start, start + len(pts))
        start += len(pts)
        inside, vis = inside_all[sl], vis_all[sl]
        out[name] = {"points_3d": pts.tolist(),
                     "points_cam": (pts @ cam.R.T + cam.t).tolist(),
                     "points_2d": cam.project(pts).tolist(),
                     "in_image": inside.tolist(), "visible": vis.tolist()}
    return out
