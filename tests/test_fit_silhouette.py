"""The silhouette term: plain-background segmentation (and its refusal of a cluttered
one), the signed distance map, the model's outer contour, and a synthetic recovery:
with the true person mask the shape fit lands nearer the true face than without."""

import warnings

import numpy as np
import pytest
import torch

from hack_render.errors import HackError
from hack_render.fit.silhouette import PhotoSilhouette, load_mask, segment_plain_background


def _disc(res=96, c=(50.0, 44.0), r=25.0):
    yy, xx = np.mgrid[0:res, 0:res] + 0.5
    return (xx - c[0]) ** 2 + (yy - c[1]) ** 2 < r * r


def _points_in(c, r, n=68):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[c[0] + 0.5 * r * np.cos(a), c[1] + 0.5 * r * np.sin(a)]


def test_01_plain_background_segmented_cluttered_refused():
    rng = np.random.default_rng(0)
    disc = _disc()
    img = np.full(disc.shape + (3,), 0.93, np.float32) + 0.01 * rng.standard_normal(
        disc.shape + (3,)).astype(np.float32)
    img[disc] = [0.7, 0.5, 0.4]
    img[40:46, 40:60] = [0.95, 0.95, 0.95]  # a background-coloured patch inside: filled
    m, why = segment_plain_background(img, _points_in((50, 44), 25))
    assert why == "" and m is not None
    iou = (m & disc).sum() / (m | disc).sum()
    assert iou > 0.97, iou
    clutter = rng.random(img.shape).astype(np.float32)
    clutter[disc] = [0.7, 0.5, 0.4]
    m, why = segment_plain_background(clutter, _points_in((50, 44), 25))
    assert m is None and "not plain" in why
    # a plain background, but the face is not on the foreground region
    m, why = segment_plain_background(img, _points_in((10, 85), 4))
    assert m is None and why


def test_01b_shading_through_the_background_colour_keeps_the_person_whole():
    """A side light's terminator: the person's shading passes through the backdrop's
    colour along a thin band that cracks the colour key in two (as on a dark studio
    backdrop); the mask is still the whole person, not the half holding the face."""
    rng = np.random.default_rng(1)
    disc = _disc()
    img = np.full(disc.shape + (3,), 0.22, np.float32) + 0.005 * rng.standard_normal(
        disc.shape + (3,)).astype(np.float32)
    xx = np.mgrid[0:96, 0:96][1] + 0.5
    lit = disc & (xx < 47)
    img[lit] = [0.85, 0.7, 0.6]
    img[disc & (xx > 49)] = [0.05, 0.03, 0.02]           # the shadowed half
    img[disc & (xx >= 47) & (xx <= 49)] = 0.22           # the terminator: backdrop-coloured
    m, why = segment_plain_background(img, _points_in((58, 44), 16))
    assert why == "" and m is not None
    iou = (m & disc).sum() / (m | disc).sum()
    assert iou > 0.95, iou
    assert m[lit].mean() > 0.97 and m[disc & (xx > 49)].mean() > 0.97


def test_01d_shadowed_skin_as_bright_as_the_backdrop_kept_by_its_chromaticity():
    """A shadow that darkens a side of the face to the backdrop's brightness opens a gap
    onto the background (no hole to fill): the colour key drops it, the chromaticity
    step gives it back. On a backdrop of the skin's own chromaticity nothing is grown
    (the key's mask is kept as it is), and no backdrop pixel is ever added."""
    rng = np.random.default_rng(3)
    disc = _disc()
    xx = np.mgrid[0:96, 0:96][1] + 0.5
    shadow = disc & (xx > 62)                      # the right third of the face
    skin = np.array([0.62, 0.45, 0.36], np.float32)

    def photo(backdrop, shadow_rgb):
        img = np.broadcast_to(np.asarray(backdrop, np.float32), disc.shape + (3,)).copy()
        img += 0.004 * rng.standard_normal(img.shape).astype(np.float32)
        img[disc] = skin
        img[shadow] = shadow_rgb
        return img

    grey = 0.22
    # the shadowed skin: the skin's chromaticity at the grey backdrop's brightness
    dark = skin * (3 * grey / skin.sum())
    m, why = segment_plain_background(photo([grey] * 3, dark), _points_in((44, 44), 16))
    assert why == "" and m is not None
    assert m[shadow].mean() > 0.95, m[shadow].mean()
    assert (m & ~disc).sum() <= 0.01 * disc.sum()
    iou = (m & disc).sum() / (m | disc).sum()
    assert iou > 0.97, iou
    # the key alone (the step off: a backdrop of the shadow's own chromaticity) loses it
    beige = dark * (1.0 + 0.02 * np.array([1, 0, -1], np.float32))
    m2, why = segment_plain_background(photo(beige, dark), _points_in((44, 44), 16))
    assert m2 is not None
    assert m2[shadow].mean() < 0.5 and (m2 & ~disc).sum() <= 0.01 * disc.sum()


def test_01c_backdrop_of_one_colour_per_row_segmented():
    """A horizon behind the person (sky above, ground below, each with a vertical
    gradient: one colour per row, not one colour) gives a mask; a backdrop whose left
    and right edges differ row by row does not."""
    rng = np.random.default_rng(2)
    disc = _disc()
    yy = np.mgrid[0:96, 0:96][0][..., None] / 96.0
    img = np.where(yy < 0.55, np.array([0.6, 0.7, 0.85]) + 0.2 * yy,
                   np.array([0.35, 0.33, 0.3]) - 0.1 * yy).astype(np.float32)
    img += 0.005 * rng.standard_normal(img.shape).astype(np.float32)
    img[disc] = [0.85, 0.65, 0.55]
    m, why = segment_plain_background(img, _points_in((50, 44), 25))
    assert why == "" and m is not None
    iou = (m & disc).sum() / (m | disc).sum()
    assert iou > 0.97, iou
    halves = img.copy()
    halves[:, 48:] = rng.random((96, 1, 3)).astype(np.float32)  # right edge: other colours
    halves[disc] = [0.85, 0.65, 0.55]
    m, why = segment_plain_background(halves, _points_in((50, 44), 25))
    assert m is None and "rows" in why


def test_02_signed_distance_and_its_gradient():
    c, r = (50.0, 44.0), 25.0
    sil = PhotoSilhouette.from_mask(_disc(c=c, r=r), "test")
    rng = np.random.default_rng(1)
    uv = torch.tensor(rng.uniform(15, 85, (200, 2)), requires_grad=True)
    d, ok = sil.distance(uv)
    assert bool(ok.all())
    true = np.linalg.norm(uv.detach().numpy() - c, axis=1) - r
    assert np.abs(d.detach().numpy() - true).max() < 0.8
    # the gradient points away from the centre (outward normal of the disc) off the centre
    d.sum().backward()
    g = uv.grad.numpy()
    radial = (uv.detach().numpy() - c) / np.linalg.norm(uv.detach().numpy() - c, axis=1)[:, None]
    far = np.linalg.norm(uv.detach().numpy() - c, axis=1) > 6
    cos = (g[far] * radial[far]).sum(1) / np.linalg.norm(g[far], axis=1)
    assert np.median(cos) > 0.95
    # outside the photo nothing is known
    _, ok = sil.distance(torch.tensor([[-3.0, 40.0], [40.0, 200.0], [40.0, 40.0]]))
    assert ok.tolist() == [False, False, True]
    with pytest.raises(HackError, match="both"):
        PhotoSilhouette.from_mask(np.zeros((8, 8), bool), "test")


def test_03_mask_file_checked(tmp_path):
    import imageio.v3 as iio

    m = np.zeros((20, 30), np.uint8)
    m[4:14, 10:20] = 255
    iio.imwrite(tmp_path / "m.png", m)
    np.testing.assert_array_equal(load_mask(tmp_path / "m.png", (20, 30)), m > 0)
    # a photo downscaled on the way in: the original-size mask follows it
    half = load_mask(tmp_path / "m.png", (10, 15), original=(20, 30))
    np.testing.assert_array_equal(half, m[::2, ::2] > 0)
    with pytest.raises(HackError, match="size"):
        load_mask(tmp_path / "m.png", (30, 20))
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(HackError, match="cannot read"):
        load_mask(tmp_path / "bad.png", (20, 30))


@pytest.fixture(scope="module")
def subject():
    from synthetic import landmark_view

    from hack_render.geometry import load_default_model

    torch.set_num_threads(1)
    model = load_default_model()
    beta = torch.zeros(1, 20)
    beta[0, :6] = torch.tensor([2.0, -1.5, 1.5, 1.0, -1.0, 1.2])
    return model, beta, landmark_view(model, beta=beta, angles_deg=(4.0, 20.0, 2.0),
                                      res=256, name="sil", mask=True)


def _fit(model, view, mask, mode, check=True):
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter

    cfg = load_config(None, {"camera": {"iterations": 60},
                             "shape": {"iterations": 80, "n_beta": 20},
                             "silhouette": {"mode": mode, "check": check}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = Fitter([view[0]], [view[1]], cfg, model=model, appearance=None, progress=False,
                   masks=[mask])
        f.fit_camera()
        f.fit_shape()
    return f


def test_04_outer_contour_and_recovery(subject):
    from hack_render.fit.metrics import similarity_error

    model, beta, (photo, det, mask) = subject
    with_sil = _fit(model, (photo, det), mask, "auto")
    without = _fit(model, (photo, det), mask, "off")
    v = with_sil.state.views[0]
    assert v.silhouette_note == "mask file" and without.state.views[0].silhouette is None
    pairs, t = v.sil_contour
    # the outer contour: points on mesh edges (zero crossings of n.v), on the face/neck
    # outline; contours hidden inside the footprint (the jaw's over the neck) left out
    assert len(t) > 40 and bool(((t >= 0) & (t <= 1)).all())
    with torch.no_grad():
        out = with_sil.forward(v)
        pts = with_sil.state.silhouette.points(out.vertices[0], pairs, t)
        d, ok = v.silhouette.distance(with_sil.project(v, pts))
    assert float(d[ok].abs().median()) < 1.0
    with torch.no_grad():
        true = model(beta=beta).vertices[0][:9409].numpy()
    err = {}
    for name, f in (("with", with_sil), ("without", without)):
        with torch.no_grad():
            rest = model(beta=f.state.beta, psi=f.state.psi).vertices[0][:9409].numpy()
        err[name] = similarity_error(rest, true)
    assert err["with"] < 0.9 * err["without"], err


def test_04c_a_mask_cut_by_an_object_in_front_of_the_face_is_dropped(subject):
    """The true mask with the face's near half cut away (a camera held in front of it,
    as in the cameraman's photo: the person segmentation leaves the object out): its
    border there is the object's, and the silhouette term pulls the fitted points off
    the landmarks. The shape stage run with and without it finds so and drops it (a
    note says why); the true mask is kept (test_04)."""
    from hack_render.fit.geometric import SILHOUETTE_MARGIN_IOD
    from hack_render.fit.terms import fitted_points, landmark_residual_iod

    model, _beta, (photo, det, mask) = subject
    cut = mask.copy()
    p = det.points
    x0 = int(p[27:36, 0].mean())   # from the nose to the far cheek: gone
    y0, y1 = int(p[19:25, 1].min()), int(p[8, 1])
    cut[y0:y1, x0:] = False
    res = {}
    for check in (False, True):
        f = _fit(model, (photo, det), cut, "auto", check=check)
        v = f.state.views[0]
        res[check] = (landmark_residual_iod(v, fitted_points(f.state, f.cfg, v)), v)
    names = [r.name for r in f.reports]   # "shape" is the run kept, without the mask
    assert names.count("shape") == 1 and "shape (with the masks, not kept)" in names, names
    assert res[False][1].silhouette is not None
    assert res[True][1].silhouette is None
    note = res[True][1].silhouette_note
    assert note.startswith("dropped (mask file)"), note
    assert res[True][0] + SILHOUETTE_MARGIN_IOD < res[False][0], (res[True][0], res[False][0])


def test_04b_contour_crossings_lie_on_the_true_outline(subject):
    """On the true mesh seen by the true camera, the contour crossings kept as the outline
    lie on the true mask's border: at ``border_depth`` 1 (the default) their mean signed
    distance is within 0.4 px and under 5 % lie over 2 px inside. At 2.5 (the previous
    default) the ears' and cheeks' inner contours were kept too: a mean further inside,
    which pulled the fit wider."""
    from hack_render.fit.fitter import R0
    from hack_render.fit.silhouette import ModelSilhouette
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render.bridge import vertex_normals_torch
    from scenes.cameras import Camera

    model, beta, (_photo, det, mask) = subject
    ang = torch.deg2rad(torch.tensor([4.0, 20.0, 2.0]))
    with torch.no_grad():
        V = model(beta=beta, theta=distribute_head_rotation(ang)[None]).vertices[0]
    n = vertex_normals_torch(V, model.faces).numpy().astype(np.float64)
    V = V.numpy().astype(np.float64)
    f = 50.0 / 36.0 * 256 * 2.2
    cam = Camera(np.array([[f, 0, 128], [0, f, 128], [0, 0, 1.0]]),
                 R0.numpy().astype(np.float64), np.array([0.0, -0.03, 1.0]), 256, 256, "v")
    sdf = PhotoSilhouette.from_mask(mask, "truth")
    stats = {}
    for depth in (1.0, 2.5):
        sil = ModelSilhouette(model, border_depth=depth)
        pairs, t = sil.select_contour(V, n, -cam.R.T @ cam.t, cam.project, mask.shape,
                                      max(det.size / 60.0, 0.5))
        pts = V[pairs[:, 0]] + t[:, None] * (V[pairs[:, 1]] - V[pairs[:, 0]])
        d, ok = sdf.distance(torch.as_tensor(cam.project(pts), dtype=torch.float32))
        d = d[ok].numpy()
        stats[depth] = (len(d), float(d.mean()), float((d < -2.0).mean()))
    count, mean, deep = stats[1.0]
    assert count > 100 and abs(mean) < 0.4 and deep < 0.05, stats
    # here (skin triangles only in the mask) 2.5 gives -0.18 px and 2.6 % over 2 px
    # inside against -0.04 px and none; on full renders -0.7 px and a sixth (README)
    assert stats[2.5][0] > count and stats[2.5][1] < mean - 0.1 and stats[2.5][2] > deep, stats


def test_05_one_mask_per_photo(tmp_path):
    from hack_render.fit.cli import fit_photos

    with pytest.raises(HackError, match="one mask per photo"):
        fit_photos([tmp_path / "a.png", tmp_path / "b.png"], tmp_path / "out",
                   masks=[tmp_path / "m.png"])


def test_06_cli_takes_a_mask_file(tmp_path, subject):
    """`hack-render fit PHOTO --landmarks F --mask M`: the fit uses the mask (the report
    says so) and runs to its outputs. In process (the CLI's argument parsing and exit
    code, not a subprocess: test_fit_e2e.py test_02 runs `hack-render fit` as one)."""
    import json

    import imageio.v3 as iio

    from hack_render.cli import main

    _, _, (photo, det, mask) = subject
    iio.imwrite(tmp_path / "p.png", photo.uint8())
    np.save(tmp_path / "p.npy", det.points)
    iio.imwrite(tmp_path / "m.png", (mask * 255).astype(np.uint8))
    (tmp_path / "c.json").write_text(json.dumps(
        {"camera": {"iterations": 10}, "shape": {"iterations": 10, "n_beta": 10},
         "photometric": {"enabled": False}, "landmarks": {"files_follow": "vertices"},
         # 10 iterations: mid-way, the mask's pull on the points says nothing of the mask
         "silhouette": {"check": False}}))
    try:
        main(["fit", str(tmp_path / "p.png"), "--landmarks", str(tmp_path / "p.npy"),
              "--mask", str(tmp_path / "m.png"), "--config", str(tmp_path / "c.json"),
              "-o", str(tmp_path / "out"), "--quiet"])
        code = 0
    except SystemExit as exc:
        code = exc.code
    assert code in (0, None), code
    rep = json.loads((tmp_path / "out" / "fit_report.json").read_text())
    assert rep["views"][0]["silhouette"] == "mask file", rep["views"][0]["silhouette"]
    stages = {s["name"]: s for s in rep["stages"]}
    assert stages["shape"]["iterations"] == 10


def _tight_crop() -> np.ndarray:
    """The astronaut's face, cropped tight (1.4 x dlib's box) and resized to 224 x 224:
    the usual format of face datasets."""
    from skimage import data, transform

    face = data.astronaut()[50:177, 156:283]
    return (transform.resize(face, (224, 224), anti_aliasing=True) * 255).round().astype(
        np.uint8)


@pytest.mark.parametrize("found", [0.0, 1.0], ids=["no-person", "all-person"])
def test_07_a_tight_face_crop_fits_on_without_the_silhouette(monkeypatch, found):
    """A segmentation with no person pixels, or no background ones, on a 224 x 224 tight
    face crop stopped the fit with exit 2 ("silhouette mask (segmentation): expected a 2-D
    mask with both person and background pixels, found shape (224, 224) with 0 person
    pixels"; issue 65). Such a crop has no outline to fit: the fit goes on without the
    term, the report's view says why, and a warning says so; only a photo without a face
    is refused."""
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.landmarks import detect
    from hack_render.fit.photo import from_array
    from hack_render.fit.stages import FitWarning
    from hack_render.vision import segment as vision_segment

    real = vision_segment.segment

    def segment(rgb8, *args, **kwargs):  # the segmenter's answer on such crops
        seg = real(rgb8, *args, **kwargs)
        seg.person = np.full_like(seg.person, found)
        return seg

    monkeypatch.setattr(vision_segment, "segment", segment)
    photo = from_array(_tight_crop(), "crop.png")
    det = detect(photo.uint8(), None, photo.name)
    cfg = load_config(None, {"camera": {"iterations": 3}, "shape": {"iterations": 3}})
    with pytest.warns(FitWarning, match=r"crop.png: the person segmentation found no "
                      r"(person|background) pixels.*fitting without the silhouette term"):
        f = Fitter([photo], [det], cfg, appearance=None, progress=False)
    view = f.state.views[0]
    assert view.silhouette is None
    note = view.silhouette_note  # the report's views[0].silhouette
    assert note.startswith("none: ") and "segmentation: no" in note and "224 x 224" in note
    f.fit_camera()
    f.fit_shape()
    assert np.isfinite(f.state.beta.detach().numpy()).all()


def test_08_a_mask_file_keeps_the_segmentations_occluders_and_hair():
    """A person mask file (``--mask``) is the silhouette's, and the segmentation still
    gives the skin, hair and occluder masks: before, a mask file skipped them, so the bake
    took the hair and whatever covered the face as skin and ``render.png`` had no hair
    (the cameraman's photo with his own person mask: the bake saw 46 % of the face
    instead of 13 %). The same photo without the file gives the same masks."""
    pytest.importorskip("mediapipe")
    from skimage import data

    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.landmarks import detect
    from hack_render.fit.photo import from_array

    img = data.astronaut()
    photo = from_array(img, "astronaut.png")
    det = detect(photo.uint8(), None, photo.name)
    cfg = load_config(None, {"silhouette": {"check": False}})
    mask = np.zeros(img.shape[:2], bool)
    mask[20:, 100:420] = True
    views = [Fitter([photo], [det], cfg, appearance=None, progress=False,
                    masks=m).state.views[0] for m in ([mask], None)]
    filed, auto = views
    assert filed.silhouette_note == "mask file" and auto.silhouette_note != "mask file"
    for name in ("skin", "hair", "occluder", "clothes"):
        assert getattr(filed, name) is not None, name
        np.testing.assert_array_equal(getattr(filed, name), getattr(auto, name))
    assert filed.hair.sum() > 1000 and filed.skin.sum() > 1000
