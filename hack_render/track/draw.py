"""One frame of ``overlay.mp4``: the fitted model rasterised over the frame, the detected
and the model's landmarks, a band on frames where the face was lost.

NumPy and PIL only: :func:`draw_frame` runs in the overlay's drawing threads
(``outputs.write_overlay``).
"""

from __future__ import annotations

import time

import numpy as np
from PIL import Image, ImageDraw

from hack_render.render.raster import render_shaded
from scenes.cameras import Camera


def dots(img: np.ndarray, pts: np.ndarray, colour, r: int = 1) -> None:
    """Squares of side 2 r + 1 px at ``pts`` (n, 2) on ``img`` (NaN points skipped)."""
    h, w = img.shape[:2]
    for x, y in pts:
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        xi, yi = int(x), int(y)
        img[max(0, yi - r):min(h, yi + r + 1), max(0, xi - r):min(w, xi + r + 1)] = colour


def blend(img: np.ndarray, rgba: np.ndarray, opacity: float = 0.6) -> np.ndarray:
    """The frame (H, W, 3) uint8 with the linear render ``rgba`` over it at ``opacity``
    (gamma 2.2 for display), where the render covers it."""
    out = np.array(img, np.uint8)
    flat, rgb = out.reshape(-1, 3), rgba.reshape(-1, 4)
    on = np.flatnonzero(rgb[:, 3] > 0)      # the covered pixels only (the gamma's power
    # over the whole frame was a sixth of a frame's drawing)
    a = opacity * rgb[on, 3:4]
    shade = np.clip(rgb[on, :3], 0, 1) ** (1 / 2.2) * 255
    flat[on] = (flat[on] * (1 - a) + shade * a).astype(np.uint8)
    return out


def frame_context(faces: np.ndarray, closed: np.ndarray, camera: tuple) -> dict:
    """What every frame of a clip shares: the model's triangles, the closed skin's mask
    and the clip's camera ``(K, R, t, width, height)``."""
    K, R, t, w, h = camera
    return {"faces": faces, "closed": closed, "camera": Camera(K, R, t, w, h, "clip")}


def draw_frame(ctx: dict, i: int, img: np.ndarray, verts: np.ndarray, detected: np.ndarray,
               model_points: np.ndarray, lost: str | None) -> tuple[np.ndarray, float]:
    """Frame ``i`` drawn (``ctx``: :func:`frame_context`'s): the model (``verts``, shaded, 60 % opacity) over ``img``, the
    detected landmarks (green) and the model's (red); ``lost``: why the face was lost
    (a red band says so), None where it was found. Returns (frame, CPU seconds)."""
    c0 = time.thread_time()
    cam = ctx["camera"]
    frame = blend(img, render_shaded(verts, ctx["faces"], cam, closed=ctx["closed"]))
    dots(frame, detected, (40, 220, 60))
    dots(frame, model_points, (230, 40, 40))
    if lost is not None:
        pil = Image.fromarray(frame)
        d = ImageDraw.Draw(pil)
        d.rectangle([0, 0, cam.width, 14], fill=(200, 20, 20))
        d.text((4, 1), f"frame {i}: face lost ({lost}); interpolated", fill=(255, 255, 255))
        frame = np.asarray(pil)
    return frame, time.thread_time() - c0
