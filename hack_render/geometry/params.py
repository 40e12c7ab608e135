"""HACK parameter files (JSON or YAML), shared by `mesh`, `render`, `turntable` and `fit`.

A parameter file is a mapping with any of these keys (all optional; missing = zero, except
``eta``, which is 1, the identity's own larynx: the same default as the Python API,
``HackModel.forward``)::

    beta: [0.5, -1.0]              # identity, in standard deviations (N(0, 1) units)
    psi: [...]                     # 53 expression weights, or instead / in addition:
    expression: {AU12: 0.7, jawOpen: 0.4}   # FACS action units and shape names
    head_rotation_deg: [20, 30, 0] # whole-head (flexion X, axial Y, lateral Z), degrees,
                                   # shared over the 8 joints by their ranges (the
                                   # whole neck's range: skeleton.head_rotation_range_deg)
    theta: [[x, y, z], ...]        # 8 x 3 axis-angle per joint, radians (added after the
                                   # head rotation's share when both are given)
    global_orient: [x, y, z]       # root axis-angle, radians
    transl: [x, y, z]              # metres
    eta: 1.0                       # larynx size, 0..1.5 (0 = none, 1 = the identity's own)
    tau: 0.0                       # larynx vertical slide, metres, up, -0.01..0.02
    hair: {archetype: long, color: brown, beard: stubble}   # the hair layer (docs/hair.md)

Values beyond the anatomical limits (joints, head rotation, eta, tau) are governed by the
commands' ``--limits`` (:mod:`hack_render.geometry.limits`).

The commands that pose the model gather their parameters here: :func:`gather_params` reads
``--params`` and lets the pose flags (:func:`check_flags`) override it, and
:func:`forward_inputs` / :func:`model_inputs` turn the result into a forward pass's inputs.

Unknown keys are errors (a misspelt key must not be silently ignored).

A parameter *sequence* (:class:`ParamSequence`, :func:`load_sequence`) animates one person:
per-frame ``theta``, ``psi``, ``tau``, ``global_orient``, ``transl`` at a frame rate ``fps``,
as ``.npz`` arrays or JSON lines (a header line, then one object per frame).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from hack_render import boundary
from hack_render.errors import HackError
from hack_render.geometry.anatomy import ETA_DEFAULT, distribute_head_rotation
from hack_render.io import atomic_write_text, write_json
from hack_render.io.npz import write_npz

if TYPE_CHECKING:  # torch is imported where tensors are made: parsing and checking need none
    import torch

KEYS = ("beta", "psi", "expression", "head_rotation_deg", "theta", "global_orient", "transl",
        "eta", "tau", "hair")


#: Hard bounds of each key (beyond them a value means nothing, under any ``--limits``;
#: the anatomical limits inside them are :mod:`hack_render.geometry.limits`' business).
BOUNDS = {"beta": 10.0, "psi": 10.0, "expression": 10.0, "head_rotation_deg": 360.0,
          "theta": 2 * math.pi, "global_orient": 2 * math.pi, "transl": 10.0,
          "eta": (0.0, 10.0), "tau": (-0.1, 0.1)}
#: What each bound means, for the messages.
_UNITS = {"beta": " (standard deviations)", "psi": "", "expression": "",
          "head_rotation_deg": " degrees", "theta": " radians", "global_orient": " radians",
          "transl": " metres", "eta": "", "tau": " metres"}


def parse_params_text(text: str, suffix: str, where: str) -> Any:
    """The data of a parameter file's text: JSON (duplicate keys and NaN refused) or YAML
    (``suffix`` .yaml/.yml; duplicate keys refused)."""
    try:
        if suffix.lower() in (".yaml", ".yml"):
            return boundary.parse_yaml(text)
        return boundary.parse_json(text)
    except HackError as exc:
        raise HackError(f"--params {where}: {exc}") from exc
    except (ValueError, RecursionError) as exc:  # json.JSONDecodeError is a ValueError
        kind = "YAML" if suffix.lower() in (".yaml", ".yml") else "JSON"
        raise HackError(f"--params {where}: not valid {kind} ({str(exc)[:200]}).") from exc
    except Exception as exc:  # yaml.YAMLError and its parser/scanner errors
        raise HackError(f"--params {where}: not valid YAML ({str(exc).splitlines()[0][:200]})."
                        ) from exc


#: A parameter file holds at most a few hundred numbers; anything this large is not one.
MAX_PARAMS_BYTES = 16 * 1024 * 1024


def load_params(path: str | Path) -> dict[str, Any]:
    """Read and check a JSON or YAML parameter file; returns the validated mapping."""
    path = Path(path)
    if path.is_dir():
        raise HackError(f"--params {path}: expected a .json or .yaml file, found a folder.")
    if not path.is_file():
        raise HackError(f"--params {path}: file not found.")
    if path.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise HackError(f"--params {path}: expected a .json, .yaml or .yml file, found "
                        f"{repr(path.suffix) if path.suffix else 'no suffix'}.")
    size = path.stat().st_size
    if size > MAX_PARAMS_BYTES:
        raise HackError(f"--params {path}: expected a parameter file of a few KB, found "
                        f"{size / 1e6:.0f} MB. Pass the parameter file, not a data file.")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise HackError(f"--params {path}: expected UTF-8 text, found binary data.") from exc
    except OSError as exc:
        raise HackError(f"--params {path}: not readable ({exc.strerror}).") from exc
    data = parse_params_text(text, path.suffix, str(path))
    if data is None and _has_content(text):  # `null` (or YAML's `~`): not a mapping
        raise HackError(f"--params {path}: expected a mapping of parameter names to values, "
                        f"e.g. {{\"beta\": [0.5, -1.0]}} ({{}} for none), found null.")
    return check_params({} if data is None else data, str(path))


def _has_content(text: str) -> bool:
    """Whether a parameter file says something: a line other than blanks, comments and
    YAML's document markers (an empty file, or one of comments, reads as no parameters)."""
    return any(ln.strip() and not ln.lstrip().startswith("#") and ln.strip() not in ("---", "...")
               for ln in text.splitlines())


def _bound_text(key: str) -> tuple[float, float, str]:
    b = BOUNDS[key]
    lo, hi = (-b, b) if not isinstance(b, tuple) else b
    return lo, hi, f"{lo:g}..{hi:g}{_UNITS[key]}"


def _array(value, key: str, where: str, shape: tuple, want: str) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (None: any length) inside the key's
    hard bounds, else a HackError naming the key."""
    ok = not isinstance(value, (str, bytes, dict, bool)) and value is not None
    shown = repr(value) if len(repr(value)) < 80 else repr(value)[:77] + "..."
    bad = _non_number(value) if ok else None
    if bad is not None:  # NumPy would read true as 1.0 and "2" as 2.0
        found = (f"{str(bool(bad[0])).lower()} (true and false are not numbers)"
                 if isinstance(bad[0], (bool, np.bool_)) else f"{bad[0]!r} in {shown}")
        raise HackError(f"{where}: key '{key}' expected {want}, found {found}.")
    arr = None
    if ok:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            arr = None
    if arr is None or arr.dtype == object:
        raise HackError(f"{where}: key '{key}' expected {want}, found {shown}.")
    if arr.ndim != len(shape) or any(d is not None and d != s for d, s in zip(shape, arr.shape)):
        raise HackError(f"{where}: key '{key}' expected {want}, found shape {arr.shape}.")
    if not np.isfinite(arr).all():
        raise HackError(f"{where}: key '{key}' contains NaN or inf; expected finite numbers.")
    lo, hi, text = _bound_text(key)
    if arr.size and (arr.min() < lo or arr.max() > hi):
        bad = arr.min() if arr.min() < lo else arr.max()
        raise HackError(f"{where}: key '{key}' expected values in {text}, found {bad:g}.")
    return arr


def _non_number(value) -> tuple[Any] | None:
    """``(element,)``: the first element of a (nested) list, array or tensor that is not a
    number (booleans and strings are not), or None when all are."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, (list, tuple)):
            stack.extend(reversed(v))
            continue
        if v is None or isinstance(v, (bool, np.bool_, str, bytes, dict)):
            return (v,)
        if isinstance(v, (int, float, np.number)):
            continue
        try:
            a = np.asarray(v)  # an array, a tensor
        except Exception:  # noqa: BLE001 - whatever it is, it is not a number
            return (v,)
        if a.dtype.kind in "iuf":
            continue
        if a.dtype.kind == "O" and a.ndim:
            stack.extend(reversed(a.ravel().tolist()))
            continue
        return (a.ravel()[0].item() if a.size and a.dtype.kind != "O" else v,)
    return None


def _vector(value, name: str, where: str, length: int | None = None) -> list[float]:
    want = f"a list of {length} numbers" if length else "a list of numbers"
    return _array(value, name, where, (length,), want).tolist()


def _scalar(value, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise HackError(f"{where}: key '{key}' expected a number, found {value!r}.")
    return float(_array(value, key, where, (), "a number"))


def parse_expression(text: str, where: str) -> dict[str, float]:
    """``"AU12=0.7, jawOpen=0.4"`` -> {name: weight}, each weight finite and inside the
    hard bound; names are checked against the model later (``expression_vector``)."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in re.split(r"[,;]", text))):
        name, eq, value = part.partition("=")
        try:
            weight = float(value) if eq and name.strip() else None
        except ValueError:
            weight = None
        if weight is None:
            raise HackError(f"{where}: expected NAME=VALUE pairs like 'AU12=0.7,jawOpen=0.4', "
                            f"found {part!r}.")
        out[name.strip()] = _expr_weight(weight, name.strip(), where)
    return out


def _expression(expr, where: str):
    if isinstance(expr, str):
        return parse_expression(expr, f"{where}: key 'expression'")
    if not isinstance(expr, dict):
        raise HackError(f"{where}: key 'expression' expected a mapping like {{AU12: 0.7}} or "
                        f"a string 'AU12=0.7,jawOpen=0.4', found {expr!r}.")
    out = {}
    for k, v in expr.items():
        if not isinstance(k, str):
            raise HackError(f"{where}: key 'expression' expected names (AU12, jawOpen), "
                            f"found {k!r}.")
        out[k] = _expr_weight(v, k, where)
    return out


def _expr_weight(v, name: str, where: str) -> float:
    what = f"{where}: key 'expression.{name}'" if where.endswith(("json", "yaml", "yml",
                                                                   "parameters")) else \
        f"{where} {name}"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise HackError(f"{what}: expected a number, found {v!r}.")
    lo, hi, text = _bound_text("expression")
    if not math.isfinite(v) or not lo <= v <= hi:
        raise HackError(f"{what}: expected a finite weight in {text}, found {v!r}.")
    return float(v)


def check_params(data: dict[str, Any], where: str = "parameters") -> dict[str, Any]:
    """Validate a parameter mapping: known keys, types, shapes, finite values inside
    :data:`BOUNDS`. Returns plain lists and floats."""
    if not isinstance(data, dict):
        raise HackError(f"{where}: expected a mapping of parameter names to values, found "
                        f"{type(data).__name__}.")
    unknown = sorted(map(str, set(data) - set(KEYS)))
    if unknown:
        raise HackError(f"{where}: unknown keys {unknown}; known keys: {', '.join(KEYS)}.")
    out: dict[str, Any] = {}
    for key in ("beta", "psi"):
        if key in data:
            out[key] = _vector(data[key], key, where)
    for key in ("head_rotation_deg", "global_orient", "transl"):
        if key in data:
            out[key] = _vector(data[key], key, where, 3)
    if "theta" in data:
        out["theta"] = _array(data["theta"], "theta", where, (8, 3), "8 x 3 numbers "
                              "(axis-angle per joint c7-t1 ... o-c1, radians)").tolist()
    for key in ("eta", "tau"):
        if key in data:
            out[key] = _scalar(data[key], key, where)
    if "expression" in data:
        out["expression"] = _expression(data["expression"], where)
    if "hair" in data:
        out["hair"] = _hair(data["hair"], where)
    return out


def _hair(value: Any, where: str) -> Any:
    """The ``hair`` section's shape: a style name, a mapping of style fields, or null (no
    hair). Its fields are checked by :class:`hack_render.hair.style.HairStyle`."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return dict(value)
    raise HackError(f"{where}: hair: expected a style name, a mapping of hair fields or null, "
                    f"found {type(value).__name__}.")


def parse_floats(text: str | None, name: str) -> list[float] | None:
    """Comma-separated finite numbers of option ``--name`` (None passes through)."""
    return boundary.numbers(text, f"--{name}")


def check_flags(beta: str | None, expression: str | None, head_rotation: str | None,
                eta: float | None, tau: float | None) -> dict:
    """The pose flags of `mesh`, `render`, `turntable`, `export`, checked (finite, inside
    the hard bounds of :data:`BOUNDS`) and named by option."""
    b = boundary
    return {"beta": b.numbers(beta, "--beta", None, -BOUNDS["beta"], BOUNDS["beta"],
                              unit=" (standard deviations)", example="1.0,-0.5"),
            "expression": None if expression is None else parse_expression(expression, "--expr"),
            "head_rotation_deg": b.numbers(head_rotation, "--head-rotation", 3, -360, 360,
                                           unit=" degrees", example="15,40,0"),
            "eta": b.number(eta, "--eta", *BOUNDS["eta"]),
            "tau": b.number(tau, "--tau", *BOUNDS["tau"], unit=" metres")}


def gather_params(params_file: Path | None, beta: str | None, expression: str | None,
                  head_rotation: str | None, eta: float | None, tau: float | None) -> dict:
    """Parameters from a file, overridden by command-line flags (shared by several commands)."""
    flags = check_flags(beta, expression, head_rotation, eta, tau)
    params = load_params(params_file) if params_file else {}
    params.update({k: v for k, v in flags.items() if v is not None})
    return check_params(params, "command-line parameters")


def save_params(path: str | Path, params: dict[str, Any]) -> Path:
    """Write a parameter mapping as JSON (or YAML by suffix), atomically."""
    path = Path(path)
    params = check_params(params, str(path))
    if path.suffix.lower() in (".yaml", ".yml"):
        return atomic_write_text(path, yaml.safe_dump(params, sort_keys=False))
    return write_json(path, params, indent=2)


def forward_inputs(model, params: dict[str, Any], dtype=np.float32) -> dict[str, np.ndarray]:
    """One row of forward inputs (unbatched NumPy arrays of ``dtype``) for ``model`` from a
    checked parameter mapping: ``psi`` and ``theta`` always, ``eta`` where the model has a
    larynx, the others where given. ``model``: a :class:`~hack_render.geometry.model.HackModel`
    or a :class:`~hack_render.geometry.posing.PosingModel` (``num_shape``,
    ``num_expressions``, ``has_larynx``, ``expression_vector``)."""
    kw: dict[str, np.ndarray] = {}
    if "beta" in params:
        if len(params["beta"]) > model.num_shape:
            raise HackError(f"beta: {len(params['beta'])} values given, the model has "
                            f"{model.num_shape} components.")
        kw["beta"] = np.asarray(params["beta"], dtype)
    psi = np.zeros(model.num_expressions, dtype)
    if "psi" in params:
        if len(params["psi"]) != model.num_expressions:
            raise HackError(f"psi: expected {model.num_expressions} values, found "
                            f"{len(params['psi'])}.")
        psi = psi + np.asarray(params["psi"], dtype)
    if "expression" in params:
        e = model.expression_vector(params["expression"])
        psi = psi + np.asarray(e.detach().cpu() if hasattr(e, "detach") else e, dtype)
    kw["psi"] = psi
    theta = np.zeros((8, 3), dtype)
    if "head_rotation_deg" in params:
        share = distribute_head_rotation(np.deg2rad(params["head_rotation_deg"]))
        theta = theta + share.astype(dtype)
    if "theta" in params:
        theta = theta + np.asarray(params["theta"], dtype)
    kw["theta"] = theta
    for key in ("global_orient", "transl", "eta", "tau"):
        if key in params:
            kw[key] = np.asarray(params[key], dtype)
    if "eta" not in kw and getattr(model, "has_larynx", False):
        kw["eta"] = np.asarray(ETA_DEFAULT, dtype)  # the API's default too
    return kw


def model_inputs(model, params: dict[str, Any]) -> dict[str, torch.Tensor]:
    """Forward-pass keyword arguments (batch 1) for ``model`` from a checked parameter
    mapping: :func:`forward_inputs` as tensors of the model's dtype."""
    import torch

    dtype = model.template.dtype
    arrays = forward_inputs(model, params, np.float64 if dtype == torch.float64 else np.float32)
    return {k: torch.as_tensor(v, dtype=dtype)[None] for k, v in arrays.items()}


# ------------------------------------------------------------------ parameter sequences
#: Per-frame keys of a parameter sequence and each frame's shape (None: any length).
SEQUENCE_KEYS: dict[str, tuple[int | None, ...]] = {
    "theta": (8, 3), "psi": (None,), "tau": (), "global_orient": (3,), "transl": (3,)}
SEQUENCE_FORMAT = "hack-sequence"


@dataclass(frozen=True)
class ParamSequence:
    """A parameter sequence: per-frame pose, expression and larynx arrays at a frame rate.

    The identity (beta, eta) is not part of it: it animates one person, whose parameter
    file gives them. Missing per-frame keys are zero (psi: the neutral face).

    Attributes:
        fps: frames per second (> 0).
        theta: (T, 8, 3) axis-angle per joint c7-t1 ... o-c1, radians.
        psi: (T, E) expression weights, or None.
        tau: (T,) larynx vertical slide, metres, or None.
        global_orient: (T, 3) root axis-angle, radians, or None.
        transl: (T, 3) metres, or None.
    """

    fps: float
    theta: np.ndarray
    psi: np.ndarray | None = None
    tau: np.ndarray | None = None
    global_orient: np.ndarray | None = None
    transl: np.ndarray | None = None

    @property
    def frames(self) -> int:
        return len(self.theta)

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-frame arrays that are present, by key."""
        return {k: getattr(self, k) for k in SEQUENCE_KEYS if getattr(self, k) is not None}


def _frame_error(where: str, frame: int, key: str, msg: str) -> HackError:
    return HackError(f"{where}: frame {frame}, key '{key}': {msg}")


def _check_frames(where: str, key: str, arr: np.ndarray, frames: int,
                  num_expressions: int | None) -> np.ndarray:
    """(T, ...) array of one key: shape per frame and finite values, else the frame named."""
    want = SEQUENCE_KEYS[key]
    if key == "psi" and num_expressions is not None:
        want = (num_expressions,)
    shape_text = " x ".join("E" if d is None else str(d) for d in want) or "a number"
    if arr.ndim != len(want) + 1 or any(d is not None and d != s for d, s in
                                         zip(want, arr.shape[1:], strict=True)):
        raise _frame_error(where, 0, key, f"expected {shape_text} per frame, found "
                           f"{arr.shape[1:] or 'a number'} (array shape {arr.shape}).")
    if len(arr) != frames:
        raise HackError(f"{where}: key '{key}' has {len(arr)} frames, key 'theta' has "
                        f"{frames}; every per-frame key needs one entry per frame.")
    bad = ~np.isfinite(arr.reshape(len(arr), -1)).all(1)
    if bad.any():
        raise _frame_error(where, int(np.flatnonzero(bad)[0]), key, "contains NaN or inf.")
    return arr.astype(np.float64)


def check_sequence(data: dict[str, Any], fps: Any, where: str = "sequence",
                   num_expressions: int | None = None) -> ParamSequence:
    """Validate per-frame arrays (``SEQUENCE_KEYS``) and a frame rate into a sequence."""
    unknown = sorted(set(data) - set(SEQUENCE_KEYS))
    if unknown:
        raise HackError(f"{where}: unknown keys {unknown}; per-frame keys: "
                        f"{', '.join(SEQUENCE_KEYS)} (and 'fps').")
    try:
        fps = float(np.asarray(fps).item())
    except (TypeError, ValueError) as exc:
        raise HackError(f"{where}: key 'fps' expected a number of frames per second, found "
                        f"{fps!r}.") from exc
    if not (math.isfinite(fps) and 0 < fps <= 1000):
        raise HackError(f"{where}: key 'fps' expected a frame rate in (0, 1000], found {fps}.")
    if "theta" not in data:
        raise HackError(f"{where}: key 'theta' is missing: a sequence needs (T, 8, 3) joint "
                        "rotations (zeros for a still neck).")
    theta = np.asarray(data["theta"], dtype=np.float64)
    if theta.ndim == 0 or len(theta) == 0:
        raise HackError(f"{where}: key 'theta' holds no frames; expected (T, 8, 3), T >= 1.")
    out = {k: _check_frames(where, k, np.asarray(v, dtype=np.float64), len(theta),
                            num_expressions) for k, v in data.items()}
    return ParamSequence(fps=fps, **out)


def _jsonl_frames(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    header, frames = None, []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            obj = boundary.parse_json(line)
        except HackError as exc:  # a key twice in one frame
            raise HackError(f"{path}:{lineno}: {exc}") from exc
        except (json.JSONDecodeError, RecursionError) as exc:
            msg = getattr(exc, "msg", "nested too deeply")
            raise HackError(f"{path}:{lineno}: not valid JSON ({msg}); expected one JSON "
                            "object per line.") from exc
        if not isinstance(obj, dict):
            raise HackError(f"{path}:{lineno}: expected a JSON object, found "
                            f"{type(obj).__name__}.")
        if header is None:
            header = obj
        else:
            frames.append(obj)
    if header is None or "fps" not in header:
        raise HackError(f"{path}: the first line must be the header "
                        f'{{"format": "{SEQUENCE_FORMAT}", "fps": 24}}; found '
                        f"{'an empty file' if header is None else sorted(header)}.")
    return header, frames


def _stack_frames(path: Path, frames: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Per-key (T, ...) arrays from frame objects; every frame must carry frame 0's keys."""
    if not frames:
        raise HackError(f"{path}: no frames after the header; expected one JSON object per "
                        "frame with 'theta' (and optionally psi, tau, global_orient, transl).")
    keys = list(frames[0])
    out: dict[str, list] = {k: [] for k in keys}
    for i, fr in enumerate(frames):
        unknown = sorted(set(fr) - set(SEQUENCE_KEYS))
        if unknown:
            raise _frame_error(str(path), i, unknown[0], "unknown key; per-frame keys: "
                               f"{', '.join(SEQUENCE_KEYS)}.")
        for k in keys:
            if k not in fr:
                raise _frame_error(str(path), i, k, "missing (frame 0 has it; every frame "
                                   "needs the same keys).")
            try:
                a = np.asarray(fr[k], dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise _frame_error(str(path), i, k, f"expected numbers, found {fr[k]!r}.") from exc
            want = SEQUENCE_KEYS[k]
            if a.ndim != len(want) or any(d is not None and d != s
                                          for d, s in zip(want, a.shape, strict=True)):
                shape_text = " x ".join("E" if d is None else str(d) for d in want) or "a number"
                raise _frame_error(str(path), i, k, f"expected {shape_text}, found shape "
                                   f"{a.shape or 'a number'}.")
            if not np.isfinite(a).all():
                raise _frame_error(str(path), i, k, "contains NaN or inf.")
            if k == "psi" and out[k] and a.shape != out[k][0].shape:
                raise _frame_error(str(path), i, k, f"expected {out[k][0].shape[0]} values like "
                                   f"frame 0, found {a.shape[0]}.")
            out[k].append(a)
        extra = sorted(set(fr) - set(keys))
        if extra:
            raise _frame_error(str(path), i, extra[0], "not in frame 0; every frame needs the "
                               "same keys.")
    return {k: np.stack(v) for k, v in out.items()}


def load_sequence(path: str | Path, num_expressions: int | None = None) -> ParamSequence:
    """Read and validate a parameter sequence: ``.npz`` or JSON lines (``.jsonl``).

    NPZ: arrays ``theta`` (T, 8, 3) and optionally ``psi`` (T, E), ``tau`` (T,),
    ``global_orient`` (T, 3), ``transl`` (T, 3), plus a scalar ``fps``.
    JSON lines: a header ``{"format": "hack-sequence", "fps": 24}``, then one object per
    frame with the same keys (each frame's values, e.g. ``"theta": [[0, 0.1, 0], ...]``).
    Errors name the file, the frame and the key. ``num_expressions`` checks psi's length.
    """
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--sequence {path}: file not found.")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as exc:
            raise HackError(f"{path}: not a readable .npz ({exc}).") from exc
        if "fps" not in data:
            raise HackError(f"{path}: key 'fps' is missing; save the frame rate as a scalar "
                            "array 'fps'.")
        fps = data.pop("fps")
        data.pop("format", None)
    elif suffix in (".jsonl", ".ndjson"):
        header, frames = _jsonl_frames(path)
        fps = header["fps"]
        data = _stack_frames(path, frames)
    else:
        raise HackError(f"--sequence {path}: expected a .npz or .jsonl file, found "
                        f"{suffix or 'no suffix'}.")
    return check_sequence(data, fps, str(path), num_expressions)


def save_sequence(path: str | Path, seq: ParamSequence) -> Path:
    """Write a sequence as ``.npz`` or JSON lines (by suffix), atomically."""
    path = Path(path)
    seq = check_sequence(seq.arrays(), seq.fps, str(path))
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".jsonl", ".ndjson"):
        raise HackError(f"{path}: expected a .npz or .jsonl sequence file, found "
                        f"{suffix or 'no suffix'}.")
    if suffix == ".npz":
        return write_npz(path, {"fps": np.float64(seq.fps), "format": np.str_(SEQUENCE_FORMAT),
                                **seq.arrays()})
    arrays = seq.arrays()
    lines = [json.dumps({"format": SEQUENCE_FORMAT, "version": 1, "fps": seq.fps})]
    lines += [json.dumps({k: a[i].tolist() for k, a in arrays.items()})
              for i in range(seq.frames)]
    return atomic_write_text(path, "\n".join(lines) + "\n")


def sequence_inputs(model, seq: ParamSequence) -> dict[str, torch.Tensor]:
    """Forward-pass keyword arguments (batch T) of a sequence, without beta and eta."""
    dtype = model.template.dtype
    if seq.psi is not None and seq.psi.shape[1] != model.num_expressions:
        raise _frame_error("sequence", 0, "psi", f"expected {model.num_expressions} values "
                           f"(the model's expressions), found {seq.psi.shape[1]}.")
    import torch

    return {k: torch.as_tensor(a, dtype=dtype) for k, a in seq.arrays().items()}
