"""hack_render.vision.segment's graph cut (refine_skin) on a real photo."""

from __future__ import annotations

import numpy as np
import pytest

# as tests/test_vision.py: mediapipe 0.10.14 (the fit extra) has no wheel for Python 3.13+
pytest.importorskip("mediapipe", reason="mediapipe 0.10.14 (fit extra) is not installed; "
                    "it has no wheel for Python 3.13+")
pytest.importorskip("ai_edge_litert", reason="ai-edge-litert (fit extra) is not installed")

from hack_render.vision.detect import detect_face


def test_the_graph_cut_takes_the_fringe_away_from_the_skin():
    """The astronaut (public domain, 256 px): her blond fringe has the skin's colour in
    its highlights, and the per-pixel tests left a ragged band of it as skin along the
    hairline. The graph cut only takes skin away (never adds), keeps the skin below the
    eyes, and what it takes inside the face oval is the fringe: far darker than the
    forehead it leaves."""
    import skimage.data

    from hack_render.vision.segment import _upright_rows, _upright_y, segment

    img = np.ascontiguousarray(skimage.data.astronaut()[::2, ::2])
    face = detect_face(img, "mesh")
    tests, cut = [segment(img, face, hands=False, graph_cut=g) for g in (False, True)]
    h, w = img.shape[:2]
    up = _upright_rows(face, h, w)
    oval = tests.face > 0.5
    assert not (cut.skin & ~tests.skin).any()
    below = oval & (up > _upright_y(face, slice(36, 48)).mean())
    assert (cut.skin & below).sum() >= 0.98 * (tests.skin & below).sum()
    taken = tests.skin & ~cut.skin & oval
    assert taken.sum() > 50, taken.sum()
    lum = img.mean(-1)
    forehead = cut.skin & oval & (up < _upright_y(face, slice(17, 27)).min())
    assert np.median(lum[taken]) < 0.75 * np.median(lum[forehead]), (
        np.median(lum[taken]), np.median(lum[forehead]))
    assert (cut.occluder & taken).sum() > 0.8 * taken.sum()   # the fit leaves them out


def test_a_grey_photos_dark_hair_is_an_occluder():
    """The cameraman (skimage, public domain; grey): his dark fringe reaches down to his
    brows. A grey photo's chromaticity is the same everywhere, so the colour test calls
    all of the face oval skin; brightness and texture tell his hair from his cheeks
    (well past ``GREY_HAIR_SEPARABLE``), and the hair test and the graph cut take it out
    above the eyes' line. Below it nothing is taken: there a shadowed chin or a dark
    collar looks as much like dark hair."""
    import skimage.data
    from skimage.color import gray2rgb

    from hack_render.vision.segment import _upright_rows, _upright_y, segment

    img = np.ascontiguousarray(gray2rgb(skimage.data.camera()))
    face = detect_face(img, "mesh")
    before, seg = [segment(img, face, hands=False, hair_model=m) for m in (False, True)]
    h, w = img.shape[:2]
    up = _upright_rows(face, h, w)
    oval = seg.face > 0.5
    lum = img.mean(-1)
    dark = oval & (up < _upright_y(face, slice(17, 27)).min()) & (lum < 50)
    assert dark.sum() > 100, dark.sum()
    assert (before.occluder & dark).sum() < 0.2 * dark.sum()
    assert (seg.occluder & dark).sum() > 0.9 * dark.sum()
    taken = seg.occluder & oval
    assert taken.sum() > 400, taken.sum()
    assert np.median(lum[taken]) < 0.6 * np.median(lum[seg.skin & oval & ~seg.occluder])
    below = oval & (up > _upright_y(face, slice(36, 48)).mean())
    assert (seg.occluder & below).sum() <= (before.occluder & below).sum() + 5
