"""hack_render.vision.segment's graph cut (refine_skin) on a real photo."""

from __future__ import annotations

import numpy as np
import pytest

# as tests/test_vision.py: mediapipe 0.10.14 (the fit extra) has no wheel for Python 3.13+
pytest.importorskip("mediapipe", reason="mediapipe 0.10.14 (fit extra) is not installed; "
                    "it has no wheel for Python 3.13+")
pytest.importorskip("ai_edge_litert", reason="ai-edge-litert (fit extra) is not installed")

from hack_render.vision.detect import detect_face


def test_the_graph_cut_takes_the_fringe_away_from_the_skin():
    """The astronaut (public domain, 256 px): her blond fringe has the skin's colour in
    its highlights, and the per-pixel tests left a ragged band of it as skin along the
    hairline. The graph cut only takes skin away (never adds), keeps the skin below the
    eyes, and what it takes inside the face oval is the fringe: far darker than the
    forehead it leaves."""
    import skimage.data

    from hack_render.vision.segment import _upright_rows, _upright_y, segment

    img = np.ascontiguousarray(skimage.data.astronaut()[::2, ::2])
    face = detect_face(img, "mesh")
    tests, cut = [segment(img, face, hands=False, graph_cut=g) for g in (False, True)]
    h, w = img.shape[:2]
    up = _upright_rows(face, h, w)
    oval = tests.face > 0.5
    assert not (cut.skin & ~tests.skin).any()
    below = oval & (up > _upright_y(face, slice(36, 48)).mean())
    assert (cut.skin & below).sum() >= 0.98 * (tests.skin & below).sum()
    taken = tests.skin & ~cut.skin & oval
    assert taken.sum() > 50, taken.sum()
    lum = img.mean(-1)
    forehead = cut.skin & oval & (up < _upright_y(face, slice(17, 27)).min())
    assert np.median(lum[taken]) < 0.75 * np.median(lum[forehead]), (
        np.median(lum[taken]), np.median(lum[forehead]))
    assert (cut.occluder & taken).sum() > 0.8 * taken.sum()   # the fit leaves them out


def test_a_grey_photos_dark_hair_is_an_occluder():
    """The cameraman (skimage, public domain; grey): his dark fringe reaches down to his
    brows. A grey photo's chromaticity is the same everywhere, so the colour test calls
    all of the face oval skin; brightness and texture tell his hair from his cheeks
    (well past ``GREY_HAIR_SEPARABLE``), and the hair test and the graph cut take it out
    above the eyes' line. Below it only his dark sideburn, inside the face oval and above
    the nose's base, is taken: lower down a shadowed chin or a dark collar looks as much
    like dark hair."""
    import skimage.data
    from skimage.color import gray2rgb

    from hack_render.vision.segment import _upright_rows, _upright_y, segment

    img = np.ascontiguousarray(gray2rgb(skimage.data.camera()))
    face = detect_face(img, "mesh")
    before, seg = [segment(img, face, hands=False, hair_model=m) for m in (False, True)]
    h, w = img.shape[:2]
    up = _upright_rows(face, h, w)
    oval = seg.face > 0.5
    lum = img.mean(-1)
    dark = oval & (up < _upright_y(face, slice(17, 27)).min()) & (lum < 50)
    assert dark.sum() > 100, dark.sum()
    assert (before.occluder & dark).sum() < 0.2 * dark.sum()
    assert (seg.occluder & dark).sum() > 0.9 * dark.sum()
    taken = seg.occluder & oval
    assert taken.sum() > 400, taken.sum()
    assert np.median(lum[taken]) < 0.6 * np.median(lum[seg.skin & oval & ~seg.occluder])
    below = oval & (up > _upright_y(face, slice(36, 48)).mean())
    new = seg.occluder & below & ~before.occluder
    # the sideburn in front of his ear (62 pixels measured), as dark as the hair above
    assert new.sum() > 30, new.sum()
    assert np.median(lum[new]) < 0.6 * np.median(lum[seg.skin & oval & ~seg.occluder])
    assert not (new & (up > _upright_y(face, slice(31, 36)).mean())).any()
    assert abs(np.nonzero(new)[1].mean() - face.points[30, 0]) > \
        abs(face.points[36:48, 0].mean() - face.points[30, 0])   # beside the ear, not the nose


def _face_points() -> np.ndarray:
    """68 points of an upright face: eyes' corners and lids at rows 46-50 (eyes at
    columns 10-22 and 38-50), the nose's line at column 30."""
    p = np.zeros((68, 2))
    p[[36, 37, 38, 39]] = [[10, 50], [14, 46], [18, 46], [22, 50]]
    p[[42, 43, 44, 45]] = [[38, 50], [42, 46], [46, 46], [50, 50]]
    p[27:31] = [[30, 48], [30, 52], [30, 56], [30, 60]]
    return p


def test_frames_in_brows_needs_thin_occluders_under_both_eyes():
    """glasses.frames_in_brows on masks drawn by hand: both brows' dark strips joined to
    thin occluders under the lids between the eyes' corners (a frame's rims) are taken;
    a rim on one side only, a blob instead of a rim, a fringe above the brows, or hair
    beside the eyes (outside their corners) reaching as low take nothing; skin in the
    brows is never taken."""
    from hack_render.vision.detection import FaceLandmarks
    from hack_render.vision.glasses import frames_in_brows

    face = FaceLandmarks(_face_points(), (0, 0, 64, 80), 1)   # outer-eye distance 40
    shape = (80, 64)
    brows = np.zeros(shape, bool)
    brows[36:40, 8:24] = brows[36:40, 36:52] = True
    skin = ~brows
    skin[37:39, 8:12] = True          # part of a brow is skin

    def rim(x0, x1):                  # down the eye's outer side and under it
        m = np.zeros(shape, bool)
        m[40:56, x0:x0 + 2] = m[54:56, min(x0, x1):max(x0, x1)] = True
        return m

    rims = rim(6, 20) | rim(52, 40)
    blob = np.zeros(shape, bool)
    blob[40:64, 4:24] = blob[40:64, 36:56] = True     # 20 px wide: not thin at 0.08 x 40
    fringe = np.zeros(shape, bool)
    fringe[20:36, 10:14] = fringe[20:36, 40:44] = True
    temple = np.zeros(shape, bool)
    temple[36:60, 3:8] = temple[36:60, 53:58] = True
    for occ, taken in ((rims, True), (rim(6, 20), False), (blob, False), (fringe, False),
                       (temple, False)):
        skin_here = skin & ~occ
        add = frames_in_brows(face, skin_here, occ, brows)
        assert not (add & skin_here).any() and not (add & ~brows).any()
        assert add.any() == taken, (taken, add.sum())
        if taken:
            assert add.sum() == (brows & ~skin_here & ~occ).sum()


def test_a_glasses_frame_across_the_brows_is_an_occluder(monkeypatch):
    """Grace Hopper (matplotlib's sample, public domain): her glasses' dark top bar runs
    along her brows, where the skin test does not look; the part of it inside the brows
    joins her frames' rims under the eyes and is taken as an occluder, far darker than
    her skin. The astronaut's dark brows, joined to her hair at the temple, stay."""
    import matplotlib.cbook
    import skimage.data
    from PIL import Image

    import hack_render.vision.segment as seg_mod

    seen = {}
    real = seg_mod.frames_in_brows

    def spy(face, skin, occluder, brows):
        seen.update(skin=skin, brows=brows, added=real(face, skin, occluder, brows))
        return seen["added"]

    monkeypatch.setattr(seg_mod, "frames_in_brows", spy)
    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        grace = np.asarray(Image.open(f).convert("RGB"))
    seg = seg_mod.segment(grace, detect_face(grace, "mesh"), hands=False)
    added = seen["added"]
    assert added.sum() > 80, added.sum()
    assert (seg.occluder & added).sum() == added.sum()
    lum = grace.mean(-1)
    skin = seg.skin & (seg.face > 0.5) & ~seg.occluder
    assert np.median(lum[added]) < 0.6 * np.median(lum[skin])

    img = np.ascontiguousarray(skimage.data.astronaut())
    seg_mod.segment(img, detect_face(img, "mesh"), hands=False)
    assert (~seen["skin"] & seen["brows"]).sum() > 20       # her brows are not skin ...
    assert not seen["added"].any()                          # ... and are kept


def test_a_turned_photos_person_is_segmented_upright():
    """Grace Hopper turned a quarter turn (a phone photo whose rotation was not applied):
    MediaPipe's selfie segmentation expects an upright person, and on the turned photo
    its mask turned back agrees with the upright photo's at IoU 0.8 only; run on the
    photo turned upright by the face's roll (``person_probability(..., roll_deg)``) it
    is the upright photo's mask, turned."""
    import matplotlib.cbook
    from PIL import Image

    from hack_render.vision.segment import PERSON_THRESHOLD, person_probability

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        grace = np.asarray(Image.open(f).convert("RGB"))
    upright = person_probability(grace) > PERSON_THRESHOLD

    def iou(a, b):
        return (a & b).sum() / (a | b).sum()

    for k in (1, 3):
        turned = np.ascontiguousarray(np.rot90(grace, k))
        face = detect_face(turned, "mesh")
        assert abs(abs(face.roll_deg) - 90) < 10, face.roll_deg
        as_is = np.rot90(person_probability(turned), -k) > PERSON_THRESHOLD
        fixed = np.rot90(person_probability(turned, face.roll_deg), -k) > PERSON_THRESHOLD
        assert iou(as_is, upright) < 0.9
        assert iou(fixed, upright) > 0.99


def test_an_upside_down_photos_face_is_segmented():
    """Grace Hopper upside down: the face mesh detector alone takes BlazeFace's keypoints
    as they come and misplaces the face (its oval at IoU 0.5 with the upright photo's);
    ``segment`` without a face detects with ``auto``, which turns them the right way up,
    so its face oval and person, turned back, are the upright photo's."""
    import matplotlib.cbook
    from PIL import Image

    from hack_render.vision.segment import segment

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        grace = np.asarray(Image.open(f).convert("RGB"))
    upright = segment(grace, hands=False)
    turned = segment(np.ascontiguousarray(grace[::-1, ::-1]), hands=False)
    for a, b in ((upright.face, turned.face), (upright.person, turned.person)):
        a, b = a > 0.5, b[::-1, ::-1] > 0.5
        assert (a & b).sum() / (a | b).sum() > 0.95


def test_the_neck_below_the_jaw_is_skin():
    """Grace Hopper: the face's skin test (Mahalanobis 3 of the cheeks' chromaticity)
    takes half of her neck under the jaw's shade, and the segmentation called the rest
    clothes; the neck's looser test below the jaw (``vision/neck.py``) takes 80 % of it
    (measured), joined to the face, and none of her dark tie and at most the edge of her white collar. The
    neck is skin, not clothes. A grey photo (the cameraman) has no chromaticity to tell a
    neck from a collar: no neck."""
    import matplotlib.cbook
    import skimage.data
    from PIL import Image

    from hack_render.vision.segment import segment, skin_colour_mask

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        grace = np.asarray(Image.open(f).convert("RGB"))
    face = detect_face(grace, "mesh")
    seg = segment(grace, face, hands=False)
    neck = np.zeros(grace.shape[:2], bool)
    neck[350:400, 235:295] = True            # under her chin, above the collar
    assert (seg.neck & neck).sum() > 0.7 * neck.sum()
    strict = skin_colour_mask(grace, face.dense, seg.person > 0.5)
    assert (strict & neck).sum() < 0.6 * neck.sum()
    assert not (seg.neck & seg.clothes).any() and not (seg.neck & ~seg.skin).any()
    lum, spread = grace.mean(-1), np.ptp(grace.astype(int), -1)
    collar = (lum > 200) & (spread < 25)
    collar[:380] = False
    tie = lum < 30
    tie[:420] = False
    assert collar.sum() > 2000 and tie.sum() > 2000
    # (1 %, measured: the collar's edge beside the neck, warm white where the JPEG's
    # chroma bleeds; the bake's robust test leaves such pixels out)
    assert (seg.neck & collar).sum() < 0.02 * collar.sum()
    assert not (seg.neck & tie).any()
    ys = np.nonzero(seg.neck)[0]
    assert ys.max() < 430 and ys.min() > face.points[27][1]
    grey = np.repeat(np.ascontiguousarray(skimage.data.camera())[..., None], 3, 2)
    assert not segment(grey, detect_face(grey, "mesh"), hands=False).neck.any()


def _layer_view(rgb8):
    """A fit's view as ``outputs.photo_layer`` reads it, from the segmentation (what
    ``fitter._init_silhouette`` keeps, the neck included)."""
    from types import SimpleNamespace

    from hack_render.vision.segment import segment

    face = detect_face(rgb8, "mesh")
    seg = segment(rgb8, face, hands=False)
    return SimpleNamespace(hair=seg.hair, occluder=seg.occluder, clothes=seg.clothes,
                           skin=seg.skin & (seg.face > 0.5) | seg.neck, face=seg.face > 0.5,
                           detection=face, photo=SimpleNamespace(width=rgb8.shape[1])), face


def test_the_composite_keeps_the_photo_below_the_face():
    """``render_over_photo.png`` keeps the photo in front of the model's neck and chest
    wherever the photo below the face is not the person's skin (``vision.neck.below_face``):
    the cameraman's gloved hand and black coat under his chin were covered by a grey slab
    of the model's chest (a grey photo: no skin test, no clothes found); on Grace Hopper
    her collar, tie and the background beside her neck stay the photo's and her neck,
    skin the bake took, the model's. Her face and his stay the model's. Above the brows
    and outside the oval (``vision.neck.above_brows``) her cap and the flag stay the
    photo's, her forehead the model's."""
    import matplotlib.cbook
    import skimage.data
    from PIL import Image

    from hack_render.fit.outputs import photo_layer
    from hack_render.vision.neck import above_brows, below_face

    grey = np.repeat(np.ascontiguousarray(skimage.data.camera())[..., None], 3, 2)
    view, face = _layer_view(grey)
    h, w = grey.shape[:2]
    layer = photo_layer(view, h, w)
    below = below_face(face.points, (h, w)) & (view.face is not None) & ~view.face
    person_below = below & (grey.mean(-1) < 60)        # his dark coat and glove
    assert person_below.sum() > 3000
    assert (layer[person_below] > 0.5).mean() > 0.95
    cheek = view.skin & view.face & ~below
    assert cheek.sum() > 500 and (layer[cheek] < 0.5).mean() > 0.95

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        grace = np.asarray(Image.open(f).convert("RGB"))
    view, face = _layer_view(grace)
    h, w = grace.shape[:2]
    layer = photo_layer(view, h, w)
    neck = np.zeros((h, w), bool)
    neck[350:400, 235:295] = True
    assert (layer[neck & view.skin] < 0.5).mean() > 0.95
    lum, spread = grace.mean(-1), np.ptp(grace.astype(int), -1)
    collar = (lum > 200) & (spread < 25)
    collar[:380] = False
    tie = lum < 30
    tie[:420] = False
    assert (layer[collar] > 0.5).mean() > 0.95 and (layer[tie] > 0.5).mean() > 0.95
    sky = below_face(face.points, (h, w)) & ~view.face & (np.ptp(grace.astype(int), -1) > 60) \
        & (grace[..., 2].astype(int) > grace[..., 0].astype(int) + 40)   # the blue beside her
    assert sky.sum() > 1000 and (layer[sky] > 0.5).mean() > 0.95
    # above the brows: her cap and the flag outside the oval stay the photo's (the model
    # has no hair and no cap: its bare scalp showed where the segmentation missed hair),
    # her forehead's skin inside the oval is the model's
    up = above_brows(face.points, (h, w))
    cap = up & ~view.face
    forehead = up & view.face & view.skin
    assert cap.sum() > 20000 and forehead.sum() > 2000
    assert (layer[cap] > 0.5).mean() > 0.95 and (layer[forehead] < 0.5).mean() > 0.95
    assert not up[face.points[36:48, 1].astype(int), face.points[36:48, 0].astype(int)].any()
