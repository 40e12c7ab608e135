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

if TYPE_CHECKING:  # imported lazily (below)
    from appearance.builder import build_model
    from appearance.detail import compose_detail, detail_slopes
    from appearance.generator import TextureSet, generate_subject
    from appearance.model import AppearanceMaps, AppearanceModel
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

#: the public names, imported on first use: importing any module of the package runs this
#: file, and the texture IO and UV layout must not load torch or SciPy through it
#: (tests/test_structure.py LAZY_PACKAGES)
_LAZY = {"AppearanceMaps": "appearance.model", "AppearanceModel": "appearance.model",
         "REGIONS": "appearance.regions", "region_labels": "appearance.regions",
         "UVLayout": "appearance.uv", "rasterize_layout": "appearance.uv",
         "compose_detail": "appearance.detail", "detail_slopes": "appearance.detail",
         "build_model": "appearance.builder", "generate_subject": "appearance.generator",
         "TextureSet": "appearance.generator", "read_exr": "appearance.texture_io",
         "write_exr": "appearance.texture_io", "read_png": "appearance.texture_io",
         "write_png": "appearance.texture_io", "read_texture_set": "appearance.texture_io",
         "write_texture_set": "appearance.texture_io"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'appearance' has no attribute {name!r}")


__all__ = sorted(_LAZY)
