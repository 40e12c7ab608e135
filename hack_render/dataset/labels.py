"""Dataset labels: the segmentation table, soft per-class masks, landmarks and the larynx peak.

Segmentation (:data:`LABELS`, id = index, stored in ``segmentation.png``): the renderer
reports a coarse region per hit (``render.parts.REGIONS``: skin of the face / back atlas
tile, mouth, teeth, sclera, iris, lacrimal film, lashes, and, where the scene has a groom,
``hair``: every strand of scalp hair, brows, lashes and beard) and the model UV of the
hit. Skin
hits are refined by looking their UV up in a label atlas built once from the appearance
layer's geometric region labels (``appearance.regions.region_labels``): lips, brows,
scalp, neck; everything else on the skin (forehead, lids, nose, cheeks, chin, jaw) is
face skin; the mouth and eye sockets (skin inside the lips and lids) count as
gums/tongue and eyes. The atlas corrects three of those regions for the labels only
(:func:`skin_label_atlas`; the appearance model's regions stay as they are): the ears are
the pinnae themselves (:func:`pinna_texels`; the appearance ``ears`` box is the head skin
behind the ear), the socket rims are socket, and the face tile's neck is the throat's
region alone (no spot on the jaw). The labels are geometric approximations, not painted
masks.

Soft masks (``masks.exr``, one channel per label): the fraction of each pixel covered
by each class, from k x k sub-pixel rays. A ray that hits the see-through lash cards
gives the lashes the cards' opacity at the hit (the renderer's procedural strand texture)
and the surface behind them the rest, so overlaps (eye under lashes) are not lost. The
channels sum to 1 (background included).
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

import appearance
from appearance.regions import LANDMARK_VERTICES, SOCKET_VERTICES, hairline_y, nape_y, region_labels
from appearance.regions import REGIONS as ATLAS_REGIONS
from appearance.uv import TEMPLATE_FILE, default_template, rasterize_layout
from hack_render.errors import HackError
from hack_render.geometry import default_model_path, load_default_model
from hack_render.io import atomic_path
from hack_render.render.parts import REGIONS

#: Dataset segmentation labels; the id is the index.
LABELS: tuple[str, ...] = ("background", "face_skin", "neck_skin", "scalp", "ears", "lips",
                           "eyebrows", "eyes", "iris", "teeth", "gums_tongue", "eyelashes",
                           "bust_cap", "hair")
LABEL_ID = {n: i for i, n in enumerate(LABELS)}
LABEL_DESCRIPTIONS = {
    "background": "no surface",
    "face_skin": "skin of the face: forehead, eyelids, nose, cheeks, philtrum, chin, jaw",
    "neck_skin": "skin below the jaw line: neck, nape, and the top of chest and shoulders",
    "scalp": "skin above the hairline (under the hair where the sample has some)",
    "ears": "pinnae, outer and cranial sides (tragus and lobe included)",
    "lips": "red of the lips, inside the outer lip contour",
    "eyebrows": "the brow region's skin (the brow hairs on it are 'hair')",
    "eyes": "sclera, lacrimal film, and the eye-socket skin inside the lids",
    "iris": "iris and pupil (visible cornea)",
    "teeth": "teeth",
    "gums_tongue": "gums, tongue and the mouth socket",
    "eyelashes": "eyelash cards, weighted by their strand opacity",
    "bust_cap": "the matte grey cap closing the cut of the chest and shoulders (not anatomy)",
    "hair": "hair strands: scalp hair, brows, lashes and beard (the hair layer's curves), "
            "its soft mask the strands' coverage",
}
#: Appearance atlas region -> dataset label, before :func:`skin_label_atlas`'s corrections
#: (the ``ears`` box is replaced by the pinna, the sockets are split by vertex group).
_ATLAS_TO_LABEL = {"none": "face_skin", "forehead": "face_skin", "brows": "eyebrows",
                   "eyelids": "face_skin", "nose": "face_skin", "cheeks": "face_skin",
                   "lips": "lips", "upper_lip": "face_skin", "chin": "face_skin",
                   "jaw": "face_skin", "ears": "ears", "scalp": "scalp", "neck": "neck_skin",
                   "sockets": "eyes"}
#: Render region (``parts.REGIONS``) -> dataset label; skin regions use the atlas.
_RENDER_TO_LABEL = {"background": "background", "mouth": "gums_tongue", "teeth": "teeth",
                    "sclera": "eyes", "iris": "iris", "lacrimal": "eyes",
                    "eyelashes": "eyelashes", "bust": "bust_cap", "hair": "hair"}
SKIN_RENDER_REGIONS = ("face", "back_head")
#: Atlas height of the label lookup (texel ~ 1 mm on the face).
ATLAS_HEIGHT = 256
#: ICT-FaceKit's ear patches, template vertex ids (inclusive): left ear (x > 0), right
#: ear. Each is the run of face-group vertices at |x| > 6 cm (the neighbouring ids are
#: elsewhere on the face): the pinna's outer side and about 1 cm of cheek in front of it.
EAR_VERTICES = ((6706, 7432), (7433, 8167))
#: The pinna's outline (:func:`pinna_texels`) is spanned by the patch vertices that stand
#: out from the pre-auricular skin's surface by more than this (cm), and grown by
#: :data:`PINNA_MARGIN` (cm).
PINNA_STAND_OUT = 0.15
PINNA_MARGIN = 0.1
#: Neck-front window for the larynx peak: half height (m) around the C4-C5 level and
#: half width (m) about the midline. ANATOMY.md: laryngeal prominence at C4-C5.
LARYNX_WINDOW = (0.015, 0.012)


#: Label atlases kept on disk (see :func:`skin_label_atlas`); ``HACK_RENDER_NO_CACHE=1``
#: turns the cache off.
ATLAS_CACHE_KEEP = 8
_ATLAS_CACHE_FORMAT = 1


def _file_identity(path) -> list:
    p = Path(path)
    st = p.stat()
    return [str(p.resolve()), st.st_size, st.st_mtime_ns]


def atlas_cache_path(height: int) -> Path | None:
    """Where :func:`skin_label_atlas` keeps its atlas of ``height``: a file named by the
    sha256 of what the atlas depends on (the model and template files' identity, the
    source of this module, of the appearance package and of the geometry package); None
    when ``HACK_RENDER_NO_CACHE`` is set."""
    if os.environ.get("HACK_RENDER_NO_CACHE", "") not in ("", "0"):
        return None
    h = hashlib.sha256(json.dumps([_ATLAS_CACHE_FORMAT, int(height),
                                   _file_identity(default_model_path()),
                                   _file_identity(TEMPLATE_FILE)]).encode())
    geometry = Path(__file__).resolve().parents[1] / "geometry"
    for f in [Path(__file__).resolve(), *sorted(Path(appearance.__file__).parent.glob("*.py")),
              *sorted(geometry.glob("*.py"))]:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hack-render" / "labels" / f"atlas-{h.hexdigest()[:32]}.npy"


@lru_cache(maxsize=2)
def skin_label_atlas(height: int = ATLAS_HEIGHT) -> np.ndarray:
    """(H, 2H) uint8 dataset label per texel of the skin atlas (:func:`label_atlas`).

    Rasterising it costs ~1 CPU s, a third of a dataset's start-up, so the first one made
    on a machine is kept in ``$XDG_CACHE_HOME/hack-render/labels/`` (:func:`atlas_cache_path`:
    any change to the files or code it depends on makes another) and later processes load
    it (no pickle); a file that cannot be read is made again, one that cannot be written
    costs only the time."""
    path = atlas_cache_path(height)
    if path is not None:
        try:
            got = np.load(path, allow_pickle=False)
            if got.shape == (height, 2 * height) and got.dtype == np.uint8:
                return got
        except (OSError, ValueError):
            pass
    atlas = label_atlas(height)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as f:
                    np.save(f, atlas, allow_pickle=False)
            kept = sorted(path.parent.glob("atlas-*.npy"), key=lambda p: p.stat().st_mtime_ns)
            for old in kept[:-ATLAS_CACHE_KEEP]:
                old.unlink(missing_ok=True)
        except (OSError, HackError):  # a read-only or full cache: the next process makes it
            pass
    return atlas


def label_atlas(height: int = ATLAS_HEIGHT) -> np.ndarray:
    """(H, 2H) uint8 dataset label per texel of the skin atlas, filled past the islands.

    The appearance regions (:func:`appearance.regions.region_labels`) through
    :data:`_ATLAS_TO_LABEL`, then three label-only corrections (the appearance regions, and
    so the generator's statistics, are left as they are):

    - ears: the pinna, :func:`pinna_texels` (the appearance ``ears`` box lies on the head
      skin behind the ear; its texels take the back tile's own rule, scalp above the
      hairline, else neck);
    - sockets: every back-tile texel of a triangle with a socket vertex (the rims of the
      mouth and eye sockets, whose nearest vertex is a lip or lid vertex, were ``neck``),
      split into gums/tongue and eyes by that socket vertex's group;
    - neck: on the face tile only the throat's region below the jaw line is neck; smaller
      islands of the appearance rule (a spot on the jaw below each ear, where the
      surface dips under the rule's width limit) are face skin.
    """
    from scipy import ndimage

    lay = rasterize_layout(height)
    mesh = default_template()
    atlas = region_labels(lay)
    lut = np.array([LABEL_ID[_ATLAS_TO_LABEL[n]] for n in ATLAS_REGIONS], np.uint8)
    out = lut[atlas]
    face = lay.mask & (lay.tile == 0)
    back = lay.mask & (lay.tile == 1)
    x, y, z = (lay.position[..., k] for k in range(3))
    # ears: the appearance box (head skin behind the ear) -> the back tile's hairline rule
    box = atlas == ATLAS_REGIONS.index("ears")
    brow_y = float(mesh.vertices[LANDMARK_VERTICES[17:27], 1].max())
    hair = y > np.minimum(hairline_y(x, z, brow_y), nape_y(z))
    out[box] = np.where(hair, LABEL_ID["scalp"], LABEL_ID["neck_skin"])[box]
    out[pinna_texels(lay)] = LABEL_ID["ears"]
    # sockets: every back-tile triangle with a socket vertex, by that vertex's group
    model = load_default_model()
    groups = model.vertex_group.numpy()
    tri = mesh.faces[np.where(lay.mask, lay.face, 0)]
    in_socket = (tri >= SOCKET_VERTICES[0]) & (tri <= SOCKET_VERTICES[1])
    sockets = back & in_socket.any(-1)
    vert = np.take_along_axis(tri, in_socket.argmax(-1)[..., None], -1)[..., 0][sockets]
    mouth = model.group_names.index("mouth_socket") if "mouth_socket" in model.group_names else -1
    out[sockets] = np.where(groups[vert] == mouth, LABEL_ID["gums_tongue"], LABEL_ID["eyes"])
    # neck on the face tile: the largest connected region (the throat); islands -> face
    neck = face & (out == LABEL_ID["neck_skin"])
    parts, n = ndimage.label(neck)
    if n > 1:
        keep = 1 + int(np.argmax(ndimage.sum(neck, parts, np.arange(1, n + 1))))
        out[neck & (parts != keep)] = LABEL_ID["face_skin"]
    return out.ravel()[lay.fill].reshape(out.shape)


def pinna_texels(lay) -> np.ndarray:
    """(H, 2H) bool: texels of the pinnae, both sides of each ear, on a :class:`UVLayout`.

    Outer side (face tile): ICT-FaceKit's ear patches (:data:`EAR_VERTICES`, triangles with
    at least two corners in one) inside the pinna's outline in side view. The patches
    reach about 1 cm in front of the ear onto the cheek; the outline is the convex hull,
    in the (z, y) plane, of the patch vertices that stand out by more than
    :data:`PINNA_STAND_OUT` from the pre-auricular skin (a quadratic x(y, z) fitted to
    the face-tile vertices just in front of the patch: helix, antihelix, tragus,
    antitragus, lobe; the concha lies inside), grown by :data:`PINNA_MARGIN`.
    Cranial side (back tile): the back-tile UV islands that touch an ear patch and lie
    wholly beside the head (every vertex at |x| > 6 cm), where their surface faces the
    head (the island's rim on the head itself, in the retro-auricular fold, is not pinna).
    """
    from scipy.spatial import ConvexHull

    mesh = default_template()
    v, f = mesh.vertices, mesh.faces
    face_mat, back_mat = (mesh.materials.index(m) for m in ("M_Face", "M_BackHead"))
    h, w = lay.mask.shape
    pos = lay.position.reshape(-1, 3).astype(np.float64)
    tri = f[np.where(lay.mask, lay.face, 0)].reshape(-1, 3)
    tile = lay.tile.reshape(-1)
    valid = lay.mask.reshape(-1)
    out = np.zeros(h * w, bool)
    face_verts = np.unique(f[mesh.face_material == face_mat])

    def basis(p):
        yy, zz = p[:, 1], p[:, 2]
        return np.stack([np.ones_like(yy), yy, zz, yy * yy, zz * zz, yy * zz], -1)

    in_any = np.zeros(len(v), bool)
    for first, last in EAR_VERTICES:
        patch = np.arange(first, last + 1)
        in_any[patch] = True
        side = float(np.sign(v[patch, 0].mean()))
        lo, hi = v[patch].min(0), v[patch].max(0)
        cheek = face_verts[((face_verts < first) | (face_verts > last))
                           & (side * v[face_verts, 0] > 0)
                           & (v[face_verts, 1] > lo[1]) & (v[face_verts, 1] < hi[1])
                           & (v[face_verts, 2] > hi[2] - 1.5) & (v[face_verts, 2] < hi[2] + 1.0)]
        coef = np.linalg.lstsq(basis(v[cheek]), side * v[cheek, 0], rcond=None)[0]
        stand_out = side * v[patch, 0] - basis(v[patch]) @ coef > PINNA_STAND_OUT
        hull = ConvexHull(v[patch[stand_out]][:, [2, 1]])
        # the hull's facets n . p + c <= 0 inside (unit normals): grown by the margin
        inside = (pos[:, [2, 1]] @ hull.equations[:, :2].T + hull.equations[:, 2]
                  <= PINNA_MARGIN).all(-1)
        corners = ((tri >= first) & (tri <= last)).sum(-1)
        out |= valid & (tile == 0) & (corners >= 2) & inside & (side * pos[:, 0] > 0)
    # cranial side: small back-tile islands beside the head that touch an ear patch
    sel = np.flatnonzero(mesh.face_material == back_mat)
    island = _uv_islands(mesh.uv_faces[sel], len(mesh.uvs))
    ear_islands = [k for k in np.unique(island)
                   if in_any[f[sel[island == k]]].any()
                   and (np.abs(v[f[sel[island == k]], 0]) > 6.0).all()]
    island_of = np.full(len(f), -1)
    island_of[sel] = island
    on_island = np.isin(island_of[np.where(lay.mask, lay.face, 0)].reshape(-1), ear_islands)
    normal = lay.normal.reshape(-1, 3)
    facing_head = normal[:, 0] * np.sign(pos[:, 0]) < 0.0
    out |= valid & (tile == 1) & on_island & facing_head
    return out.reshape(h, w)


def _uv_islands(uv_faces: np.ndarray, num_uvs: int) -> np.ndarray:
    """(F,) connected-component id of each triangle over shared UV corners."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    a = uv_faces.ravel()
    b = np.roll(uv_faces, 1, axis=1).ravel()
    graph = sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(num_uvs, num_uvs))
    _, comp = connected_components(graph, directed=False)
    return comp[uv_faces[:, 0]]


def to_labels(region: np.ndarray, uv: np.ndarray, atlas: np.ndarray | None = None) -> np.ndarray:
    """Dataset label ids (H, W) uint8 from render region ids (H, W) and model UVs (H, W, 2)."""
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
    return np.array([0 if n in SKIN_RENDER_REGIONS else LABEL_ID[_RENDER_TO_LABEL[n]]
                     for n in REGIONS], np.uint8)


def label_images(head, k: int, atlas: np.ndarray | None = None):
    """G-buffer, segmentation and soft masks of a head scene's current view, one ray batch.

    Returns:
        (aov, seg, masks): ``aov`` the pixel-centre G-buffer (``render.aov.gbuffer``'s
        keys), ``seg`` (H, W) uint8 labels at the pixel centres, ``masks`` (H, W, L)
        float32 coverage over k x k sub-pixel rays (one-hot ``seg`` for k = 0); a ray that
        meets the lash cards counts the cards' opacity at the hit (the renderer's strand
        texture) for the lashes and the rest for what is behind them.
    """
    atlas = skin_label_atlas() if atlas is None else atlas
    out = head.label_pass(k, render_region_labels(), atlas, SKIN_RENDER_REGIONS,
                          see_through=("eyelashes",), num_labels=len(LABELS))
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
    h, w = head.camera.height, head.camera.width
    n_lab = len(LABELS)
    acc = np.zeros(h * w * n_lab, np.float64)
    base = np.arange(h * w) * n_lab
    for off in subpixel_offsets(k):
        hits = head.region_hits(off, see_through=("eyelashes",))
        front = to_labels(hits["region"], hits["uv"], atlas).ravel()
        lash = front == LABEL_ID["eyelashes"]
        opacity = np.where(lash, hits["opacity"].ravel(), 1.0)  # the cards' at the hit
        # bincount is the fast scatter-add (np.add.at is several times slower)
        acc += np.bincount(base + front, opacity, len(acc))
        if lash.any():
            behind = to_labels(hits["region_behind"], hits["uv_behind"], atlas).ravel()
            acc += np.bincount(base[lash] + behind[lash], 1.0 - opacity[lash], len(acc))
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
