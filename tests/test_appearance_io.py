"""Texture IO: EXR/PNG round trips and errors that name the folder and file."""

import numpy as np
import pytest

from appearance.texture_io import (
    read_exr,
    read_png,
    read_texture_set,
    write_exr,
    write_png,
    write_texture_set,
)
from hack_render.errors import HackError


def test_exr_float32_round_trip_exact_multichannel(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.normal(size=(7, 14, 5)).astype(np.float32)
    names = ["diffuse.R", "diffuse.G", "diffuse.B", "spec", "z_extra"]
    write_exr(tmp_path / "a.exr", img, channels=names)
    back, got = read_exr(tmp_path / "a.exr")
    assert sorted(got) == sorted(names)
    for i, n in enumerate(names):
        np.testing.assert_array_equal(back[..., got.index(n)], img[..., i])


def test_exr_half_round_trip(tmp_path):
    img = np.random.default_rng(1).random((4, 8, 3)).astype(np.float32)
    write_exr(tmp_path / "h.exr", img, half=True)
    back, names = read_exr(tmp_path / "h.exr")
    assert back.dtype == np.float16 and names == ["R", "G", "B"]
    np.testing.assert_array_equal(back, img.astype(np.float16))


@pytest.mark.parametrize("bits,channels", [(8, 3), (16, 1), (16, 3), (16, 4)])
def test_png_round_trip_within_quantisation(tmp_path, bits, channels):
    img = np.random.default_rng(2).random((6, 12, channels))
    write_png(tmp_path / "p.png", img, bits=bits, srgb=True)
    back = read_png(tmp_path / "p.png", srgb=True)
    from appearance.colour_space import srgb_encode

    step = 1.0 / (255 if bits == 8 else 65535)
    assert np.abs(srgb_encode(back) - srgb_encode(img)).max() <= 0.5 * step + 1e-6


def _subject(folder, h=8, **override):
    maps = {"diffuse": np.full((h, 2 * h, 3), 0.4, np.float32),
            "specular": np.full((h, 2 * h, 1), 0.5, np.float32),
            "normal": np.tile(np.float32([0, 0, 1]), (h, 2 * h, 1))}
    maps.update(override)
    write_texture_set(folder, maps)
    return maps


def test_texture_set_round_trip(tmp_path):
    maps = _subject(tmp_path / "s0")
    back = read_texture_set(tmp_path / "s0")
    assert set(back) == set(maps)
    for k in maps:
        np.testing.assert_array_equal(back[k], maps[k])


def test_missing_map_names_folder(tmp_path):
    _subject(tmp_path / "s1")
    (tmp_path / "s1" / "specular.exr").unlink()
    with pytest.raises(HackError, match=r"s1.*specular"):
        read_texture_set(tmp_path / "s1")


def test_mismatched_resolution_names_file(tmp_path):
    _subject(tmp_path / "s2")
    write_exr(tmp_path / "s2" / "normal.exr", np.ones((4, 8, 3), np.float32))
    with pytest.raises(HackError, match=r"s2/normal\.exr.*resolution"):
        read_texture_set(tmp_path / "s2")


def test_wrong_channel_count_names_file(tmp_path):
    _subject(tmp_path / "s3")
    write_exr(tmp_path / "s3" / "specular.exr", np.ones((8, 16, 3), np.float32))
    with pytest.raises(HackError, match=r"s3/specular\.exr.*1 channel"):
        read_texture_set(tmp_path / "s3")


def test_nan_texel_names_file_and_position(tmp_path):
    d = np.full((8, 16, 3), 0.4, np.float32)
    d[2, 5, 1] = np.nan
    (tmp_path / "s4").mkdir()
    _subject(tmp_path / "s4")
    write_exr(tmp_path / "s4" / "diffuse.exr", d)
    with pytest.raises(HackError, match=r"s4/diffuse\.exr.*row 2, column 5"):
        read_texture_set(tmp_path / "s4")


def test_non_image_file_is_a_hack_error(tmp_path):
    _subject(tmp_path / "s5")
    (tmp_path / "s5" / "normal.exr").write_text("not an image")
    with pytest.raises(HackError, match=r"s5/normal\.exr"):
        read_texture_set(tmp_path / "s5")


def test_bad_set_writes_nothing(tmp_path):
    good = np.zeros((8, 16, 3), np.float32)
    bad = np.zeros((8, 16, 2), np.float32)
    with pytest.raises(HackError):
        write_texture_set(tmp_path / "out", {"diffuse": good, "normal": bad})
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
