"""Reading and writing polygon meshes with UVs (OBJ, PLY), with seams kept.

ICT-FaceKit's OBJ indexes texture coordinates separately from vertices (UV seams), which
generic loaders resolve by splitting vertices; the model needs the original vertex order,
so the template is read here with its own small parser, and written back the same way:
OBJ and PLY files keep the model's vertex order (no seam splits), so vertex k of a file is
vertex k of the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.io import atomic_write_bytes, atomic_write_text


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


@dataclass(frozen=True)
class ObjMaterials:
    """What an OBJ's ``.mtl`` says: one material per model material, skin maps on the skin.

    Attributes:
        names: material names (the model's ``material_names``), one ``newmtl`` each.
        face_material: (F,) int64 index into ``names`` per face (``usemtl`` switches).
        maps: texture paths relative to the ``.mtl`` by kind (``diffuse``, ``specular``,
            ``roughness``, ``normal``), applied to the materials in ``skin``.
        skin: names of the materials on the skin atlas. The atlas covers u in [0, 2] (two
            tiles), so its maps are scaled by 1/2 in u (``-s 0.5 1 1``): the file keeps the
            model's own texture coordinates.
        colours: linear RGB (0..1) diffuse colour of the other materials by name.
    """

    names: tuple[str, ...]
    face_material: np.ndarray
    maps: dict[str, str]
    skin: tuple[str, ...] = ("M_Face", "M_BackHead")
    colours: dict[str, tuple[float, float, float]] | None = None


#: MTL statements per map kind (``map_Pr`` and ``norm``: the PBR extension of MTL).
_MTL_MAP = {"diffuse": "map_Kd", "specular": "map_Ks", "roughness": "map_Pr", "normal": "norm"}


def _mtl_text(mats: ObjMaterials) -> str:
    lines = [("# hack-render: one material per model material; skin maps on the atlas's two "
              "tiles (u in [0, 2], hence -s 0.5 1 1)")]
    for name in mats.names:
        rgb = (mats.colours or {}).get(name, (0.8, 0.8, 0.8))
        lines += [f"newmtl {name}", "Ka 0 0 0", "Kd {:.4f} {:.4f} {:.4f}".format(*rgb),
                  "Ks 0.03 0.03 0.03", "illum 2"]
        if name in mats.skin:
            lines[-3] = "Kd 1 1 1"
            lines += [f"{_MTL_MAP[k]} -s 0.5 1 1 {rel}" for k, rel in mats.maps.items()
                      if k in _MTL_MAP]
        lines.append("")
    return "\n".join(lines)


def _obj_text(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None,
              uv_faces: np.ndarray | None, mtl_name: str | None,
              mats: ObjMaterials | None) -> str:
    """OBJ text: ``v`` in the given order, ``vt`` indexed separately (``f v/vt``)."""
    out = ["# hack-render: vertices in the model's order (v line k = model vertex k - 1)"]
    if mtl_name:
        out.append(f"mtllib {mtl_name}")
    # 9 significant digits: float32 positions read back bit for bit
    out.append("\n".join("v %.9g %.9g %.9g" % tuple(r) for r in vertices.tolist()))
    if uvs is not None:
        out.append("\n".join("vt %.9g %.9g" % tuple(r) for r in uvs.tolist()))
        corners = np.stack([faces + 1, uv_faces + 1], axis=2).reshape(len(faces), 6)
        fmt = "f %d/%d %d/%d %d/%d"
    else:
        corners, fmt = faces + 1, "f %d %d %d"
    rows = [fmt % tuple(r) for r in corners.tolist()]
    if mats is not None:  # usemtl wherever the material changes, faces kept in order
        fm = np.asarray(mats.face_material)
        starts = np.flatnonzero(np.r_[True, fm[1:] != fm[:-1]])
        for s in starts[::-1]:
            rows.insert(int(s), f"usemtl {mats.names[int(fm[s])]}")
    out.append("\n".join(rows))
    return "\n".join(out) + "\n"


def _ply_bytes(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None,
               uv_faces: np.ndarray | None) -> bytes:
    """Binary PLY: vertices in the given order; UVs per face corner (``texcoord``, the
    MeshLab convention), so seams need no split vertices."""
    n, f = len(vertices), len(faces)
    head = ["ply", "format binary_little_endian 1.0",
            "comment hack-render: vertices in the model's order; UVs per face corner",
            f"element vertex {n}", "property float x", "property float y", "property float z",
            f"element face {f}", "property list uchar int vertex_indices"]
    fields = [("n", "u1"), ("vi", "<i4", (3,))]
    if uvs is not None:
        head.append("property list uchar float texcoord")
        fields += [("m", "u1"), ("tc", "<f4", (6,))]
    head.append("end_header")
    rec = np.zeros(f, dtype=fields)
    rec["n"], rec["vi"] = 3, faces
    if uvs is not None:
        rec["m"], rec["tc"] = 6, np.asarray(uvs)[uv_faces].reshape(f, 6)
    return ("\n".join(head) + "\n").encode() + \
        np.ascontiguousarray(vertices, "<f4").tobytes() + rec.tobytes()


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
               uvs: np.ndarray | None = None, uv_faces: np.ndarray | None = None,
               materials: ObjMaterials | None = None) -> Path:
    """Write a triangle mesh as OBJ or PLY (by suffix) in the model's vertex order.

    OBJ: ``v`` line k is vertex k; texture coordinates are indexed separately
    (``f v/vt``), so UV seams split nothing. With ``materials`` an ``.mtl`` beside it (same
    stem) names the texture maps and ``usemtl`` lines follow the faces; without, no
    ``mtllib`` line. PLY (binary): vertex k is vertex k; UVs per face corner
    (``texcoord``, 6 floats a face). Files are written under a temporary name and renamed,
    so a crash leaves no partial file.

    Args:
        vertices: (N, 3) positions in metres.
        faces: (F, 3) vertex indices.
        uvs: (T, 2) texture coordinates (v up); uv_faces: (F, 3) indices into them.
        materials: the ``.mtl`` to write (OBJ only; ignored for PLY).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".obj", ".ply"):
        raise HackError(f"{path}: unsupported mesh format {suffix!r}; use .obj or .ply.")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if (uvs is None) != (uv_faces is None):
        raise HackError(f"{path}: texture coordinates need both uvs and uv_faces, found one.")
    if uvs is not None:
        uvs, uv_faces = np.asarray(uvs, np.float64), np.asarray(uv_faces, np.int64)
        if uv_faces.shape != faces.shape:
            raise HackError(f"{path}: uv_faces expected shape {faces.shape} (one per face "
                            f"corner), found {uv_faces.shape}.")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".ply":
            atomic_write_bytes(path, _ply_bytes(vertices, faces, uvs, uv_faces))
            return path
        mtl = path.with_suffix(".mtl") if materials is not None else None
        if mtl is not None:
            atomic_write_text(mtl, _mtl_text(materials))
        atomic_write_text(path, _obj_text(vertices, faces, uvs, uv_faces,
                                          mtl.name if mtl else None, materials))
    except OSError as exc:
        raise HackError(f"{path}: cannot write ({exc.strerror or exc}). Choose a writable "
                        "output path.") from exc
    return path
