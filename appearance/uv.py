"""The skin UV atlas of the template: rasterisation, validity mask and seam dilation.

The template (ICT-FaceKit ``generic_neutral_mesh.obj``, shipped as ``data/ict_template.npz``) lays its skin out in two UDIM-like
tiles: material ``M_Face`` in u in [0, 1] (tile 0, the face) and ``M_BackHead`` in
u in [1, 2] (tile 1: back of the head, scalp, ears, neck down to the shoulders, and the
mouth and eye sockets). A skin map is one image covering u in [0, 2], v in [0, 1]:

- shape (H, 2H, C); columns [0, H) are tile 0, columns [H, 2H) are tile 1;
- texel (i, j) has its centre at u = (j + 0.5) / H, v = 1 - (i + 0.5) / H (row 0 is the
  top, v = 1), the convention of image files and of Mitsuba's ``bitmap`` texture.

:func:`rasterize_layout` finds, for every texel whose centre lies in a skin triangle, the
triangle and barycentric coordinates, and from them the template surface point and normal
(used by the procedural generator and the region labels). :func:`fill_index` gives, for
every texel, the nearest valid texel of the same tile, so that maps can be dilated past
the island borders (bilinear filtering at a border then never reads invalid texels, and
no colour bleeds between the two tiles).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy import ndimage

from hack_render.errors import HackError
from hack_render.geometry.obj_io import ObjMesh, read_obj
from hack_render.io.npz import write_npz

#: The template (ICT-FaceKit ``generic_neutral_mesh.obj``, MIT licence, see
#: ``appearance/data/LICENSE-ICT-FaceKit``), shipped as package data: vertices (cm, as in
#: the OBJ, larynx included), triangles, UVs and materials. Rebuilt from the OBJ by
#: :func:`write_template_file` (``hack-render learn template --ict DIR``).
TEMPLATE_FILE = Path(__file__).resolve().parent / "data" / "ict_template.npz"
TEMPLATE_FORMAT = 1
SKIN_MATERIALS = ("M_Face", "M_BackHead")
_TEMPLATE_KEYS = {"format_version": "i", "meta_json": "U", "vertices": "f", "faces": "i",
                  "uvs": "f", "uv_faces": "i", "face_material": "i", "materials": "U",
                  "polygon_of_face": "i"}


def write_template_file(obj_path: str | Path, out: str | Path = TEMPLATE_FILE) -> Path:
    """Convert ICT-FaceKit's ``generic_neutral_mesh.obj`` into the packaged template file.

    Args:
        obj_path: the OBJ, or the ICT-FaceKit folder holding ``generic_neutral_mesh.obj``.
        out: the ``.npz`` to write (default: the package's own file).
    Returns:
        The path written. Vertices and UVs are kept in float64, exactly as parsed, so the
        atlas rasterised from the file is identical to one rasterised from the OBJ.
    """

    obj_path = Path(obj_path)
    if obj_path.is_dir():
        obj_path = obj_path / "generic_neutral_mesh.obj"
    if not obj_path.is_file():
        raise HackError(f"ICT-FaceKit template: expected generic_neutral_mesh.obj, found "
                        f"none at {obj_path}. ICT-FaceKit is public (MIT licence; "
                        f"github.com/ICT-VGL/ICT-FaceKit, FaceXModel/): pass its folder.")
    mesh = read_obj(obj_path)
    missing = [m for m in SKIN_MATERIALS if m not in mesh.materials]
    if missing:
        raise HackError(f"{obj_path}: expected the skin materials {SKIN_MATERIALS}, found "
                        f"{mesh.materials} (missing {missing}). Pass ICT-FaceKit's "
                        f"generic_neutral_mesh.obj.")
    meta = {"source": "ICT-FaceKit generic_neutral_mesh.obj (MIT licence, "
                      "University of Southern California ICT; see LICENSE-ICT-FaceKit)",
            "provenance": "captured (ICT-FaceKit's template), converted unchanged: "
                          "vertices in centimetres, larynx included",
            "obj_sha256": hashlib.sha256(obj_path.read_bytes()).hexdigest(),
            "command": "hack-render learn template --ict ICT_FACEKIT_DIR"}
    return write_npz(out, dict(
        format_version=np.int32(TEMPLATE_FORMAT), meta_json=np.array(json.dumps(meta)),
        vertices=mesh.vertices.astype(np.float64), faces=mesh.faces.astype(np.int32),
        uvs=mesh.uvs.astype(np.float64), uv_faces=mesh.uv_faces.astype(np.int32),
        face_material=mesh.face_material.astype(np.int16),
        materials=np.array(mesh.materials), polygon_of_face=mesh.polygon_of_face.astype(np.int32)),
        compressed=True)


def load_template(path: str | Path = TEMPLATE_FILE):
    """The skin template as an :class:`~hack_render.geometry.obj_io.ObjMesh`, from the
    packaged file (no file outside the package is read).

    Raises:
        HackError: the file is missing, truncated or lacks a key.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in _TEMPLATE_KEYS if k in z.files}
    except (OSError, ValueError, EOFError) as err:
        raise HackError(f"skin template {path}: expected the packaged ict_template.npz, "
                        f"could not read it ({err}). Reinstall hack-render, or rebuild it "
                        f"with `hack-render learn template --ict ICT_FACEKIT_DIR`.") from err
    missing = sorted(set(_TEMPLATE_KEYS) - set(d))
    if missing or int(d["format_version"]) != TEMPLATE_FORMAT:
        raise HackError(f"skin template {path}: expected format {TEMPLATE_FORMAT} with keys "
                        f"{sorted(_TEMPLATE_KEYS)}, found missing {missing} / format "
                        f"{d.get('format_version')}. Rebuild it with `hack-render appearance "
                        f"template --ict ICT_FACEKIT_DIR`.")
    return ObjMesh(vertices=d["vertices"].astype(np.float64), faces=d["faces"].astype(np.int64),
                   uvs=d["uvs"].astype(np.float64), uv_faces=d["uv_faces"].astype(np.int64),
                   face_material=d["face_material"].astype(np.int64),
                   materials=tuple(str(m) for m in d["materials"]),
                   polygon_of_face=d["polygon_of_face"].astype(np.int64))


@dataclass(frozen=True)
class UVLayout:
    """The rasterised skin atlas at one resolution.

    Attributes (H rows, W = 2H columns):
        height: H.
        mask: (H, W) bool, texel centre inside a skin triangle.
        face: (H, W) int64 triangle index into the OBJ's triangles, -1 outside.
        bary: (H, W, 3) float32 barycentric coordinates in that triangle (0 outside).
        position: (H, W, 3) float32 template surface point, centimetres (0 outside).
        normal: (H, W, 3) float32 unit template surface normal (0 outside).
        vertex: (H, W) int64 nearest triangle corner (vertex index), -1 outside.
        tile: (H, W) int8, 0 for u < 1 (M_Face), 1 for u >= 1 (M_BackHead).
        fill: (H * W,) int64 flat index of the nearest valid texel in the same tile.
    """

    height: int
    mask: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    vertex: np.ndarray
    tile: np.ndarray
    fill: np.ndarray

    @property
    def width(self) -> int:
        return 2 * self.height


def tile_of(height: int) -> np.ndarray:
    """(H, 2H) int8: 0 in the left half (tile 0), 1 in the right half (tile 1)."""
    t = np.zeros((height, 2 * height), np.int8)
    t[:, height:] = 1
    return t


def fill_index(mask: np.ndarray) -> np.ndarray:
    """Flat index of the nearest valid texel of the same tile, for every texel.

    Args:
        mask: (H, 2H) bool validity mask.
    Returns:
        (H * 2H,) int64; valid texels map to themselves. A tile without valid texels
        maps to the nearest valid texel anywhere.
    """
    h, w = mask.shape
    out = np.empty((h, w), np.int64)
    flat = np.arange(h * w).reshape(h, w)
    for sl in (np.s_[:, : w // 2], np.s_[:, w // 2:]):
        m = mask[sl]
        src = m if m.any() else mask
        if not src.any():
            raise HackError("UV mask: expected at least one valid texel, found none. "
                            "Check the mask passed to fill_index.")
        if m.any():
            _, (ii, jj) = ndimage.distance_transform_edt(~m, return_indices=True)
            out[sl] = flat[sl][ii, jj]
        else:
            _, (ii, jj) = ndimage.distance_transform_edt(~mask, return_indices=True)
            out[sl] = flat[ii, jj][sl]
    return out.reshape(-1)


def _tri_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals."""
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                  vertices[faces[:, 2]] - vertices[faces[:, 0]])
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


def rasterize_uv(uv_tris: np.ndarray, height: int, chunk: int = 4096):
    """Rasterise UV triangles into an (H, 2H) atlas (texel-centre sampling).

    Args:
        uv_tris: (F, 3, 2) UV coordinates of each triangle's corners, u in [0, 2].
        height: H.
    Returns:
        face (H, 2H) int64 (-1 outside) and bary (H, 2H, 3) float32.
    """
    h, w = height, 2 * height
    px = np.stack([uv_tris[..., 0] * h - 0.5, (1.0 - uv_tris[..., 1]) * h - 0.5], -1)
    lo = np.floor(px.min(1)).astype(np.int64) + 1  # first texel centre >= min
    hi = np.floor(px.max(1)).astype(np.int64)
    lo = np.clip(lo, 0, [w - 1, h - 1])
    hi = np.clip(hi, 0, [w - 1, h - 1])
    ext = np.maximum(hi - lo + 1, 0)
    order = np.argsort(ext[:, 0] * ext[:, 1], kind="stable")
    face = np.full(h * w, -1, np.int64)
    bary = np.zeros((h * w, 3), np.float32)
    for s in range(0, len(order), chunk):
        ids = order[s: s + chunk]
        ew, eh = ext[ids].max(0)
        if ew == 0 or eh == 0:
            continue
        oy, ox = np.meshgrid(np.arange(eh), np.arange(ew), indexing="ij")
        x = lo[ids, 0, None] + ox.reshape(1, -1)  # (n, eh*ew) texel columns
        y = lo[ids, 1, None] + oy.reshape(1, -1)
        a, b, c = px[ids, 0], px[ids, 1], px[ids, 2]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        ok_tri = np.abs(det) > 1e-14
        det = np.where(ok_tri, det, 1.0)[:, None]
        dx, dy = x - a[:, 0, None], y - a[:, 1, None]
        l1 = (dx * (c[:, 1, None] - a[:, 1, None]) - dy * (c[:, 0, None] - a[:, 0, None])) / det
        l2 = (dy * (b[:, 0, None] - a[:, 0, None]) - dx * (b[:, 1, None] - a[:, 1, None])) / det
        l0 = 1.0 - l1 - l2
        eps = -1e-9
        inside = ((l0 >= eps) & (l1 >= eps) & (l2 >= eps) & ok_tri[:, None]
                  & (x <= hi[ids, 0, None]) & (y <= hi[ids, 1, None]))
        r, k = np.nonzero(inside)
        flat = y[r, k] * w + x[r, k]
        face[flat] = ids[r]
        bary[flat] = np.stack([l0[r, k], l1[r, k], l2[r, k]], -1)
    return face.reshape(h, w), bary.reshape(h, w, 3)


@lru_cache(maxsize=1)
def default_template():
    """The packaged template (:data:`TEMPLATE_FILE`), loaded once per process."""
    return load_template()


@lru_cache(maxsize=4)
def rasterize_layout(height: int) -> UVLayout:
    """Rasterise the template's skin (``M_Face``, ``M_BackHead``) at atlas height H.

    Cached per H within the process. H between 16 and 8192.
    """
    if not (isinstance(height, (int, np.integer)) and 16 <= height <= 8192):
        raise HackError(f"UV atlas height: expected an integer in [16, 8192], found "
                        f"{height!r}.")
    mesh = default_template()
    mats = [mesh.materials.index(m) for m in SKIN_MATERIALS]
    sel = np.isin(mesh.face_material, mats)
    faces, uv_faces = mesh.faces[sel], mesh.uv_faces[sel]
    face, bary = rasterize_uv(mesh.uvs[uv_faces], int(height))
    mask = face >= 0
    fi = np.where(mask, face, 0)
    vn = _tri_normals(mesh.vertices, mesh.faces)
    tri = faces[fi]  # (H, W, 3) vertex ids
    pos = np.einsum("hwk,hwkc->hwc", bary, mesh.vertices[tri]).astype(np.float32)
    nrm = np.einsum("hwk,hwkc->hwc", bary, vn[tri])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12)
    vert = np.take_along_axis(tri, bary.argmax(-1)[..., None], -1)[..., 0]
    m3 = mask[..., None]
    glob = np.flatnonzero(sel)[fi]
    return UVLayout(
        height=int(height), mask=mask, face=np.where(mask, glob, -1),
        bary=np.where(m3, bary, 0).astype(np.float32),
        position=np.where(m3, pos, 0).astype(np.float32),
        normal=np.where(m3, nrm, 0).astype(np.float32),
        vertex=np.where(mask, vert, -1), tile=tile_of(int(height)), fill=fill_index(mask))
