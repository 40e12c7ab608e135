"""Drive HACK from face-capture apps: `hack-render drive CAPTURE -o anim.npz`.

- Apple ARKit / Live Link Face CSV: ``Timecode``, ``BlendShapeCount``, the 52 ARKit
  blendshape columns (``EyeBlinkLeft`` ... ``TongueOut``), ``HeadYaw``, ``HeadPitch``,
  ``HeadRoll`` and optionally the eye rotations. psi comes straight from the blendshapes
  (the model's 53 expressions carry ARKit's names, split ``_L``/``_R``): ARKit's
  ``browInnerUp`` and ``cheekPuff`` are one shape each where the model has a left and a
  right one, so both halves take the value; ``tongueOut`` has no shape in the model and
  is dropped (the report says how much of the clip used it). theta comes from the head
  rotation through ``distribute_head_rotation`` (the anatomical share of each joint), with
  pitch about x (positive: the face turns down, flexion), yaw about y and roll about z, in
  the face's own frame (ARKit's: x to the face's left, y up, z out of the face, which is
  the model's). The frame rate comes from the timecodes (``HH:MM:SS:FF.fff``: FF counts
  frames and wraps at the rate) or ``--fps``.
- A plain head-rotation sequence: CSV with ``yaw``, ``pitch``, ``roll`` columns (and
  optionally ``time`` in seconds), or NPY (T, 3) yaw, pitch, roll; radians unless
  ``--degrees``.

The result is a parameter sequence (``hack_render.geometry.params``: .npz or .jsonl) that
``export --sequence`` animates.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry import distribute_head_rotation
from hack_render.geometry.params import ParamSequence
from hack_render.geometry.skeleton import head_rotation_range_deg

#: ARKit's 52 blendshape names as Live Link Face writes them (CSV column order)
ARKIT = ("EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft",
         "EyeSquintLeft", "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight",
         "EyeLookOutRight", "EyeLookUpRight", "EyeSquintRight", "EyeWideRight", "JawForward",
         "JawRight", "JawLeft", "JawOpen", "MouthClose", "MouthFunnel", "MouthPucker",
         "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
         "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft",
         "MouthStretchRight", "MouthRollLower", "MouthRollUpper", "MouthShrugLower",
         "MouthShrugUpper", "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft",
         "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
         "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff",
         "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut")
HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")
EYES = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch",
        "RightEyeRoll")
#: ARKit shapes with no model shape, and why
DROPPED = {"TongueOut": "the model has no tongue shape"}
#: ARKit shapes that drive both halves of a split model shape
BOTH_HALVES = ("BrowInnerUp", "CheekPuff")
#: ARKit shapes whose Left/Right is the direction the jaw or mouth moves
DIRECTIONS = ("JawLeft", "JawRight", "MouthLeft", "MouthRight")


def model_name(arkit: str) -> list[str]:
    """The model's expression names that an ARKit column drives ('' list: none)."""
    if arkit in DROPPED:
        return []
    if arkit in DIRECTIONS:  # a direction of motion, not a side of the face
        return [arkit[0].lower() + arkit[1:]]
    side = ""
    base = arkit
    for word, suffix in (("Left", "_L"), ("Right", "_R")):
        if arkit.endswith(word):
            base, side = arkit[: -len(word)], suffix
    name = base[0].lower() + base[1:]
    if arkit in BOTH_HALVES:
        return [name + "_L", name + "_R"]
    return [name + side]


def _parse_timecodes(codes: list[str], where: str) -> tuple[np.ndarray | None, float | None]:
    """(seconds since the first frame, fps found from the frame field) of SMPTE-like
    timecodes ``HH:MM:SS:FF[.fff]``; (None, None) if the clip is too short to tell."""
    rx = re.compile(r"^(\d+):(\d{2}):(\d{2})[:;](\d+)(\.\d+)?$")
    parts = []
    for i, c in enumerate(codes):
        m = rx.match(c.strip())
        if not m:
            raise HackError(f"{where}: row {i + 2}: timecode {c!r} is not HH:MM:SS:FF[.fff].")
        h, mi, s, f = (int(m.group(k)) for k in (1, 2, 3, 4))
        parts.append((h * 3600 + mi * 60 + s, f + float(m.group(5) or 0.0)))
    secs = np.array([p[0] for p in parts], np.float64)
    frames = np.array([p[1] for p in parts], np.float64)
    if secs[-1] == secs[0]:
        return None, None  # within one second: the frame field never wraps
    fps = float(np.floor(frames.max()) + 1)
    t = secs + frames / fps
    return t - t[0], fps


def read_live_link_csv(path: Path, fps: float | None) -> dict:
    """{"blend": (T, 52) in ARKit order, "head": (T, 3) yaw, pitch, roll (radians),
    "fps": float, "notes": [...]} of a Live Link Face / ARKit CSV."""
    where = str(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise HackError(f"{where}: cannot read it as CSV ({exc}).") from exc
    if len(rows) < 2:
        raise HackError(f"{where}: expected a header and at least one frame, found "
                        f"{len(rows)} line(s).")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in (*ARKIT, *HEAD) if c not in header]
    if missing:
        raise HackError(f"{where}: missing column(s) {', '.join(missing[:6])}"
                        f"{' ...' if len(missing) > 6 else ''} ({len(missing)} of the 52 "
                        "blendshapes and HeadYaw/HeadPitch/HeadRoll expected). Export with "
                        "Live Link Face's CSV layout.")
    known = {"Timecode", "BlendShapeCount", *ARKIT, *HEAD, *EYES}
    extra = [c for c in header if c not in known]
    notes = [f"columns ignored: {', '.join(extra)}"] if extra else []
    body = [r for r in rows[1:] if any(x.strip() for x in r)]
    bad = [i for i, r in enumerate(body) if len(r) != len(header)]
    if bad:
        raise HackError(f"{where}: row {bad[0] + 2} has {len(body[bad[0]])} fields, the header "
                        f"{len(header)}.")
    col = {h: k for k, h in enumerate(header)}

    def numbers(names) -> np.ndarray:
        out = np.empty((len(body), len(names)))
        for j, n in enumerate(names):
            for i, r in enumerate(body):
                try:
                    out[i, j] = float(r[col[n]])
                except ValueError:
                    raise HackError(f"{where}: row {i + 2}, column {n}: {r[col[n]]!r} is not a "
                                    "number.") from None
        bad = ~np.isfinite(out)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise HackError(f"{where}: row {i + 2}, column {names[j]}: NaN or infinite.")
        return out

    blend, head = numbers(ARKIT), numbers(HEAD)
    rate = fps
    if "Timecode" in col and fps is None:
        t, rate = _parse_timecodes([r[col["Timecode"]] for r in body], where)
        if t is not None and np.any(np.diff(t) <= 0):
            i = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise HackError(f"{where}: row {i + 3}: the timecode does not increase.")
    if rate is None:
        raise HackError(f"{where}: the clip is too short (under a second) to find its frame "
                        "rate from the timecodes. Pass --fps.")
    return {"blend": blend, "head": head, "fps": float(rate), "notes": notes}


def read_head_rotations(path: Path, fps: float | None, degrees: bool) -> dict:
    """{"head": (T, 3) yaw, pitch, roll radians, "fps"} of a CSV (yaw, pitch, roll[, time])
    or an NPY (T, 3)."""
    where = str(path)
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise HackError(f"{where}: cannot read it ({exc}).") from exc
        if arr.dtype.kind not in "fiu" or arr.ndim != 2 or arr.shape[1] != 3 or not len(arr):
            raise HackError(f"{where}: expected a (T, 3) array of yaw, pitch, roll, found shape "
                            f"{arr.shape}.")
        head, t = arr.astype(np.float64), None
    else:
        try:
            with open(path, newline="") as fh:
                rows = [r for r in csv.DictReader(fh)]
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise HackError(f"{where}: cannot read it as CSV ({exc}).") from exc
        if not rows or not {"yaw", "pitch", "roll"} <= set(k.strip().lower() for k in rows[0]):
            raise HackError(f"{where}: expected columns yaw, pitch, roll (and optionally time) "
                            "and at least one row.")
        low = [{k.strip().lower(): v for k, v in r.items()} for r in rows]
        try:
            head = np.array([[float(r["yaw"]), float(r["pitch"]), float(r["roll"])] for r in low])
            t = np.array([float(r["time"]) for r in low]) if "time" in low[0] else None
        except (TypeError, ValueError) as exc:
            raise HackError(f"{where}: a value is not a number ({exc}).") from exc
    if not np.isfinite(head).all():
        i = int(np.flatnonzero(~np.isfinite(head).all(1))[0])
        raise HackError(f"{where}: frame {i}: NaN or infinite rotation.")
    if degrees:
        head = np.deg2rad(head)
    rate = fps
    if rate is None and t is not None and len(t) > 1:
        dt = np.diff(t)
        if np.any(dt <= 0) or not np.isfinite(t).all():
            raise HackError(f"{where}: the time column must increase.")
        rate = 1.0 / float(np.median(dt))
    if rate is None:
        raise HackError(f"{where}: no frame rate: pass --fps (or give a time column).")
    return {"head": head, "fps": float(rate), "notes": []}


def head_to_theta(head: np.ndarray, limits: str = "clamp") -> tuple[np.ndarray, int]:
    """(T, 8, 3) joint rotations from (T, 3) yaw, pitch, roll radians, and the number of
    frames beyond the neck's range (clamped)."""
    import torch

    # (flexion about x, axial about y, lateral about z) = (pitch, yaw, roll)
    angles = torch.as_tensor(head[:, [1, 0, 2]], dtype=torch.float64)
    rng = torch.deg2rad(head_rotation_range_deg().double())  # (3, 2)
    beyond = int(((angles < rng[:, 0]) | (angles > rng[:, 1])).any(1).sum())
    if beyond and limits == "error":
        raise HackError(f"head rotation: {beyond} frame(s) beyond the neck's range; use "
                        "--limits clamp.")
    theta = distribute_head_rotation(angles.float(), clamp=True)
    return theta.double().numpy(), beyond


def drive(capture: Path, fps: float | None, degrees: bool, expression_names, limits: str):
    """(ParamSequence, report) from a capture file."""
    if not capture.is_file():
        raise HackError(f"{capture}: no such file. Pass a Live Link Face / ARKit CSV or a head "
                        "rotation CSV/NPY.")
    if fps is not None and not (math.isfinite(fps) and 0 < fps <= 1000):
        raise HackError(f"--fps: expected a frame rate in (0, 1000], found {fps}.")
    is_arkit = False
    if capture.suffix.lower() == ".csv":
        with open(capture, newline="", errors="replace") as fh:
            first = fh.readline()
        is_arkit = "Timecode" in first or "EyeBlinkLeft" in first
    report: dict = {"source": str(capture)}
    if is_arkit:
        cap = read_live_link_csv(capture, fps)
        names = list(expression_names)
        psi = np.zeros((len(cap["blend"]), len(names)))
        for j, a in enumerate(ARKIT):
            for n in model_name(a):
                if n not in names:
                    raise HackError(f"model: expected an expression {n!r} for ARKit's {a}, "
                                    "found none; use a model with ARKit-named expressions.")
                psi[:, names.index(n)] = cap["blend"][:, j]
        psi = np.clip(psi, 0.0, 1.0)
        tongue = cap["blend"][:, ARKIT.index("TongueOut")]
        report["dropped"] = {"TongueOut": {"why": DROPPED["TongueOut"],
                                           "frames_used": int((tongue > 0.05).sum())}}
        report["both_halves"] = list(BOTH_HALVES)
    else:
        cap = read_head_rotations(capture, fps, degrees)
        psi = None
    theta, beyond = head_to_theta(cap["head"], limits)
    report.update({"frames": len(theta), "fps": cap["fps"], "head_beyond_range": beyond,
                   "notes": cap["notes"], "kind": "arkit" if is_arkit else "head rotations"})
    return ParamSequence(fps=cap["fps"], theta=theta, psi=psi), report
