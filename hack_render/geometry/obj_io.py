"""Reading and writing polygon meshes with UVs (OBJ, PLY), with seams kept.

ICT-FaceKit's OBJ indexes texture coordinates separately from vertices (UV seams), which
generic loaders resolve by splitting vertices; the model needs the original vertex order,
so the template is read here with its own small parser. Writing goes through trimesh.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hack_render.errors import HackError


@dataclass(frozen=True)
class ObjMesh:
    """A triangulated mesh with separately indexed UVs.

    Attributes:
        vertices: (N, 3) float64, file units.
        faces: (F, 3) int64 vertex indices (polygons fan-triangulated).
        uvs: (T, 2) float64 texture coordinates (OpenGL convention, v up).
        uv_faces: (F, 3) int64 indices into ``uvs``, corner for corner with ``faces``.
        face_material: (F,) int64 index into ``materials``.
        materials: material names from ``usemtl``, in order of first use.
        polygon_of_face: (F,) int64 index of the source polygon of each triangle.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    face_material: np.ndarray
    materials: tuple[str, ...]
    polygon_of_face: np.ndarray


def read_obj(path: str | Path) -> ObjMesh:
    """Read an OBJ with ``v``, ``vt``, ``f v/vt[/vn]`` and ``usemtl`` lines.

    Raises:
        HackError: if the file is missing, has no faces, or indexes out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise HackError(f"{path}: OBJ file not found. Pass the path to an existing .obj file.")
    verts, uvs, faces, uv_faces, mats, polys = [], [], [], [], [], []
    materials: list[str] = []
    current = -1
    n_poly = 0
    with path.open("r", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("vt "):
                uvs.append([float(x) for x in line.split()[1:3]])
            elif line.startswith("usemtl"):
                name = line.split(maxsplit=1)[1].strip()
                if name not in materials:
                    materials.append(name)
                current = materials.index(name)
            elif line.startswith("f "):
                corners = line.split()[1:]
                try:
                    vi = [int(c.split("/")[0]) - 1 for c in corners]
                    ti = [int(c.split("/")[1]) - 1 if "/" in c and c.split("/")[1] else -1
                          for c in corners]
                except ValueError as exc:
                    raise HackError(f"{path}:{lineno}: malformed face line {line.strip()!r}.") from exc
                for k in range(1, len(vi) - 1):  # fan triangulation
                    faces.append([vi[0], vi[k], vi[k + 1]])
                    uv_faces.append([ti[0], ti[k], ti[k + 1]])
                    mats.append(current)
                    polys.append(n_poly)
                n_poly += 1
    if not faces:
        raise HackError(f"{path}: no faces found; expected an OBJ with 'f' lines.")
    v = np.asarray(verts, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    t = np.asarray(uvs, dtype=np.float64).reshape(-1, 2)
    tf = np.asarray(uv_faces, dtype=np.int64)
    if f.max() >= len(v) or f.min() < 0:
        raise HackError(f"{path}: a face indexes vertex {f.max() + 1}, but the file has {len(v)}.")
    if len(t) and (tf.max() >= len(t)):
        raise HackError(f"{path}: a face indexes texture coordinate {tf.max() + 1}, but the file has {len(t)}.")
    return ObjMesh(v, f, t, tf, np.asarray(mats, dtype=np.int64), tuple(materials),
                   np.asarray(polys, dtype=np.int64))


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
               uvs: np.ndarray | None = None, uv_faces: np.ndarray | None = None) -> Path:
    """Write a triangle mesh as OBJ or PLY (by suffix), with UVs when given.

    UV seams are kept by splitting vertices at seams (each distinct (vertex, uv) pair becomes
    one output vertex), which is what both formats need for per-vertex texture coordinates.
    The file is written to a temporary name and renamed, so a crash leaves no partial file.

    Args:
        vertices: (N, 3) positions in metres.
        faces: (F, 3) vertex indices.
        uvs: (T, 2) texture coordinates; uv_faces: (F, 3) indices into them.
    """
    import trimesh

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".obj", ".ply"):
        raise HackError(f"{path}: unsupported mesh format {suffix!r}; use .obj or .ply.")
    path.parent.mkdir(parents=True, exist_ok=True)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if uvs is not None and uv_faces is not None:
        pairs = np.stack([faces.reshape(-1), np.asarray(uv_faces).reshape(-1)], axis=1)
        uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
        mesh = trimesh.Trimesh(
            vertices=vertices[uniq[:, 0]], faces=inverse.reshape(-1, 3), process=False,
            visual=trimesh.visual.TextureVisuals(uv=np.asarray(uvs)[uniq[:, 1]]),
        )
    else:
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    tmp = path.with_name(f".{path.name}.tmp{suffix}")
    if suffix == ".obj":
        data = trimesh.exchange.obj.export_obj(mesh, include_texture=uvs is not None,
                                               include_normals=False, write_texture=False,
                                               mtl_name=None)
        tmp.write_text(data if isinstance(data, str) else data[0])
    else:
        tmp.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary",
                                                        vertex_normal=False))
    tmp.replace(path)
    return path
