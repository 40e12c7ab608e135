"""Appearance model A(alpha) of HACK: PCA over skin UV maps, builder, texture IO, colour,
and a calibrated procedural skin population (the shipped default model is procedural).

Public API:
    AppearanceModel, AppearanceMaps (model.py); compose_detail, detail_slopes (detail.py);
    build_model (builder.py); generate_subject, TextureSet (generator.py);
    read_exr, write_exr, read_png, write_png, read_texture_set, write_texture_set
    (texture_io.py); rasterize_layout, UVLayout (uv.py); region_labels, REGIONS (regions.py).
This package never imports Mitsuba or Dr.Jit.
"""

from typing import TYPE_CHECKING

# first, before any module here imports torch: the package sets the OpenMP wait policy
import hack_render  # noqa: F401

if TYPE_CHECKING:  # imported lazily (below): `hack-render --help` must not import torch
    from appearance.model import AppearanceMaps, AppearanceModel  # noqa: F401
    from appearance.regions import REGIONS, region_labels  # noqa: F401
    from appearance.uv import UVLayout, rasterize_layout  # noqa: F401


def __getattr__(name):  # lazy imports keep `import appearance` light
    lazy = {"AppearanceMaps": "appearance.model", "AppearanceModel": "appearance.model",
            "REGIONS": "appearance.regions", "region_labels": "appearance.regions",
            "UVLayout": "appearance.uv", "rasterize_layout": "appearance.uv",
            "compose_detail": "appearance.detail", "detail_slopes": "appearance.detail",
            "build_model": "appearance.builder", "generate_subject": "appearance.generator",
            "TextureSet": "appearance.generator", "read_exr": "appearance.texture_io",
            "write_exr": "appearance.texture_io", "read_png": "appearance.texture_io",
            "write_png": "appearance.texture_io", "read_texture_set": "appearance.texture_io",
            "write_texture_set": "appearance.texture_io"}
    if name in lazy:
        import importlib

        return getattr(importlib.import_module(lazy[name]), name)
    raise AttributeError(name)
