"""Person, face, skin and occluder masks of a photo on any background, offline.

- **person** (soft, [0, 1]): MediaPipe's selfie segmentation
  (:func:`hack_render.vision.person.person_probability`: the landscape model, shipped in
  the ``mediapipe`` wheel; it measured better than the general one on the composites,
  docs/vision.md), above ``PERSON_THRESHOLD``, the connected part that holds the face.
- **face** (soft): the face mesh's face oval (:mod:`hack_render.vision.detect`'s dense
  points), anti-aliased, inside the person.
- **skin / hair / clothes** (bool, heuristic): skin is the person's pixels whose
  chromaticity lies within the face's own skin distribution (a Gaussian estimated from
  the cheeks, forehead and nose of the face mesh) and that do not look like the
  person's own hair (:func:`hair_like`: colour, brightness and texture against samples
  of this photo's hair and cheeks, for hair of the skin's chromaticity); the rest of the
  person is hair above the mouth's line and clothes below the chin's.
- **occluder** (bool): what covers the face: inside the face oval, pixels that are not
  skin (hair strands and fringes, glasses, a scarf) outside the eyes, brows and lips, and
  hands (MediaPipe's hand landmarks' outline, dilated) wherever they overlap the face;
  inside the brows, a glasses frame's pixels joined to an occluder under the lids
  (:mod:`hack_render.vision.glasses`). The photometric loss leaves these pixels out.

:func:`segment` returns all of them as :class:`Segmentation`; :func:`person_mask` is the
silhouette term's entry point (same contract as ``fit.silhouette.segment_plain_background``:
a mask or None and the reason).
"""

from __future__ import annotations

import warnings
from contextlib import suppress
from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError
from hack_render.vision import detect as vision_detect
from hack_render.vision.dense68 import load_map
from hack_render.vision.detect import as_rgb8
from hack_render.vision.detection import FaceLandmarks
from hack_render.vision.glasses import frames_in_brows, upright_xy
from hack_render.vision.neck import NECK_K, neck_skin
from hack_render.vision.person import person_probability

#: face-mesh point rings (MediaPipe's FACEMESH_* connection sets, as ordered loops)
_RINGS = ("FACEMESH_FACE_OVAL", "FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE", "FACEMESH_LIPS",
          "FACEMESH_LEFT_EYEBROW", "FACEMESH_RIGHT_EYEBROW")
#: face-mesh points on the cheeks and forehead (skin-colour samples)
_SKIN_SAMPLES = (50, 101, 118, 123, 147, 187, 205, 280, 330, 347, 352, 376, 411, 425,
                 10, 67, 69, 104, 108, 109, 151, 297, 299, 333, 337, 338, 4, 5, 195, 197)

#: person probability above which a pixel is the person's (0.7: the best IoU on the
#: composites among 0.3, 0.5, 0.7, 0.85)
PERSON_THRESHOLD = 0.7
#: chromaticity (r and b shares of r + g + b, sRGB) of skin across tones: the prior that
#: picks the skin's cluster among the colour samples
SKIN_CHROMA_PRIOR = np.array([0.43, 0.25])
#: the hair-against-skin test (:func:`hair_like`): the least samples of each, the mean
#: share of each set's own pixels that must fall on its side for the test to be used, and
#: the per-feature variance floor (r and b shares, log luminance, texture)
HAIR_MIN_SAMPLES = 100
HAIR_SEPARABLE = 0.85
#: the same test's threshold in a grey photo, where it has brightness and texture alone:
#: a shadowed cheek can look like dark hair, so only hair told apart this well is taken
#: (the cameraman's dark hair 0.97; bald composites in grey up to 0.94, docs/vision.md),
#: and only hair of strands: its samples' median texture this many times the cheeks'
#: (real hair in grey 3.2-5.3; a bald scalp's smooth skin on the composites up to 2.5)
GREY_HAIR_SEPARABLE = 0.95
GREY_HAIR_TEXTURE = 3.0
HAIR_FEATURE_FLOOR = (1e-4, 1e-4, 1e-3, 1e-4)


@dataclass
class Segmentation:
    """Masks at the photo's size (H, W): person, face (float32 in [0, 1]); skin, hair,
    clothes, occluder (bool). ``source`` names the models used."""

    person: np.ndarray
    face: np.ndarray
    skin: np.ndarray
    hair: np.ndarray
    clothes: np.ndarray
    occluder: np.ndarray
    source: str
    #: the neck's skin below the jaw (:mod:`hack_render.vision.neck`; bool), in
    #: ``skin`` too, not in ``clothes``; None: not looked for
    neck: np.ndarray | None = None

    def photometric_weight(self) -> np.ndarray:
        """(H, W) float32: the face's pixels a photometric loss may use (soft face mask,
        occluders removed)."""
        return (self.face * ~self.occluder).astype(np.float32)


_CACHE: dict = {}


def _hands():
    if "hands" not in _CACHE:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mediapipe as mp

            _CACHE["hands"] = mp.solutions.hands.Hands(
                static_image_mode=True, max_num_hands=2, min_detection_confidence=0.5)
    return _CACHE["hands"]


def ring(name: str) -> np.ndarray:
    """A face-mesh connection set (e.g. ``FACEMESH_FACE_OVAL``) as an ordered loop of
    point ids."""
    if name not in _CACHE:
        from mediapipe.python.solutions import face_mesh_connections as fmc

        edges = dict(getattr(fmc, name))
        loops, seen = [], set()
        for start in edges:       # the lips set holds two loops (outer, inner): the outer
            if start in seen:
                continue
            loop, p = [], start
            while p not in seen and p in edges:
                seen.add(p)
                loop.append(p)
                p = edges[p]
            loops.append(loop)
        _CACHE[name] = np.array(max(loops, key=len))
    return _CACHE[name]


def _polygon_mask(poly: np.ndarray, shape, soft: bool = True) -> np.ndarray:
    """(H, W) float32 coverage of a polygon (pixels), 4x4 supersampled when ``soft``."""
    from skimage.draw import polygon

    h, w = shape
    s = 4 if soft else 1
    m = np.zeros((h * s, w * s), np.float32)
    rr, cc = polygon(poly[:, 1] * s - 0.5, poly[:, 0] * s - 0.5, (h * s, w * s))
    m[rr, cc] = 1.0
    return m.reshape(h, s, w, s).mean((1, 3)) if s > 1 else m


def skin_colour_mask(rgb8: np.ndarray, dense: np.ndarray, within: np.ndarray,
                     k: float = 3.0) -> np.ndarray:
    """(H, W) bool: pixels in ``within`` whose chromaticity (the r and b shares of
    r + g + b: shading and highlights change brightness far more than it) lies within
    Mahalanobis ``k`` of the skin samples' (cheeks, forehead, nose: visible face-mesh
    points) and that are not too dark for their chromaticity to mean anything."""
    maha, lit = skin_distance(rgb8, dense)
    return within & (maha < k) & lit


def skin_distance(rgb8: np.ndarray, dense: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Mahalanobis distance (H, W) of each pixel's chromaticity from the skin samples'
    clusters, bool (H, W): bright enough for its chromaticity to mean anything), which
    :func:`skin_colour_mask` thresholds; one computation for several thresholds (the
    face's and the neck's)."""
    from scipy import ndimage

    h, w = rgb8.shape[:2]
    img = rgb8.astype(np.float32) / 255.0
    chroma = img[..., [0, 2]] / np.maximum(img.sum(-1, keepdims=True), 1e-6)
    vis = load_map().dense_visible(dense)
    ids = [i for i in _SKIN_SAMPLES if vis[i]] or list(_SKIN_SAMPLES)
    p = np.clip(np.round(dense[ids, :2] - 0.5).astype(int), 0, [w - 1, h - 1])
    sm = np.zeros((h, w), bool)
    sm[p[:, 1], p[:, 0]] = True
    sm = ndimage.binary_dilation(sm, iterations=1)   # a 3 x 3 neighbourhood of each
    x = chroma[sm]
    # robust, and for light of two colours (a warm key, a cool fill): the samples'
    # chromaticity clusters (greedy, 0.03 across) holding a sixth of them or more and
    # lying within 0.08 of a skin prior (any skin tone) are all skin; a strand of hair or
    # a hand over some sample points makes a cluster of its own, far from the prior
    left = np.ones(len(x), bool)
    clusters = []
    while left.sum() >= 3:
        d = np.linalg.norm(x[:, None] - x[None], axis=-1) < 0.03
        d &= left[None] & left[:, None]
        i = int(np.argmax(d.sum(1)))
        members = d[i]
        if members.sum() < max(3, len(x) // 6):
            break
        clusters.append(x[members])
        left &= ~members
    skin_like = [c for c in clusters
                 if np.linalg.norm(np.median(c, 0) - SKIN_CHROMA_PRIOR) < 0.08]
    clusters = skin_like or clusters[:1] or [x]
    maha = np.full((h, w), np.inf, np.float32)
    for c in clusters:
        mu = np.median(c, 0)
        dev = c - mu
        cov = dev.T @ dev / max(len(dev) - 1, 1) + np.eye(2) * 1e-4   # >= 0.01 per share
        dd = chroma - mu
        maha = np.minimum(maha, np.sqrt(np.einsum("...i,ij,...j->...", dd,
                                                   np.linalg.inv(cov), dd)))
    return maha, img.mean(-1) > 0.06


def _pixel_features(rgb8: np.ndarray, win: int) -> np.ndarray:
    """(H, W, 4): chromaticity (r and b shares), log luminance, and the luminance's
    local texture (its standard deviation over ``win`` x ``win``: hair is strands, skin
    smooth)."""
    from scipy import ndimage

    img = rgb8.astype(np.float32) / 255.0
    share = img[..., [0, 2]] / np.maximum(img.sum(-1, keepdims=True), 1e-6)
    lum = np.log(np.maximum(img.mean(-1), 0.02))
    m = ndimage.uniform_filter(lum, win)
    tex = np.sqrt(np.maximum(ndimage.uniform_filter(lum * lum, win) - m * m, 0.0))
    return np.concatenate([share, lum[..., None], tex[..., None]], -1)


def _gaussian_loglik(x: np.ndarray, samples: np.ndarray) -> np.ndarray:
    mu = np.median(samples, 0)
    dev = samples - mu
    cov = dev.T @ dev / max(len(dev) - 1, 1) + np.diag(HAIR_FEATURE_FLOOR)
    d = x - mu
    return -0.5 * (np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
                   + np.log(np.linalg.det(cov)))


def hair_like(rgb8: np.ndarray, face: FaceLandmarks, person: np.ndarray, oval: np.ndarray,
              skin: np.ndarray, features: np.ndarray) -> np.ndarray | None:
    """(H, W) bool: pixels that look more like the person's own hair (or headwear) than
    their own skin, by two Gaussians in colour, brightness and texture
    (:func:`_pixel_features`) fitted to this photo alone: the hair's from the person's
    pixels above the brows and well outside the face oval, the skin's from the
    skin-coloured cheeks between the eyes and the mouth. Blond or grey hair has the
    skin's chromaticity, so the colour test alone keeps a fringe over the forehead as
    skin. None where the two are not told apart (a bald head, a scalp the colour of the
    face: the hair samples are skin) or too few samples; in a grey photo, where
    brightness and texture alone can take a shadowed cheek for dark hair, unless they
    are told apart by ``GREY_HAIR_SEPARABLE`` and the hair is strands
    (``GREY_HAIR_TEXTURE``)."""
    from scipy import ndimage

    test = hair_ratio(rgb8, face, person, oval, skin, features)
    grey = _grey(rgb8)
    if test is None or test[2] < (GREY_HAIR_SEPARABLE if grey else HAIR_SEPARABLE) \
            or (grey and test[3] < GREY_HAIR_TEXTURE):
        return None
    lr, hair_seed = test[:2]
    like = ndimage.binary_opening(lr > 0, iterations=1) & (person | (oval > 0.5))
    if grey:   # brightness alone: below the eyes a shadowed chin or a dark collar
        # joins the hair; a fringe reaches down from above, and inside the face oval a
        # sideburn down to the nose's base (outside it, below the eyes, an ear's folds
        # look like hair in grey)
        h, w = rgb8.shape[:2]
        up = _upright_rows(face, h, w)
        like &= (up < _upright_y(face, slice(36, 48)).mean()) | \
            ((oval > 0.5) & (up < _upright_y(face, slice(31, 36)).mean()))
    # hair reaches the face from the hair: only the parts joined to the hair samples
    lab, _ = ndimage.label(like)
    ids = np.unique(lab[hair_seed])
    return np.isin(lab, ids[ids > 0])


def hair_samples(person: np.ndarray, oval: np.ndarray, up: np.ndarray, brow_y: float,
                 iod: float) -> np.ndarray:
    """(H, W) bool: where the hair test samples the person's hair: above the brows (in
    the upright frame ``up``), well outside the face oval, and inside the person away
    from its outline (the segmentation spreads into the background by a few pixels)."""
    from scipy import ndimage

    far = ~ndimage.binary_dilation(oval > 0.05, iterations=max(2, round(iod / 15)))
    inside = ndimage.binary_erosion(person, iterations=max(2, round(iod / 10)))
    return inside & far & (up < brow_y)


def hair_ratio(rgb8: np.ndarray, face: FaceLandmarks, person: np.ndarray, oval: np.ndarray,
               skin: np.ndarray, features: np.ndarray):
    """:func:`hair_like`'s test: (log likelihood ratio hair : skin (H, W), the hair
    samples (H, W) bool, how well it tells its own samples apart: the mean of the shares
    of hair and skin samples on their side, the hair samples' median texture over the
    cheeks'), or None (too few samples). In a grey photo the chromaticity is the same
    everywhere: brightness and texture tell them apart."""
    h, w = rgb8.shape[:2]
    pts = face.points
    iod = float(np.linalg.norm(pts[36] - pts[45]))
    up = _upright_rows(face, h, w)
    brow_y = float(_upright_y(face, slice(17, 27)).min())
    eye_y = float(_upright_y(face, slice(36, 48)).mean())
    mouth_y = float(_upright_y(face, slice(48, 68)).mean())
    hair_seed = hair_samples(person, oval, up, brow_y, iod)
    span = mouth_y - eye_y
    cheek = (oval > 0.5) & (features < 0.5) & skin & (up > eye_y + 0.15 * span) \
        & (up < mouth_y - 0.1 * span)
    if hair_seed.sum() < HAIR_MIN_SAMPLES or cheek.sum() < HAIR_MIN_SAMPLES:
        return None
    f = _pixel_features(rgb8, max(3, round(iod / 25) | 1))
    lr = _gaussian_loglik(f, f[hair_seed]) - _gaussian_loglik(f, f[cheek])
    texture = float(np.median(f[hair_seed][:, 3]) / max(np.median(f[cheek][:, 3]), 1e-6))
    return (lr, hair_seed, 0.5 * float((lr[hair_seed] > 0).mean() + (lr[cheek] < 0).mean()),
            texture)


#: :func:`segment` refines the skin by :func:`refine_skin` (a graph cut) by default
GRAPH_CUT = True


def _grey(rgb8: np.ndarray) -> bool:
    return int(np.ptp(rgb8, axis=2).max()) <= 1


def refine_skin(rgb8: np.ndarray, face: FaceLandmarks, skin: np.ndarray, person: np.ndarray,
                oval: np.ndarray, features: np.ndarray, iterations: int = 5,
                hair_found: bool = False) -> np.ndarray:
    """(H, W) bool: ``skin`` (the per-pixel colour and hair tests) refined by a graph cut
    (OpenCV's GrabCut: a mixture of five Gaussians in colour for skin and for the rest,
    and a smoothness term that puts the boundary on the image's edges) in a box about the
    face. Per pixel, a highlighted strand of blond hair has the skin's colour and a
    shadowed patch of forehead the hair's, so the tests above leave a fringe's edge as a
    ragged band of both; the cut follows the fringe. Seeds: the person's pixels that the
    hair test sampled as hair and the background are surely not skin, the cheeks and the
    nose (skin below the eyes, away from its edge) surely skin, the rest keeps the tests'
    answer as a likely one. The cut only takes skin away: what the tests call not skin
    stays so (glasses' frames of the skin's colour, which the cut's smoothness would
    join to the face). A grey photo keeps ``skin`` unless :func:`hair_like` found its hair
    (``hair_found``): the cut then models brightness alone, seeded by that hair, and
    takes only what joins its seeds (the hair's samples, the background); without hair
    seeds it took 2.7-4.7 % of bald faces for occluders (docs/vision.md)."""
    import cv2
    from scipy import ndimage

    if _grey(rgb8) and not hair_found:
        return skin
    h, w = skin.shape
    pts = face.points
    iod = float(np.linalg.norm(pts[36] - pts[45]))
    ys, xs = np.nonzero(oval > 0.05)
    if len(ys) == 0 or iod < 8:
        return skin
    pad = round(0.5 * iod)
    y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, h)
    x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, w)
    up = _upright_rows(face, h, w)
    eye_y = float(_upright_y(face, slice(36, 48)).mean())
    brow_y = float(_upright_y(face, slice(17, 27)).min())
    core = ndimage.binary_erosion(skin & (oval > 0.5) & (features < 0.5),
                                  iterations=max(1, round(iod / 12)))
    label = np.where(skin, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    label[~person & (oval < 0.05)] = cv2.GC_BGD
    label[hair_samples(person, oval, up, brow_y, iod) & ~skin] = cv2.GC_BGD
    label[core & (up > eye_y)] = cv2.GC_FGD
    sub = np.ascontiguousarray(label[y0:y1, x0:x1])
    if not ((sub == cv2.GC_FGD).any() and np.isin(sub, (cv2.GC_BGD, cv2.GC_PR_BGD)).any()):
        return skin
    bgr = np.ascontiguousarray(rgb8[y0:y1, x0:x1, ::-1])
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, sub, None, np.zeros((1, 65)), np.zeros((1, 65)), iterations,
                cv2.GC_INIT_WITH_MASK)
    out = skin.copy()   # only taken away: what the tests call no skin (a frame of the
    # skin's colour between dark rims, a shadowed fold) stays out of the bake
    out[y0:y1, x0:x1] &= (sub == cv2.GC_FGD) | (sub == cv2.GC_PR_FGD)
    if hair_found and _grey(rgb8):   # brightness alone: a shadowed chin goes with the
        # hair; only what the cut takes joined to its seeds (hair, background) is taken
        lab, _ = ndimage.label(skin & ~out)
        seeds = ndimage.binary_dilation(label == cv2.GC_BGD, iterations=1)
        ids = np.unique(lab[seeds & (lab > 0)])
        out |= skin & ~np.isin(lab, ids)
    return out


def hand_mask(rgb8: np.ndarray, dilate: float = 0.08) -> np.ndarray:
    """(H, W) bool: the convex hull of each hand's 21 landmarks (MediaPipe hands),
    dilated by ``dilate`` of the hand's size (the landmarks are joints, not the outline)."""
    from scipy import ndimage
    from scipy.spatial import ConvexHull

    h, w = rgb8.shape[:2]
    out = np.zeros((h, w), bool)
    res = _hands().process(rgb8)
    for hand in res.multi_hand_landmarks or []:
        p = np.array([[q.x * w, q.y * h] for q in hand.landmark])
        hull = p[ConvexHull(p).vertices]
        m = _polygon_mask(hull, (h, w), soft=False) > 0
        r = round(dilate * float(np.ptp(p, 0).max()))
        out |= ndimage.binary_dilation(m, iterations=max(r, 1))
    return out


def segment(image, face: FaceLandmarks | None = None, hands: bool = True,
            name: str = "photo", hair_model: bool = True,
            graph_cut: bool | None = None) -> Segmentation:
    """All masks of ``image`` (see the module docstring). ``face``: a detection with
    dense points (:func:`hack_render.vision.detect.detect_face`); where None, ``auto``'s
    mesh face, else ``mesh``'s. ``hands``: look for hands over the face (~30 ms)."""
    from scipy import ndimage

    rgb8 = as_rgb8(image, name)
    if face is None:   # auto turns BlazeFace's keypoints the right way up (mesh does not)
        with suppress(HackError):    # (auto drops boxes off the person: then mesh's)
            face = vision_detect.detect_face(rgb8, "auto", name=name)
        if face is None or face.dense is None:   # or took the shape predictor's points
            face = vision_detect.detect_face(rgb8, "mesh", name=name)
    if face.dense is None:
        raise HackError(f"{name}: segmentation needs the face mesh's dense points; expected "
                        f"a 'mesh' detection, found one from {face.source}.")
    h, w = rgb8.shape[:2]
    prob = person_probability(rgb8, face.roll_deg)
    person_bin = _holding_face(prob > PERSON_THRESHOLD, face.points)
    person = np.where(ndimage.binary_dilation(person_bin, iterations=2), prob, 0.0)
    oval = _polygon_mask(face.dense[ring("FACEMESH_FACE_OVAL"), :2], (h, w))
    # the face oval is the mesh's, which also covers the far side of a turned head: only
    # its part inside the person is seen
    face_soft = np.minimum(oval, np.maximum(person, person_bin.astype(np.float32)))
    maha, lit = skin_distance(rgb8, face.dense)
    skin = (person_bin | (oval > 0.5)) & (maha < 3.0) & lit
    features = np.zeros((h, w), np.float32)
    brows = np.zeros((h, w), bool)
    for nm in _RINGS[1:]:
        poly = face.dense[ring(nm), :2]
        if nm.endswith("EYEBROW"):      # a brow is a thin loop: widen it
            c = poly.mean(0)
            poly = c + 1.6 * (poly - c)
        m = _polygon_mask(poly, (h, w), soft=False)
        features = np.maximum(features, m)
        if nm.endswith("EYEBROW"):
            brows |= m > 0.5
    inner = (oval > 0.5) & (features < 0.5)
    like_hair = hair_like(rgb8, face, person_bin, oval, skin, features) if hair_model else None
    if like_hair is not None:   # the person's hair is not skin, whatever its colour
        skin &= ~like_hair
    if GRAPH_CUT if graph_cut is None else graph_cut:
        skin = refine_skin(rgb8, face, skin, person_bin, oval, features,
                           hair_found=like_hair is not None)
    occluder = inner & ~skin
    occluder = ndimage.binary_opening(occluder, iterations=1)
    occluder |= frames_in_brows(face, skin, occluder, brows & (oval > 0.5))
    if hands:
        occluder |= hand_mask(rgb8) & (oval > 0.5)
    skin_all = skin & person_bin
    rest = person_bin & ~skin_all
    # (in the upright frame: for a tilted head the image's rows are not the face's)
    mouth_y = float(_upright_y(face, slice(48, 68)).mean())
    chin_y = float(_upright_y(face, 8))
    up = _upright_rows(face, h, w)
    hair = rest & (up < mouth_y) & (oval < 0.5)
    neck = neck_skin(face, rgb8, person_bin & (maha < NECK_K) & lit,
                     skin_all & (oval > 0.5), person_bin, _grey(rgb8))
    skin_all |= neck
    clothes = rest & (up > chin_y) & ~neck
    return Segmentation(person.astype(np.float32), face_soft.astype(np.float32), skin_all,
                        hair & ~neck, clothes, occluder,
                        "mediapipe selfie_segmentation + face mesh"
                        + (" + hands" if hands else ""), neck)


def _upright_rows(face: FaceLandmarks, h: int, w: int) -> np.ndarray:
    """(H, W) each pixel's row in the face's upright frame (the image turned by the
    face's roll about the nose), so 'above the mouth' holds for a tilted head."""
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    return _upright(face, xx, yy)


def _upright_y(face: FaceLandmarks, idx) -> np.ndarray:
    """The upright rows (as :func:`_upright_rows`) of the landmarks ``idx``."""
    p = face.points[idx]
    return _upright(face, p[..., 0], p[..., 1])


def _upright(face: FaceLandmarks, x, y):
    return upright_xy(face, x, y)[1]


def _holding_face(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The connected parts of ``mask`` that hold the face's inner landmarks."""
    from scipy import ndimage

    lab, n = ndimage.label(mask)
    if n == 0:
        return mask
    h, w = mask.shape
    p = np.clip(np.floor(points[27:]).astype(int), 0, [w - 1, h - 1])
    ids = np.unique(lab[p[:, 1], p[:, 0]])
    ids = ids[ids > 0]
    return np.isin(lab, ids) if len(ids) else mask


def person_mask(rgb, points: np.ndarray, threshold: float = PERSON_THRESHOLD,
                min_inside: float = 0.9) -> tuple[np.ndarray | None, str]:
    """The silhouette term's person mask on any background: MediaPipe selfie
    segmentation above ``threshold``, the connected parts holding the face.

    Args:
        rgb: (h, w, 3) sRGB image, uint8 or float in [0, 1].
        points: (68, 2) landmarks of the face, pixels.
    Returns:
        ((h, w) bool mask, "") or (None, why): no mask when under ``min_inside`` of the
        nose, eye and mouth landmarks fall inside it (the model missed the person).
    """
    rgb8 = as_rgb8(rgb)
    d = np.asarray(points)[45] - np.asarray(points)[36]     # the face's roll (its eyes)
    roll = float(np.degrees(np.arctan2(-d[1], d[0])))
    m = _holding_face(person_probability(rgb8, roll) > threshold, np.asarray(points))
    h, w = m.shape
    p = np.clip(np.floor(np.asarray(points)[27:]).astype(int), 0, [w - 1, h - 1])
    inside = float(m[p[:, 1], p[:, 0]].mean())
    if inside < min_inside or m.all():
        return None, (f"the person segmentation holds only {100 * inside:.0f} % of the nose, "
                      "eye and mouth landmarks")
    return m, ""
