"""hack_render.io: atomic writes (one temporary beside the target, renamed; none left on a
failure), and (io.image) the sRGB 8-bit encoder: colour-science's rounding, from cached
thresholds."""

import numpy as np
import pytest

from hack_render import io
from hack_render.errors import HackError
from hack_render.io import image
from hack_render.io.npz import write_npz


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    image.srgb8_thresholds.cache_clear()
    yield tmp_path / "hack-render" / image.SRGB8_CACHE
    image.srgb8_thresholds.cache_clear()


def test_01_thresholds_give_colour_sciences_codes(fresh_cache):
    colour = pytest.importorskip("colour")
    rng = np.random.default_rng(0)
    t = image.srgb8_thresholds()
    x = np.concatenate([rng.random(200_000) * 1.2 - 0.1, t + 1e-9, t - 1e-9, [0.0, 1.0]])
    want = np.round(np.clip(colour.cctf_encoding(np.clip(x, 0, 1), function="sRGB"), 0, 1)
                    * 255).astype(np.uint8)
    assert np.array_equal(image.to_srgb8(x, 0.0, "clip"), want)


def test_02_cache_is_written_reused_and_repaired(fresh_cache):
    t = image.srgb8_thresholds()
    assert fresh_cache.is_file() and np.array_equal(np.load(fresh_cache), t)
    image.srgb8_thresholds.cache_clear()
    np.save(fresh_cache, np.zeros(255))  # not increasing: recomputed
    assert np.array_equal(image.srgb8_thresholds(), t)
    image.srgb8_thresholds.cache_clear()
    fresh_cache.write_bytes(b"not a numpy file")
    assert np.array_equal(image.srgb8_thresholds(), t)
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
    out = image.straight_colour(pre, alpha)
    solid = alpha >= 0.5
    assert np.allclose(out[solid], pre[solid] / alpha[solid][:, None])
    edge = (alpha > 0) & ~solid
    assert edge.sum() > 20 and np.abs(out[edge] - colour).max() < 0.1
    assert (out[alpha == 0] == 0).all()


# ------------------------------------------------------------------------ atomic writes


def test_04_atomic_writers_leave_the_file_whole_and_no_temporary(tmp_path):
    """Bytes, text, JSON and .npz land whole; a failed write keeps the old file and leaves
    no temporary; the folder is created."""
    d = tmp_path / "a" / "b"
    assert io.atomic_write_bytes(d / "x.bin", b"\x00\x01") == d / "x.bin"
    assert (d / "x.bin").read_bytes() == b"\x00\x01"
    io.atomic_write_text(d / "x.txt", "héllo\n")
    assert (d / "x.txt").read_text(encoding="utf-8") == "héllo\n"
    io.write_json(d / "x.json", {"b": 1, "a": [1.5]}, indent=None, sort_keys=True)
    assert (d / "x.json").read_text() == '{"a": [1.5], "b": 1}'
    write_npz(d / "arrays.dat", {"a": np.arange(3)}, compressed=True)  # no .npz added
    assert np.array_equal(np.load(d / "arrays.dat")["a"], np.arange(3))
    with pytest.raises(ZeroDivisionError):
        with io.atomic_path(d / "x.txt") as tmp:
            tmp.write_text("partial")
            1 / 0
    assert (d / "x.txt").read_text(encoding="utf-8") == "héllo\n"
    assert sorted(p.name for p in d.iterdir()) == ["arrays.dat", "x.bin", "x.json", "x.txt"]


def test_05_temporaries_are_short_hidden_and_found_by_their_target(tmp_path):
    """Any legal name (255 bytes) can be written; a temporary keeps the target's suffix
    (writers choose formats by it) and matches temp_glob of its target, not another's."""
    long = "n" * 250 + ".json"
    io.write_json(tmp_path / long, [1])
    assert (tmp_path / long).read_text() == "[\n 1\n]"
    with io.atomic_path(tmp_path / "frame_0001.png") as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png" and len(tmp.name) < 30
        assert tmp.name.startswith(io.TEMP_PREFIX) and tmp.match(io.TEMP_GLOB)
        assert tmp.match(io.temp_glob(tmp_path / "frame_0001.png"))
        assert not tmp.match(io.temp_glob("frame_0002.png"))
    assert io.temp_glob("frame_0001.png") == io.temp_glob(tmp_path / "frame_0001.png")


def test_06_a_full_disk_at_the_rename_keeps_the_old_file(tmp_path, monkeypatch):
    import errno
    import os

    io.atomic_write_text(tmp_path / "x.txt", "old")

    def full(src, dst, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(dst))

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OSError, match="No space"):
        io.atomic_write_text(tmp_path / "x.txt", "new")
    monkeypatch.undo()
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]
    assert (tmp_path / "x.txt").read_text() == "old"


def test_07_an_unwritable_folder_is_named(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(HackError, match="cannot be created"):
        io.atomic_write_text(tmp_path / "file" / "x.txt", "x")


def test_08_the_atomic_writers_import_the_standard_library_only():
    """hack_render.boundary writes its run records through hack_render.io and is imported
    by ``hack-render --help``: io's package imports nothing heavy (image.py and npz.py do)."""
    import subprocess
    import sys

    code = ("import sys, hack_render.io\n"
            "print(sorted(m for m in ('numpy', 'OpenEXR', 'imageio', 'torch', "
            "'hack_render.io.image') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]", out.stdout
