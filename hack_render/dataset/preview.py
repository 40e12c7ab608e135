"""A contact sheet of a dataset's first samples, with segmentation and landmarks overlaid.

Each tile is ``rgb.png`` of one view, blended with the segmentation colours (see
:data:`PALETTE`), with the 68 face landmarks (green), the 8 projected cervical joints
(red) and the larynx peak (blue); filled dots are visible, hollow ones occluded.
"""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from PIL import Image, ImageDraw

from hack_render.errors import HackError
from hack_render.io import atomic_path

#: sRGB colour per segmentation label (index = label id).
PALETTE = np.array([
    (0, 0, 0), (230, 160, 120), (180, 110, 200), (90, 60, 40), (240, 210, 70), (220, 30, 60),
    (60, 40, 20), (250, 250, 250), (40, 130, 240), (255, 255, 170), (200, 60, 140),
    (20, 220, 200), (120, 120, 130), (255, 120, 0)], np.uint8)
GROUP_COLOURS = {"face68": (40, 230, 60), "joints8": (250, 40, 40), "larynx_peak": (40, 90, 255)}


def _views(folder: Path, count: int) -> list[Path]:
    samples = sorted(p for p in (folder / "samples").glob("*") if (p / "sample.json").is_file())
    views = []
    for s in samples:
        views += sorted(p for p in s.glob("view_*") if (p / "rgb.png").is_file())
        if len(views) >= count:
            break
    return views[:count]


def tile(view: Path, blend: float = 0.35) -> np.ndarray:
    """One annotated tile (H, W, 3) uint8 from a view folder."""
    rgb = iio.imread(view / "rgb.png")[..., :3].astype(np.float64)
    seg = iio.imread(view / "segmentation.png")
    over = PALETTE[np.clip(seg, 0, len(PALETTE) - 1)].astype(np.float64)
    a = np.where(seg > 0, blend, 0.0)[..., None]
    img = Image.fromarray(np.round(rgb * (1 - a) + over * a).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    lm = json.loads((view / "landmarks.json").read_text())
    r = max(1.0, img.width / 160)
    for group, colour in GROUP_COLOURS.items():
        g = lm[group]
        for (x, y), inside, vis in zip(g["points_2d"], g["in_image"], g["visible"]):
            if not inside:
                continue
            box = (x - r, y - r, x + r, y + r)
            draw.ellipse(box, fill=colour if vis else None, outline=colour)
    return np.asarray(img)


def contact_sheet(folder: str | Path, output: str | Path | None = None, count: int = 16,
                  columns: int = 4) -> Path:
    """Write a grid of the first ``count`` views as PNG (default ``DIR/preview.png``)."""
    folder = Path(folder)
    if count < 1 or columns < 1:
        raise HackError(f"preview: expected --count and --columns >= 1, found {count}, "
                        f"{columns}.")
    views = _views(folder, count)
    if not views:
        raise HackError(f"{folder}: expected a dataset folder with complete samples "
                        "(samples/*/sample.json), found none. Run `hack-render dataset` first.")
    tiles = [tile(v) for v in views]
    h, w = tiles[0].shape[:2]
    cols = min(columns, len(tiles))
    rows = -(-len(tiles) // cols)
    sheet = np.zeros((rows * h, cols * w, 3), np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, cols)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = t[:h, :w]
    output = Path(output) if output else folder / "preview.png"

    with atomic_path(output) as tmp:
        iio.imwrite(tmp, sheet, extension=".png")
    return output
