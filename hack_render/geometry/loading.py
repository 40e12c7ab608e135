"""Loading the differentiable model (torch): :func:`load_model`, :func:`load_default_model`
(re-exported by :mod:`hack_render.geometry`), and :func:`posed_model`, which loads and
poses one mesh from a parameter file and flags (:mod:`hack_render.geometry.posing` does the
same in NumPy, without torch)."""

from __future__ import annotations

import copy
from functools import lru_cache
from pathlib import Path

import torch

from hack_render import boundary
from hack_render.geometry.limits import apply_limit_policy
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import default_model_path
from hack_render.geometry.params import gather_params, model_inputs


@lru_cache(maxsize=4)
def _load_cached(path: str, stamp: tuple[int, int]) -> HackModel:
    """The model file at ``path`` as loaded once per (modification time, size) ``stamp``:
    the prototype that :func:`load_model` hands out independent copies of."""
    return HackModel.from_file(path)


def _independent_copy(model: HackModel) -> HackModel:
    """A new module (its own submodules, attributes and buffer tables) whose buffers are
    the prototype's tensors: no memory is copied, and ``.double()`` / ``.to()`` / attribute
    changes on one copy replace that copy's tensors only. Treat the buffers as read-only:
    an in-place change (``model.template.add_(...)``) would show in every copy."""
    return copy.deepcopy(model, {id(t): t for t in model.buffers()})


def load_model(path: str | Path | None = None) -> HackModel:
    """Load a model file (default: the built-in model).

    Every call returns an independent module: ``.double()``, ``.to(device)`` or changed
    attributes in one caller's model do not change another's. The file is read and
    validated once per path (again when the file changes), and the copies share its
    tensors read-only."""
    p = Path(path) if path is not None else default_model_path()
    try:
        st = p.stat()
        stamp = (st.st_mtime_ns, st.st_size)
    except OSError:
        stamp = (0, 0)  # a missing file: from_file says so
    return _independent_copy(_load_cached(str(p), stamp))


def load_default_model() -> HackModel:
    """The built-in default HACK model (ICT-FaceKit based; docs/model.md), an independent
    module per call (see :func:`load_model`)."""
    return load_model(None)


def posed_model(params_file, beta, expression, head_rotation, eta, tau, limits, model_path):
    """Load a model and pose it from a parameter file and flags, with torch (the
    differentiable :class:`~hack_render.geometry.model.HackModel`; :func:`posed_vertices`
    gives the same vertices without torch).

    Returns (model, forward keyword arguments, posed vertices (N, 3) numpy).
    """
    if model_path is not None:
        boundary.input_file(model_path, "--model", (".npz",), "model file")
    model = load_model(model_path)
    p = gather_params(params_file, beta, expression, head_rotation, eta, tau)
    kw = apply_limit_policy(model_inputs(model, p), limits, p.get("head_rotation_deg"))
    with torch.no_grad():
        out = model(**kw)
    return model, kw, out.vertices[0].numpy()
