"""The HACK geometry layer G(beta, psi, theta, eta, tau): torch and numpy only."""

from __future__ import annotations

import copy
import importlib
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from hack_render.errors import HackError
from hack_render.geometry.model import HackModel

if TYPE_CHECKING:  # imported lazily (below): `hack-render --help` must not import torch
    from hack_render.geometry.model import HackModel, HackOutput, PersonalizedHack
    from hack_render.geometry.skeleton import (
        JOINT_NAMES,
        adjacent_similarity_penalty,
        clamp_to_limits,
        distribute_head_rotation,
        rotation_limit_penalty,
        rotation_limits,
    )

_LAZY = {"HackModel": "model", "HackOutput": "model", "PersonalizedHack": "model",
         "JOINT_NAMES": "skeleton", "adjacent_similarity_penalty": "skeleton",
         "clamp_to_limits": "skeleton", "distribute_head_rotation": "skeleton",
         "rotation_limit_penalty": "skeleton", "rotation_limits": "skeleton"}


def __getattr__(name: str):
    """The public names of model.py and skeleton.py, imported on first use (they import
    torch, which takes seconds; the CLI imports this package for every `--help`)."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"hack_render.geometry.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'hack_render.geometry' has no attribute {name!r}")

DEFAULT_MODEL_NAME = "hack_default.npz"

__all__ = [
    "JOINT_NAMES",
    "HackModel",
    "HackOutput",
    "PersonalizedHack",
    "adjacent_similarity_penalty",
    "clamp_to_limits",
    "default_model_path",
    "distribute_head_rotation",
    "load_default_model",
    "load_model",
    "rotation_limit_penalty",
    "rotation_limits",
]


def default_model_path() -> Path:
    """Path of the built-in default model shipped as package data."""
    path = Path(str(resources.files("hack_render") / "data" / DEFAULT_MODEL_NAME))
    if not path.is_file():
        raise HackError(f"the built-in default model {path} is missing: reinstall "
                        f"hack-render, or rebuild it from ICT-FaceKit (public, MIT licence; "
                        f"github.com/ICT-VGL/ICT-FaceKit) with `hack-render model build-v2 "
                        f"--ict ICT_FACEKIT_DIR -o {path}`.")
    return path


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
