"""Reading clips for the tracker (MP4, MOV, AVI, WebM, MKV through imageio-ffmpeg, or a
folder of frames) at a working size, and writing MP4 frame by frame."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import imageio_ffmpeg
import numpy as np
from PIL import Image, UnidentifiedImageError

from hack_render.errors import HackError
from hack_render.io import atomic_path

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".webm", ".mkv", ".m4v")
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def _natural(p: Path):
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


@dataclass
class Clip:
    """A clip: its source, frame rate, frame count, source size and working size (the
    frames are scaled so the long side is at most ``max_side``; even sides)."""

    source: Path
    fps: float
    frames: int
    size: tuple[int, int]          # source (width, height)
    work: tuple[int, int]          # working (width, height)
    files: list[Path] | None = None
    notes: tuple[str, ...] = ()

    @property
    def scale(self) -> float:
        return self.work[0] / self.size[0]

    def read(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        """Frames ``start`` .. ``stop`` - 1 as (H, W, 3) uint8 at the working size."""
        stop = self.frames if stop is None else min(stop, self.frames)
        if self.files is not None:
            for p in self.files[start:stop]:
                with Image.open(p) as im:
                    im = im.convert("RGB")
                    if im.size != self.work:
                        im = im.resize(self.work, Image.Resampling.LANCZOS)
                    yield np.asarray(im, dtype=np.uint8)
            return

        w, h = self.work
        gen = imageio_ffmpeg.read_frames(str(self.source), pix_fmt="rgb24",
                                         output_params=["-vf", f"scale={w}:{h}:flags=area"])
        try:
            next(gen)  # the meta data
            for i, buf in enumerate(gen):
                if i >= stop:
                    break
                if i >= start:
                    yield np.frombuffer(buf, np.uint8).reshape(h, w, 3)
        finally:
            gen.close()


def _work_size(w: int, h: int, max_side: int) -> tuple[int, int]:
    s = min(1.0, max_side / max(w, h))
    ew, eh = max(2, round(w * s / 2) * 2), max(2, round(h * s / 2) * 2)
    return ew, eh


def open_clip(path: str | Path, max_side: int = 640, fps: float | None = None) -> Clip:
    """Open a video file or a folder of frames (sorted by name, numbers in order)."""
    path = Path(path)
    if fps is not None and not (math.isfinite(fps) and 0 < fps <= 1000):
        raise HackError(f"--fps: expected a frame rate in (0, 1000], found {fps}.")
    if path.is_dir():
        files = sorted((p for p in path.iterdir() if p.suffix.lower() in FRAME_SUFFIXES
                        and not p.name.startswith(".")), key=_natural)
        if not files:
            raise HackError(f"{path}: expected video frames ({', '.join(FRAME_SUFFIXES)}) in "
                            "the folder, found none.")

        try:
            with Image.open(files[0]) as im:
                w, h = im.size
        except (UnidentifiedImageError, OSError) as err:
            raise HackError(f"{files[0]}: not a readable image ({err}).") from err
        notes = () if fps is not None else ("no frame rate for a folder of frames: 30 fps "
                                            "assumed (pass --fps)",)
        return Clip(path, float(fps or 30.0), len(files), (w, h), _work_size(w, h, max_side),
                    files, notes)
    if not path.is_file():
        raise HackError(f"{path}: no such file or folder. Pass a video ({', '.join(VIDEO_SUFFIXES)})"
                        " or a folder of frames.")
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise HackError(f"{path}: expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder "
                        f"of frames, found '{path.suffix or 'no suffix'}'.")

    try:
        gen = imageio_ffmpeg.read_frames(str(path))
        meta = next(gen)
        gen.close()
        n, _secs = imageio_ffmpeg.count_frames_and_secs(str(path))
    except (RuntimeError, OSError, StopIteration) as err:
        first = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
        raise HackError(f"{path}: not a readable video ({first}).") from err
    w, h = (int(x) for x in meta["size"])
    rate = fps or float(meta.get("fps") or 0)
    if not (rate > 0 and math.isfinite(rate)):
        raise HackError(f"{path}: the video names no frame rate; pass --fps.")
    if n <= 0:
        raise HackError(f"{path}: the video has no frames.")
    return Clip(path, float(rate), int(n), (w, h), _work_size(w, h, max_side))


class Mp4Writer:
    """H.264 MP4 (yuv420p) written frame by frame under a temporary name, renamed when
    closed without error (as ``hack_render.render.video.write_mp4``, for clips too long
    to hold in memory)."""

    def __init__(self, path: str | Path, size: tuple[int, int], fps: float, quality: int = 7):

        self.path = Path(path)
        self._ctx = atomic_path(self.path)
        tmp = self._ctx.__enter__()
        self._gen = imageio_ffmpeg.write_frames(str(tmp), size, fps=fps, codec="libx264",
                                                pix_fmt_out="yuv420p", quality=quality,
                                                macro_block_size=2, ffmpeg_log_level="error",
                                                output_params=["-movflags", "+faststart"])
        self._gen.send(None)

    def write(self, frame: np.ndarray) -> None:
        self._gen.send(np.ascontiguousarray(frame[..., :3], dtype=np.uint8))

    def close(self, ok: bool = True) -> None:
        self._gen.close()
        if ok:
            self._ctx.__exit__(None, None, None)
        else:
            self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(exc_type is None)
