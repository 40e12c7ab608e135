"""The sRGB 8-bit encoder: colour-science's rounding, from cached thresholds."""

import numpy as np
import pytest

from hack_render.render import image_io as io


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    io.srgb8_thresholds.cache_clear()
    yield tmp_path / "hack-render" / io.SRGB8_CACHE
    io.srgb8_thresholds.cache_clear()


def test_01_thresholds_give_colour_sciences_codes(fresh_cache):
    colour = pytest.importorskip("colour")
    rng = np.random.default_rng(0)
    t = io.srgb8_thresholds()
    x = np.concatenate([rng.random(200_000) * 1.2 - 0.1, t + 1e-9, t - 1e-9, [0.0, 1.0]])
    want = np.round(np.clip(colour.cctf_encoding(np.clip(x, 0, 1), function="sRGB"), 0, 1)
                    * 255).astype(np.uint8)
    assert np.array_equal(io.to_srgb8(x, 0.0, "clip"), want)


def test_02_cache_is_written_reused_and_repaired(fresh_cache):
    t = io.srgb8_thresholds()
    assert fresh_cache.is_file() and np.array_equal(np.load(fresh_cache), t)
    io.srgb8_thresholds.cache_clear()
    np.save(fresh_cache, np.zeros(255))  # not increasing: recomputed
    assert np.array_equal(io.srgb8_thresholds(), t)
    io.srgb8_thresholds.cache_clear()
    fresh_cache.write_bytes(b"not a numpy file")
    assert np.array_equal(io.srgb8_thresholds(), t)
    assert np.array_equal(np.load(fresh_cache), t)
