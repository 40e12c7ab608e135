"""HACK parameter files (JSON or YAML), shared by `mesh`, `render`, `turntable` and `fit`.

A parameter file is a mapping with any of these keys (all optional; missing = zero, except
``eta``, which is 1, the identity's mean larynx, for a model that carries a larynx)::

    beta: [0.5, -1.0]              # identity, in standard deviations (N(0, 1) units)
    psi: [...]                     # 53 expression weights, or instead / in addition:
    expression: {AU12: 0.7, jawOpen: 0.4}   # FACS action units and shape names
    head_rotation_deg: [20, 30, 0] # whole-head (flexion X, axial Y, lateral Z), degrees,
                                   # shared over the 8 joints by their ranges
    theta: [[x, y, z], ...]        # 8 x 3 axis-angle per joint, radians (added after the
                                   # head rotation's share when both are given)
    global_orient: [x, y, z]       # root axis-angle, radians
    transl: [x, y, z]              # metres
    eta: 1.0                       # larynx size (0 = none, 1 = the identity's mean larynx)
    tau: 0.0                       # larynx vertical slide, metres

Unknown keys are errors (a misspelt key must not be silently ignored).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hack_render.errors import HackError

KEYS = ("beta", "psi", "expression", "head_rotation_deg", "theta", "global_orient", "transl",
        "eta", "tau")


def load_params(path: str | Path) -> dict[str, Any]:
    """Read and check a JSON or YAML parameter file; returns the validated mapping."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--params {path}: file not found.")
    text = path.read_text()
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:
        raise HackError(f"--params {path}: not valid {path.suffix.lstrip('.').upper() or 'JSON'}: {exc}") from exc
    return check_params(data or {}, str(path))


def _vector(value, name: str, where: str, length: int | None = None) -> list[float]:
    arr = np.asarray(value, dtype=np.float64) if not isinstance(value, str) else None
    if arr is None or arr.ndim != 1 or (length is not None and len(arr) != length):
        want = f"a list of {length} numbers" if length else "a list of numbers"
        raise HackError(f"{where}: key '{name}' expected {want}, found {value!r}.")
    if not np.isfinite(arr).all():
        raise HackError(f"{where}: key '{name}' contains NaN or inf.")
    return arr.tolist()


def check_params(data: dict[str, Any], where: str = "parameters") -> dict[str, Any]:
    """Validate a parameter mapping (types, lengths, finiteness, known keys)."""
    if not isinstance(data, dict):
        raise HackError(f"{where}: expected a mapping of parameter names to values, found {type(data).__name__}.")
    unknown = sorted(set(data) - set(KEYS))
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
        arr = np.asarray(data["theta"], dtype=np.float64)
        if arr.shape != (8, 3) or not np.isfinite(arr).all():
            raise HackError(f"{where}: key 'theta' expected 8 x 3 finite numbers (axis-angle per "
                            f"joint c7-t1 ... o-c1, radians), found shape {arr.shape}.")
        out["theta"] = arr.tolist()
    for key in ("eta", "tau"):
        if key in data:
            try:
                val = float(data[key])
            except (TypeError, ValueError) as exc:
                raise HackError(f"{where}: key '{key}' expected a number, found {data[key]!r}.") from exc
            if not math.isfinite(val):
                raise HackError(f"{where}: key '{key}' is not finite.")
            out[key] = val
    if "expression" in data:
        expr = data["expression"]
        if isinstance(expr, str):
            out["expression"] = expr
        elif isinstance(expr, dict):
            out["expression"] = {str(k): float(v) for k, v in expr.items()}
        else:
            raise HackError(f"{where}: key 'expression' expected a mapping like {{AU12: 0.7}} "
                            f"or a string 'AU12=0.7,jawOpen=0.4', found {expr!r}.")
    return out


def save_params(path: str | Path, params: dict[str, Any]) -> Path:
    """Write a parameter mapping as JSON (or YAML by suffix), atomically."""
    path = Path(path)
    params = check_params(params, str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        tmp.write_text(yaml.safe_dump(params, sort_keys=False))
    else:
        tmp.write_text(json.dumps(params, indent=2))
    tmp.replace(path)
    return path


def model_inputs(model, params: dict[str, Any]) -> dict[str, torch.Tensor]:
    """Forward-pass keyword arguments (batch 1) for ``model`` from a checked parameter mapping."""
    from hack_render.geometry.skeleton import distribute_head_rotation

    dtype = model.template.dtype
    kw: dict[str, torch.Tensor] = {}
    if "beta" in params:
        if len(params["beta"]) > model.num_shape:
            raise HackError(f"beta: {len(params['beta'])} values given, the model has {model.num_shape} components.")
        kw["beta"] = torch.tensor([params["beta"]], dtype=dtype)
    psi = torch.zeros(model.num_expressions, dtype=dtype)
    if "psi" in params:
        if len(params["psi"]) != model.num_expressions:
            raise HackError(f"psi: expected {model.num_expressions} values, found {len(params['psi'])}.")
        psi = psi + torch.tensor(params["psi"], dtype=dtype)
    if "expression" in params:
        psi = psi + model.expression_vector(params["expression"])
    kw["psi"] = psi[None]
    theta = torch.zeros(8, 3, dtype=dtype)
    if "head_rotation_deg" in params:
        theta = theta + distribute_head_rotation(torch.deg2rad(torch.tensor(params["head_rotation_deg"], dtype=dtype)))
    if "theta" in params:
        theta = theta + torch.tensor(params["theta"], dtype=dtype)
    kw["theta"] = theta[None]
    for key in ("global_orient", "transl"):
        if key in params:
            kw[key] = torch.tensor([params[key]], dtype=dtype)
    for key in ("eta", "tau"):
        if key in params:
            kw[key] = torch.tensor([params[key]], dtype=dtype)
    if "eta" not in kw and getattr(model, "has_larynx", False):
        kw["eta"] = torch.ones(1, dtype=dtype)  # the identity's mean larynx, not none
    return kw
