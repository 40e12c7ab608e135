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
