"""Where skin maps come from: the appearance model (alpha or a seed), a texture folder,
or constant stand-ins. Returns :class:`~hack_render.render.materials.SkinMaps`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.io.image import read_exr
from hack_render.render.materials import VERTEX_COLOUR_PARTS, SkinMaps

TEXTURE_FILES = {"diffuse": 3, "specular": 1, "roughness": 1, "normal": 3}


def read_texture_folder(folder: str | Path) -> SkinMaps:
    """Read ``diffuse.exr`` (RGB, linear), ``specular.exr``, ``roughness.exr`` (one channel,
    e.g. ``Y`` or ``R``) and optional ``normal.exr`` (RGB = tangent-space XYZ in [-1, 1])
    from a folder. Each is (H, 2H): the skin atlas, row 0 at v = 1. An ``iris.json``
    there (:func:`read_eye_file`) gives the iris's colour and the eye whites', a
    ``parts.npz`` (:func:`read_parts_file`) the parts' per-vertex colours, a ``skin.json``
    (:func:`read_skin_file`) whether the diffuse map holds the brows."""
    folder = Path(folder)
    if not folder.is_dir():
        raise HackError(f"--textures {folder}: expected a folder with diffuse.exr, "
                        "specular.exr, roughness.exr (and optionally normal.exr), found no "
                        "such folder.")
    maps: dict[str, np.ndarray | None] = {}
    for name, c in TEXTURE_FILES.items():
        path = folder / f"{name}.exr"
        if not path.is_file():
            if name == "normal":
                maps[name] = None
                continue
            raise HackError(f"--textures {folder}: expected {path.name}, found it missing. "
                            "Write the skin maps there as EXR (docs/render.md).")
        ch = read_exr(path)
        keys = ["R", "G", "B"] if c == 3 else [k for k in ("Y", "R", "A") if k in ch][:1]
        if not keys or not all(k in ch for k in keys):
            raise HackError(f"{path}: expected channels {'R, G, B' if c == 3 else 'Y or R'}, "
                            f"found {sorted(ch)}.")
        maps[name] = np.stack([ch[k] for k in keys], axis=-1)
    return SkinMaps(maps["diffuse"], maps["specular"], maps["roughness"], maps["normal"],
                    *read_eye_file(folder / IRIS_FILE),
                    part_rgb=read_parts_file(folder / PARTS_FILE),
                    brows_baked=read_skin_file(folder / SKIN_FILE))


#: What the skin maps hold beside their pixels (``fit`` writes it): JSON with
#: ``brows_baked`` (bool: the diffuse map holds the person's brows) and ``derived``.
SKIN_FILE = "skin.json"


def read_skin_file(path: Path) -> bool:
    """``brows_baked`` of a texture folder's ``skin.json``; False where the file is absent."""
    if not path.is_file():
        return False
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise HackError(f"{path}: expected JSON with a boolean brows_baked, found it "
                        f"unreadable ({err}).") from err
    value = doc.get("brows_baked") if isinstance(doc, dict) else None
    if not isinstance(value, bool):
        raise HackError(f"{path}: expected a boolean brows_baked, found {value!r}.")
    return value


#: The per-vertex colours of the parts that are not skin beside the skin maps (``fit``
#: writes it with ``final.part_bake``): an NPZ, one (n, 3) float32 array of linear RGB
#: per part name (``materials.VERTEX_COLOUR_PARTS``), and ``derived``, a note.
PARTS_FILE = "parts.npz"


def read_parts_file(path: Path) -> dict | None:
    """{part name: (n, 3) linear RGB} of a texture folder's ``parts.npz`` (read without
    pickle); None where the file is absent."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: np.asarray(z[k], np.float32) for k in z.files if k != "derived"}
    except (OSError, ValueError, EOFError) as err:
        raise HackError(f"{path}: expected an NPZ of per-vertex part colours, found it "
                        f"unreadable ({err}).") from err
    unknown = sorted(set(out) - set(VERTEX_COLOUR_PARTS))
    if unknown:
        raise HackError(f"{path}: expected arrays named among {list(VERTEX_COLOUR_PARTS)}, "
                        f"found {unknown}.")
    return out or None


#: The iris's and the eye whites' colours beside the skin maps (``fit`` writes it: its
#: estimates from the photo).
IRIS_FILE = "iris.json"


def read_iris_file(path: Path) -> tuple[float, float, float] | None:
    """``iris_rgb`` (3 linear RGB values in [0, 1]) of a texture folder's ``iris.json``;
    None where the file is absent (the renderer's default iris)."""
    return read_eye_file(path)[0]


def read_eye_file(path: Path) -> tuple:
    """(``iris_rgb``, ``sclera_rgb``, ``eye_gloss``) of a texture folder's ``iris.json``
    (3 linear RGB values in [0, 1] each, and a share in [0, 1]; the last two are optional:
    files written before them have none); Nones where the file is absent (the renderer's
    defaults)."""
    if not path.is_file():
        return None, None, None
    try:
        doc = json.loads(path.read_text())
        out = [tuple(float(x) for x in doc["iris_rgb"])]
        out.append(tuple(float(x) for x in doc["sclera_rgb"]) if doc.get("sclera_rgb")
                   is not None else None)
        gloss = None if doc.get("eye_gloss") is None else float(doc["eye_gloss"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
        raise HackError(f"{path}: expected JSON with \"iris_rgb\": [r, g, b] (linear, 0..1) "
                        f"and optionally \"sclera_rgb\", found it unreadable ({err}).") from err
    for key, rgb in zip(("iris_rgb", "sclera_rgb"), out):
        if rgb is not None and (len(rgb) != 3 or not all(np.isfinite(x) and 0.0 <= x <= 1.0
                                                         for x in rgb)):
            raise HackError(f"{path}: expected \"{key}\" as 3 linear RGB values in [0, 1], "
                            f"found {list(rgb)}.")
    if gloss is not None and not (np.isfinite(gloss) and 0.0 <= gloss <= 1.0):
        raise HackError(f"{path}: expected \"eye_gloss\" as a share in [0, 1], found {gloss}.")
    return out[0], out[1], gloss


def appearance_maps(alpha: list[float] | None, seed: int | None, height: int = 512) -> SkinMaps:
    """Maps from the appearance layer: a procedural subject for ``seed``
    (``appearance.generator.generate_subject``), or the PCA model's ``maps(alpha)``."""
    # the appearance model and generator import torch (2.2 s): a render from texture files
    # or constant maps (and from the mesh cache) runs without it; listed deferrals
    from appearance.generator import generate_subject
    from appearance.model import AppearanceModel

    if alpha is None:
        if seed is None or seed < 0:
            raise HackError(f"--appearance-seed: expected a non-negative integer, found {seed}.")
        return SkinMaps.from_appearance(generate_subject(int(seed), height=height))
    import torch

    model = AppearanceModel.load()  # the shipped default; HackError if unusable
    a = torch.tensor([alpha], dtype=torch.float32)  # k <= n_components, checked by maps()
    with torch.no_grad():
        return SkinMaps.from_appearance(model.maps(a))


def skin_maps(alpha: list[float] | None = None, seed: int | None = None,
              textures: str | Path | None = None) -> SkinMaps:
    """Pick the source: a texture folder, the appearance model, or constant maps."""
    if textures is not None:
        return read_texture_folder(textures)
    if alpha is not None or seed is not None:
        return appearance_maps(alpha, seed)
    return SkinMaps.constant()
