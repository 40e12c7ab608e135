"""Turntables: N frames of a looping animation, resumable, as MP4 / GIF / PNG frames.

The loop is seamless: frame i of N is at phase t = i / N, so frame N would repeat
frame 0 and is never rendered. Motion options (any combination):

- ``orbit``: the camera circles the head under fixed lights; ``subject``: the head
  turns about the vertical axis through the framing target under fixed lights and camera.
- ``look_around``: a neck animation, whole-head angles (flexion, axial, lateral) on
  periodic curves, shared over the 8 cervical joints within their limits by
  ``distribute_head_rotation``.
- ``swallow``: the larynx rises and returns: the averaged swallow curve packaged as
  ``hack_render/data/swallow_tau.npz`` (:func:`swallow_source` says where it came from).

Frames are written as PNG (sRGB, tone mapped) under ``<out>/frames``; ``resume`` skips
frames already there (each was written atomically, so an existing file is complete).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from hack_render.boundary import clean_temporaries
from hack_render.errors import HackError
from hack_render.geometry.params import ParamSequence
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.io import TEMP_GLOB, temp_glob

FORMATS = ("mp4", "gif", "frames")


@dataclass(frozen=True)
class TurntableSpec:
    """What to animate. frames: N; mode: ``orbit`` or ``subject``; degrees per loop."""

    frames: int = 48
    mode: str = "orbit"
    degrees: float = 360.0
    look_around: bool = False
    swallow: bool = False
    fps: int = 24

    def __post_init__(self):
        if not 2 <= self.frames <= 10000:
            raise HackError(f"--frames: expected 2..10000, found {self.frames}.")
        if self.mode not in ("orbit", "subject"):
            raise HackError(f"--mode: expected 'orbit' or 'subject', found {self.mode!r}.")
        if not 1 <= self.fps <= 120:
            raise HackError(f"--fps: expected 1..120, found {self.fps}.")

    def phase(self, i: int) -> float:
        return i / self.frames

    def yaw_deg(self, i: int) -> float:
        return self.degrees * self.phase(i)


def head_angles_deg(t: float) -> tuple[float, float, float]:
    """Look-around whole-head angles at loop phase t in [0, 1): (flexion, axial, lateral)."""
    w = 2.0 * math.pi * t
    return (10.0 * math.sin(2.0 * w), 45.0 * math.sin(w), 8.0 * math.sin(w + math.pi / 2) *
            math.sin(w))


#: The swallow's curve (package data): averaged by ``hack_render.motion.swallow`` from
#: aligned tau clips; its ``meta`` says which clips (the shipped one: procedural ones).
SWALLOW_CURVE = "swallow_tau.npz"
#: Loop phases where the swallow starts and ends (the larynx rests outside them).
SWALLOW_SPAN = (0.15, 0.85)


@lru_cache(maxsize=1)
def _swallow_curve() -> tuple[np.ndarray, np.ndarray, dict]:
    """(times (S,) s, tau (S,) m, meta) of the packaged swallow curve."""
    path = Path(str(resources.files("hack_render") / "data" / SWALLOW_CURVE))
    try:
        with np.load(path, allow_pickle=False) as z:
            return (np.asarray(z["times"], np.float64), np.asarray(z["tau"], np.float64),
                    json.loads(str(z["meta"])))
    except (OSError, KeyError, ValueError) as exc:
        raise HackError(f"{path}: the swallow curve is missing or unreadable ({exc}); "
                        "reinstall hack-render or run `python -m hack_render.motion.swallow`."
                        ) from exc


def swallow_source() -> str:
    """One line saying where the turntable's swallow curve comes from."""
    _, tau, meta = _swallow_curve()
    prov = meta.get("provenance", {})
    return (f"swallow: tau curve {SWALLOW_CURVE} ({prov.get('kind', 'unlabelled')}; "
            f"{meta.get('count')} swallows aligned at valleys and peak and averaged, peak "
            f"{1e3 * tau.max():.1f} mm; source: {prov.get('source', 'unknown')})")


def swallow_tau(t: float, height: float | None = None) -> float:
    """Larynx slide (metres, up) at loop phase t in [0, 1): the packaged averaged swallow
    (``SWALLOW_CURVE``), onset to offset stretched over ``SWALLOW_SPAN`` of the loop, 0
    outside; scaled to peak at ``height`` metres when given (default: its own height)."""
    times, tau, _ = _swallow_curve()
    a, b = SWALLOW_SPAN
    x = times[0] + (t % 1.0 - a) / (b - a) * (times[-1] - times[0])
    y = float(np.interp(x, times, tau, left=0.0, right=0.0))
    return y if height is None else y * height / float(tau.max())


def frame_path(folder: Path, i: int, kind: str = "frames") -> Path:
    """PNG of frame i: ``<folder>/frames`` (or ``<folder>/noisy``, before denoising)."""
    return folder / kind / f"frame_{i:04d}.png"


def rotate_about_y(vertices: np.ndarray, degrees: float, centre) -> np.ndarray:
    """Rotate (N, 3) points about the vertical axis through ``centre``."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    centre = np.asarray(centre, dtype=np.float64)
    return (vertices - centre) @ R.T + centre


def pending_frames(folder: Path, n: int, resume: bool) -> list[int]:
    """Frames still to render (all of them unless ``resume``). A frame on disk is complete
    (written under a temporary name, then renamed); the temporaries a killed run left in
    ``<folder>/frames`` and ``<folder>`` are removed first."""
    for kind in ("frames", "noisy"):  # hack_render.io's, and older versions' names
        if (Path(folder) / kind).is_dir():
            for pattern in (TEMP_GLOB, ".frame_*"):
                clean_temporaries(Path(folder) / kind, pattern)
    # the video, GIF, cameras and run record (the folder's other files are not ours)
    for name in ("turntable.mp4", "turntable.gif", "cameras.json", "turntable.json"):
        clean_temporaries(Path(folder), temp_glob(name))
    for stem in ("turntable", "cameras", "run"):  # as older versions named them
        clean_temporaries(Path(folder), f".{stem}.*")
    return [i for i in range(n) if not (resume and frame_path(folder, i).is_file())]


def frames_on_disk(folder: Path) -> int:
    """How many frames ``<folder>/frames`` holds (what an interrupted run kept)."""
    frames = Path(folder) / "frames"
    return len(list(frames.glob("frame_*.png"))) if frames.is_dir() else 0


def motion_sequence(spec: TurntableSpec, base_theta: np.ndarray | None = None,
                    base_psi: np.ndarray | None = None, base_tau: float = 0.0):
    """The turntable's head motion as a parameter sequence (``hack_render.geometry.params``):
    per frame, ``base_theta`` (8, 3) plus the look-around's share of each joint, the
    swallow's tau (else ``base_tau``) and ``base_psi`` (E,), at ``spec.fps``. The camera
    orbit and the subject turn are not head motion and are not in it."""
    import torch

    n = spec.frames
    theta = np.zeros((n, 8, 3)) + (0.0 if base_theta is None else np.asarray(base_theta))
    if spec.look_around:
        ang = np.deg2rad([head_angles_deg(spec.phase(i)) for i in range(n)])
        theta = theta + distribute_head_rotation(torch.as_tensor(ang)).numpy()
    tau = np.array([swallow_tau(spec.phase(i)) if spec.swallow else base_tau for i in range(n)])
    psi = None if base_psi is None else np.tile(np.asarray(base_psi, np.float64), (n, 1))
    return ParamSequence(fps=float(spec.fps), theta=theta, psi=psi, tau=tau)
