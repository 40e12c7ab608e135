"""hack_render.io: atomic writes (one temporary beside the target, renamed; none left on a
failure), and the sRGB 8-bit encoder: colour-science's rounding, from cached thresholds."""

import numpy as np
import pytest

from hack_render import io


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


def test_03_straight_colour_pads_the_thin_edge_with_the_covered_colour():
    """A disc of one colour over a transparent background, its edge pixels' premultiplied
    colour noisy: where alpha is tiny, colour / alpha is a saturated speck; the straight
    colour takes the nearest mostly covered pixel's there, is exact where alpha >= 0.5
    and 0 where alpha is 0."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:32, 0:32] + 0.5
    r = np.hypot(yy - 16, xx - 16)
    alpha = np.clip(10.5 - r, 0.0, 1.0)
    alpha[(r >= 10.5) & (r < 11.5)] = 0.002   # a ring the samples barely touched
    colour = np.array([0.6, 0.4, 0.3])
    pre = alpha[..., None] * colour + rng.normal(0, 0.01, (32, 32, 3)) * (alpha > 0)[..., None]
    naive = np.where((alpha > 0)[..., None], pre / np.maximum(alpha, 1e-6)[..., None], 0.0)
    assert np.abs(naive - colour)[alpha > 0].max() > 1.0   # the specks the padding removes
    out = io.straight_colour(pre, alpha)
    solid = alpha >= 0.5
    assert np.allclose(out[solid], pre[solid] / alpha[solid][:, None])
    edge = (alpha > 0) & ~solid
    assert edge.sum() > 20 and np.abs(out[edge] - colour).max() < 0.1
    assert (out[alpha == 0] == 0).all()
