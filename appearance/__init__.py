"""Appearance model A(alpha) of HACK: PCA over skin UV maps, builder, texture IO, colour,
and a calibrated procedural skin population (the shipped default model is procedural).

Public API:
    AppearanceModel, AppearanceMaps (model.py); compose_detail, detail_slopes (detail.py);
    build_model (builder.py); generate_subject, TextureSet (generator.py);
    read_exr, write_exr, read_png, write_png, read_texture_set, write_texture_set
    (texture_io.py); rasterize_layout, UVLayout (uv.py); region_labels, REGIONS (regions.py).
This package never imports Mitsuba or Dr.Jit.
"""

import importlib
from typing import TYPE_CHECKING

# first, before any module here imports torch: the package sets the OpenMP wait policy
import hack_render  # noqa: F401
from appearance.generator import TextureSet, generate_subject
from appearance.regions import REGIONS, region_labels
from appearance.texture_io import (
    read_exr,
    read_png,
    read_texture_set,
    write_exr,
    write_png,
    write_texture_set,
)
from appearance.uv import UVLayout, rasterize_layout

if TYPE_CHECKING:  # imported lazily (below)
    from appearance.builder import build_model
    from appearance.detail import compose_detail, detail_slopes
    from appearance.model import AppearanceMaps, AppearanceModel

#: the public names of the modules that import torch (2.2 s), imported on first use:
#: `import appearance.texture_io` (the render from texture files, the mesh cache) must not
#: load torch through the package (tests/test_structure.py lists this deferral)
_LAZY = {"AppearanceMaps": "appearance.model", "AppearanceModel": "appearance.model",
         "compose_detail": "appearance.detail", "detail_slopes": "appearance.detail",
         "build_model": "appearance.builder"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'appearance' has no attribute {name!r}")


__all__ = ["REGIONS", "AppearanceMaps", "AppearanceModel", "TextureSet", "UVLayout",
           "build_model", "compose_detail", "detail_slopes", "generate_subject", "rasterize_layout",
           "read_exr", "read_png", "read_texture_set", "region_labels", "write_exr", "write_png",
           "write_texture_set"]
