"""Writing frame sequences as MP4 (H.264, yuv420p, through imageio-ffmpeg) and GIF.

Both writers take sRGB uint8 frames (H, W, 3), write to a temporary name and rename.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np

from hack_render.errors import HackError
from hack_render.io import atomic_path


def write_mp4(path: str | Path, frames: Sequence[np.ndarray], fps: int = 24,
              quality: int = 8) -> Path:
    """H.264 MP4 in yuv420p (plays everywhere). Frame sides must be even (chroma 2x2)."""
    if not frames:
        raise HackError(f"{path}: expected at least one frame, found none.")
    h, w = frames[0].shape[:2]
    if h % 2 or w % 2:
        raise HackError(f"{path}: expected even frame width and height for H.264 yuv420p, "
                        f"found {w}x{h}. Use an even --resolution.")
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), (w, h), fps=fps, codec="libx264",
                                             pix_fmt_out="yuv420p", quality=quality,
                                             macro_block_size=2, ffmpeg_log_level="error",
                                             output_params=["-movflags", "+faststart"])
        writer.send(None)
        for f in frames:
            writer.send(np.ascontiguousarray(f[..., :3], dtype=np.uint8))
        writer.close()
    return Path(path)


def write_gif(path: str | Path, frames: Sequence[np.ndarray], fps: int = 24) -> Path:
    """Looping GIF (Pillow through imageio)."""
    if not frames:
        raise HackError(f"{path}: expected at least one frame, found none.")
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack([f[..., :3] for f in frames]), extension=".gif",
                    duration=1000.0 / fps, loop=0)
    return Path(path)


def count_mp4_frames(path: str | Path) -> tuple[int, tuple[int, int], str]:
    """Decode an MP4 fully: (number of frames, (width, height), pixel format of the stream)."""
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    n = sum(1 for _ in gen)
    return n, tuple(meta["size"]), str(meta.get("pix_fmt", ""))
