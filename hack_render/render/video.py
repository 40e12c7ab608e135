"""Writing frame sequences as MP4 (H.264, yuv420p, through imageio-ffmpeg) and GIF.

Both writers take sRGB uint8 frames (H, W, 3), write to a temporary name and rename.
"""

from __future__ import annotations

import errno
import os
import shutil
import struct
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
        check_mp4(tmp, path)
    return Path(path)


#: free bytes under which an incomplete MP4 is put down to a full disk
FULL_DISK_BYTES = 1 << 20


def mp4_boxes(path: str | Path) -> list[tuple[str, int]]:
    """The top-level boxes of an MP4 file, [(type, size)], up to the first one that runs
    past the end of the file (an ffmpeg stopped by a full disk leaves such a file)."""
    out, end = [], os.path.getsize(path)
    with open(path, "rb") as fh:
        at = 0
        while at + 8 <= end:
            fh.seek(at)
            size, kind = struct.unpack(">I4s", fh.read(8))
            if size == 1:  # a 64-bit size follows
                size = struct.unpack(">Q", fh.read(8))[0]
            elif size == 0:  # to the end of the file
                size = end - at
            if size < 8 or at + size > end:
                break
            out.append((kind.decode("latin-1"), size))
            at += size
    return out


def check_mp4(tmp: str | Path, path: str | Path) -> None:
    """Refuse an MP4 that ffmpeg left incomplete (no ``moov`` index: unplayable): an OSError
    (ENOSPC) when the disk is all but full, else a HackError; the caller's temporary is
    then removed and ``path`` never holds it."""
    kinds = {k for k, _ in mp4_boxes(tmp)}
    if {"ftyp", "moov", "mdat"} <= kinds:
        return
    if shutil.disk_usage(Path(tmp).parent).free < FULL_DISK_BYTES:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    raise HackError(f"{path}: ffmpeg wrote an incomplete MP4 (boxes {sorted(kinds)}, no "
                    f"'moov' index); nothing was kept under that name. Try again, or "
                    f"--formats gif,frames.")


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
