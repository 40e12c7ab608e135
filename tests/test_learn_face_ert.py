"""hack_render.learn.face_ert: the training faces are prepared as the run-time predictor
(hack_render.vision.ert) sees them: upright crops, one side of the face."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cv2", reason="opencv (from mediapipe, fit extra) is not installed")

from hack_render.learn import face_ert
from hack_render.vision import ert
from hack_render.vision.detection import MIRROR_68


def _sample(rng):
    """A noise image with a coloured dot at each of 68 random points, a box around them,
    keypoints turned by 20 degrees (so the crop is turned upright)."""
    img = rng.integers(0, 40, (200, 200, 3), dtype=np.uint8)
    pts = rng.uniform(70, 130, (68, 2))
    colours = rng.integers(60, 255, (68, 3))
    for p, c in zip(pts, colours):
        x, y = int(p[0]), int(p[1])
        img[y - 1:y + 2, x - 1:x + 2] = c
    a = np.radians(20)
    up = np.array([np.sin(a), -np.cos(a)])
    kps = np.array([[90, 90], [110, 90], [100, 100], [100, 115], [80, 95], [120, 95]], float)
    kps = 100 + (kps - 100) @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T
    assert np.dot(kps[[0, 1]].mean(0) - kps[3], up) > 0
    return img, (60.0, 60.0, 140.0, 140.0), kps, pts, colours


def test_prepare_mirrors_the_negative_yaw_and_relabels():
    rng = np.random.default_rng(0)
    samples = [_sample(rng), _sample(rng)]
    data = {"images": np.array([s[0] for s in samples]),
            "boxes": np.array([s[1] for s in samples]),
            "kps": np.array([s[2] for s in samples]),
            "points": np.array([s[3] for s in samples]), "yaw": np.array([30.0, -30.0])}
    # a yaw regression that reads the sign from the sample's index: +30, then -30
    w = np.zeros(25)
    w[-1] = 30.0
    prep = face_ert.prepare({k: v[:1] for k, v in data.items()}, weights=w)
    prep_neg = face_ert.prepare({k: v[1:] for k, v in data.items()}, weights=-w)
    for p, colours, mirrored in ((prep, samples[0][4], False), (prep_neg, samples[1][4], True)):
        crop, pts = p["crops"][0], p["points"][0]
        assert crop.shape == (ert.CROP_PX, ert.CROP_PX, 3)
        # the colour under each prepared point is its own point's (or, mirrored, the
        # mirror-image point's: the labels follow the face's sides)
        ids = MIRROR_68 if mirrored else np.arange(68)
        hits = 0
        for k in range(68):
            x, y = (pts[k] - 0.5).round().astype(int)
            hits += np.abs(crop[y, x].astype(int) - colours[ids[k]]).max() < 40
        assert hits >= 60, hits


def test_training_bins_overlap_and_cover():
    for y in np.linspace(0, 95, 40):
        bins = ert.training_bins(y)
        assert ert.choose_bin(y) in bins
    assert ert.training_bins(35.0) == [0, 1] and ert.training_bins(89.0) == [2]


def test_collect_writes_whole_or_nothing(tmp_path, monkeypatch):
    """A collection stopped while its file is written leaves no file (a half-written
    .npz would stop the training that reads it), and a finished one reads back."""
    from types import SimpleNamespace

    from hack_render.dataset import composites
    from hack_render.vision import boxes

    rng = np.random.default_rng(5)
    img, box, kps, pts, _ = _sample(rng)

    made = []

    class Renderer:               # the composite renderer's stand-in: one known sample
        def __init__(self, res, spp, seed):
            made.append((res, spp, seed))

        def render(self, yaw, *a, **k):
            return SimpleNamespace(image=img, points=pts, yaw=yaw)

    monkeypatch.setattr(composites, "CompositeRenderer", Renderer)
    monkeypatch.setattr(boxes, "find_boxes", lambda im: [(*box, 0.9, kps)])
    out = tmp_path / "ert_1.npz"
    real = np.savez_compressed

    def stopped(f, **arrays):
        real(f, **{k: v[:1] for k, v in arrays.items()})    # part of it on disk, then
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", stopped)
    with pytest.raises(KeyboardInterrupt):
        face_ert.collect(3, seed=1, out=out)
    assert not out.exists()
    monkeypatch.setattr(np, "savez_compressed", real)
    face_ert.collect(3, seed=1, out=out)
    with np.load(out) as z:
        assert z["images"].shape == (3, *img.shape)
        assert np.allclose(z["points"][2], pts) and np.allclose(z["boxes"][0], box)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ert_1.npz"]
    assert made == [(256, 16, 1), (256, 16, 1)]      # the seed reaches the renderer
