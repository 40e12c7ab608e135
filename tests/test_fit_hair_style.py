"""The photo's hair read as a style of the hair layer (fit/hair_style.py, issue 61)."""

from __future__ import annotations

import numpy as np
import pytest

from hack_render.fit.hair_style import hair_style_from_photo
from hack_render.geometry.model_file import default_model_path
from hack_render.geometry.posing import PosingModel
from hack_render.hair.style import albedo_melanin, slab_albedo

SIZE = 440


@pytest.fixture(scope="module")
def points():
    """The mean head's 68 landmarks seen from the front, 1 px = 1 mm, face centred."""
    m = PosingModel.from_file(default_model_path())
    lm = m.template[m.arrays["landmark_indices"]]
    return np.stack([SIZE / 2 + lm[:, 0] * 1000, 260 - lm[:, 1] * 1000], -1)


def _mask(points, top_mm: float, bottom_mm: float, half_width_mm: float,
          line_mm: float) -> np.ndarray:
    """Hair: an outline from ``top_mm`` over the brows down to ``bottom_mm`` below them
    beside the face, and over the forehead down to ``line_mm`` over the brows."""
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    brow = points[17:27, 1].mean()
    cx = points[[36, 45], 0].mean()
    face = abs(points[16, 0] - points[0, 0]) / 2
    outer = (np.abs(xx - cx) < half_width_mm) & (yy > brow - top_mm) & (yy < brow + bottom_mm)
    face_zone = (np.abs(xx - cx) < face) & (yy > brow - line_mm)
    return outer & ~face_zone


def _photo(points, hair, hair_rgb, light=(0.9, 0.85, 0.8)):
    photo = np.zeros((SIZE, SIZE, 3))
    skin = np.zeros((SIZE, SIZE), bool)
    cx, cy = points[30]
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    skin[(np.abs(xx - cx) < 40) & (np.abs(yy - cy) < 40)] = True
    skin &= ~hair
    photo[skin] = np.array([0.5, 0.35, 0.28]) * light
    photo[hair] = np.asarray(hair_rgb) * light
    return photo, skin


@pytest.mark.parametrize("name,top,bottom,width,expected", [
    ("long", 100, 230, 95, "long"), ("bob", 90, 115, 95, "bob"),
    ("short", 120, 30, 92, "short"), ("crew", 90, 20, 88, "crew"),
    ("afro", 110, 60, 210, "afro")])
def test_the_outline_picks_the_archetype(points, name, top, bottom, width, expected):
    hair = _mask(points, top, bottom, width, 60)
    photo, skin = _photo(points, hair, slab_albedo(1.3, 0.1))
    style, report = hair_style_from_photo(photo, hair, skin, points, [0.5, 0.35, 0.28])
    assert style.archetype == expected, report
    # a crew cut is not parted (no scalp line on top); the rest keep the base's parting
    assert style.parting == ("none" if expected == "crew" else "left")


def test_no_hair_is_bald_and_a_receding_line_is_read(points):
    photo, skin = _photo(points, np.zeros((SIZE, SIZE), bool), (0, 0, 0))
    style, _ = hair_style_from_photo(photo, np.zeros((SIZE, SIZE), bool), skin, points,
                                     [0.5, 0.35, 0.28])
    assert style.bald
    full = hair_style_from_photo(*_args(points, line=62))[0]
    receded = hair_style_from_photo(*_args(points, line=110))[0]
    assert full.hairline < 0.15 and receded.hairline > 0.5


def _args(points, line):
    hair = _mask(points, 120, 30, 92, line)
    photo, skin = _photo(points, hair, slab_albedo(1.3, 0.1))
    return photo, hair, skin, points, [0.5, 0.35, 0.28]


@pytest.mark.parametrize("eu,pheo", [(0.3, 0.1), (1.3, 0.1), (8.0, 0.0), (0.5, 1.6)])
def test_the_colour_gives_back_the_melanin(points, eu, pheo):
    """A hair patch of the renderer's own albedo for (eu, pheo), lit as the skin is, gives
    back melanin whose albedo is within 10 % of it (the table's melanins are not unique
    for black hair: its albedo is the fibres' grey reflection, whatever the pigment)."""
    hair = _mask(points, 80, 230, 95, 60)
    truth = slab_albedo(eu, pheo)
    photo, skin = _photo(points, hair, truth)
    style, _ = hair_style_from_photo(photo, hair, skin, points, [0.5, 0.35, 0.28])
    got = slab_albedo(style.eumelanin, style.pheomelanin)
    np.testing.assert_allclose(got, truth, rtol=0.1, atol=0.002)
    if eu < 5 and pheo <= 0.1:  # red: eumelanin and pheomelanin trade off
        assert style.eumelanin == pytest.approx(eu, rel=0.3, abs=0.1)


def test_albedo_round_trip_over_the_table():
    for eu in (0.0, 0.2, 0.7, 2.0):
        for pheo in (0.0, 0.5, 2.5):
            a = slab_albedo(eu, pheo)
            e, p = albedo_melanin(a)
            np.testing.assert_allclose(slab_albedo(e, p), a, rtol=0.05, atol=0.002)


def test_skin_in_the_hair_mask_is_left_out_of_the_colour(points):
    """The segmentation's "hair" holding a bare upper forehead and the ears (the face's
    own skin colour, joined to its skin, as on obama's portrait): the colour is read from
    the hair alone. A hair mask that is all skin-coloured (blond on light skin) keeps
    every pixel, and skin-coloured highlights inside the hair stay."""
    from hack_render.fit.hair_style import colour_pixels

    hair = _mask(points, 90, 20, 88, 40)
    truth = slab_albedo(8.0, 0.0)
    photo, skin = _photo(points, hair, truth)
    # two thirds of the mask, over the forehead and beside it, are skin (the face's
    # colour, lit alike)
    yy = np.mgrid[:SIZE, :SIZE][0] + 0.5
    brow = points[17:27, 1].mean()
    forehead = hair & (yy > brow - 70)
    assert 0.6 < forehead.sum() / hair.sum() < 0.7
    photo[forehead] = photo[skin][0]
    # the face's skin reaches the hair mask's lower edge (the skin-like part joins it)
    xx = np.mgrid[:SIZE, :SIZE][1] + 0.5
    face = (np.abs(xx - points[30, 0]) < 60) & (yy > brow - 40) & (yy < points[8, 1]) & ~hair
    photo[face] = photo[skin][0]
    skin = face
    keep, left_out = colour_pixels(photo, hair, skin)
    assert left_out == forehead.sum() and not (keep & forehead).any()
    style, report = hair_style_from_photo(photo, hair, skin, points, [0.5, 0.35, 0.28])
    np.testing.assert_allclose(slab_albedo(style.eumelanin, style.pheomelanin), truth,
                               rtol=0.1, atol=0.002)
    assert report["skin_like_left_out"] == forehead.sum()
    # before, the median of the mask's darker 85 % was the skin's colour
    px = photo[hair]
    lum = px @ np.array([0.2126, 0.7152, 0.0722])
    np.testing.assert_allclose(np.median(px[lum <= np.percentile(lum, 85)], 0),
                               photo[skin][0])
    blond = np.zeros_like(photo)
    blond[hair] = photo[skin][0]
    blond[skin] = photo[skin][0]
    keep, left_out = colour_pixels(blond, hair, skin)
    assert left_out == 0 and keep.sum() >= 0.8 * hair.sum()
    # the hair's own skin-coloured highlights, apart from the face, stay in
    lit = photo.copy()
    spots = hair & (yy < brow - 76) & ((np.mgrid[:SIZE, :SIZE][1] // 6) % 3 == 0) \
        & ((np.mgrid[:SIZE, :SIZE][0] // 6) % 3 == 0)
    assert spots.sum() > 100
    lit[spots] = photo[skin][0]
    keep, left_out = colour_pixels(lit, hair, skin)
    assert left_out == forehead.sum()
