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
