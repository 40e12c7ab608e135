"""The HACK geometry layer G(beta, psi, theta, eta, tau): torch and numpy only."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from hack_render.geometry.model_file import DEFAULT_MODEL_NAME, default_model_path

if TYPE_CHECKING:  # imported lazily (below): the NumPy posing path must not import torch
    from hack_render.geometry.loading import load_default_model, load_model
    from hack_render.geometry.model import HackModel, HackOutput
    from hack_render.geometry.personalized import PersonalizedHack
    from hack_render.geometry.skeleton import (
        JOINT_NAMES,
        adjacent_similarity_penalty,
        clamp_to_limits,
        distribute_head_rotation,
        rotation_limit_penalty,
        rotation_limits,
    )

_LAZY = {"HackModel": "model", "HackOutput": "model", "PersonalizedHack": "personalized",
         "JOINT_NAMES": "skeleton", "adjacent_similarity_penalty": "skeleton",
         "clamp_to_limits": "skeleton", "distribute_head_rotation": "skeleton",
         "rotation_limit_penalty": "skeleton", "rotation_limits": "skeleton",
         "load_model": "loading", "load_default_model": "loading"}


def __getattr__(name: str):
    """The public names of model.py, skeleton.py and loading.py, imported on first use:
    they import torch (2.2 s), which `hack-render mesh` and the render's mesh cache do
    without (tests/test_structure.py lists this deferral)."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"hack_render.geometry.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'hack_render.geometry' has no attribute {name!r}")


__all__ = [
    "DEFAULT_MODEL_NAME",
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
