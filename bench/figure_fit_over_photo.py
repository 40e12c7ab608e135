"""The before/after figure of issue 62 in docs/fit.md (``docs/images/fit_over_photo_before_after.png``).

Rows: the three worst real photos by the face oval when the issue opened (the astronaut,
Grace Hopper, the cameraman: the only ones whose licences allow images; the others are
scored only). Columns, 200 px each:

1. the photo, cropped as the issue's first figure was (300 px squares, found again by
   template matching against that figure's first column);
2. ``render_over_photo.png`` when the issue's measure was built (that figure's third
   column, ``--then``: e.g. ``git show ad861f7:docs/images/fit_over_photo_before_after.png``);
3. ``render_over_photo.png`` of the kept fits in ``--fits`` (``bench_real_photos.py
   --fit --fit-out DIR``), the same crop;
4. and 5. the photo's and the fit's faces, zoomed (the fit's 68 detected points' box,
   grown 1.5 times).

    python bench/figure_fit_over_photo.py --fits FITS --then then.png \\
        --out docs/images/fit_over_photo_before_after.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from photo_sets import real_photos

PHOTOS = ("astronaut", "grace_hopper", "camera")
TILE = 200


def find_crop(img: np.ndarray, tile: np.ndarray) -> tuple[int, int, int]:
    """(x0, y0, side) of the square crop of ``img`` that, resized to TILE, best matches
    ``tile`` (normalised squared difference over sides 200..min(h, w) in steps of 4)."""
    h, w = img.shape[:2]
    best = None
    for s in range(TILE, min(h, w) + 1, 4):
        f = TILE / s
        im = cv2.resize(img, (round(w * f), round(h * f)), interpolation=cv2.INTER_AREA)
        if min(im.shape[:2]) < TILE:
            continue
        score, _, loc, _ = cv2.minMaxLoc(cv2.matchTemplate(im, tile, cv2.TM_SQDIFF_NORMED))
        if best is None or score < best[0]:
            best = (score, round(loc[0] / f), round(loc[1] / f), s)
    return best[1], best[2], best[3]


def square(img: np.ndarray, x0: int, y0: int, s: int) -> np.ndarray:
    """The square crop (clamped to the image), resized to TILE."""
    h, w = img.shape[:2]
    x0, y0 = int(np.clip(x0, 0, w - s)), int(np.clip(y0, 0, h - s))
    return cv2.resize(np.ascontiguousarray(img[y0:y0 + s, x0:x0 + s]), (TILE, TILE),
                      interpolation=cv2.INTER_AREA if s >= TILE else cv2.INTER_CUBIC)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fits", required=True, help="kept fits (one folder per photo)")
    ap.add_argument("--then", required=True, help="the issue's first figure (PNG)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    photos = real_photos()
    then = iio.imread(a.then)[..., :3]
    rows = []
    for r, name in enumerate(PHOTOS):
        img = np.asarray(photos[name])[..., :3]
        now = iio.imread(Path(a.fits) / name / "render_over_photo.png")[..., :3]
        if now.shape[:2] != img.shape[:2]:
            img = cv2.resize(img, now.shape[1::-1], interpolation=cv2.INTER_AREA)
        first = then[TILE * r:TILE * (r + 1), :TILE]
        x0, y0, s = find_crop(img, first)
        pts = np.load(Path(a.fits) / name / "params.npz")["view0_landmarks_detected"]
        c, half = (pts.min(0) + pts.max(0)) / 2, 0.75 * (pts.max(0) - pts.min(0)).max()
        fx, fy, fs = int(c[0] - half), int(c[1] - half), int(2 * half)
        rows.append(np.concatenate([square(img, x0, y0, s), then[TILE * r:TILE * (r + 1),
                                    2 * TILE:3 * TILE], square(now, x0, y0, s),
                                    square(img, fx, fy, fs), square(now, fx, fy, fs)], 1))
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, np.concatenate(rows, 0))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
