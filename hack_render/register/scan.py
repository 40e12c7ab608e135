"""Scans in: meshes and point clouds read through trimesh, units found, surfaces sampled.

- :func:`load_scan`: OBJ, PLY, STL, OFF, GLB/GLTF meshes and point clouds (PLY without
  faces, XYZ text, NPY) into a :class:`Scan` in metres, with normals, colours where the
  file has them (vertex colours or a texture) and the open boundary marked.
- :func:`detect_units`: m, cm or mm from the scan's size (a head with some neck is
  0.2-0.6 m across).
- :class:`SurfaceIndex`: dense area-weighted samples of the scan's surface in a KD-tree
  (scipy's ``cKDTree``): nearest-surface queries, point-to-plane distances, colours and
  boundary flags at the nearest point. Never brute force.

Every error a user can cause is a :class:`~hack_render.errors.HackError` naming the file.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry.normals import open_boundary

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
POINT_SUFFIXES = (".xyz", ".npy", ".txt")
#: metres per unit
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: a head with some neck and shoulders, largest bounding-box side, metres
TYPICAL_EXTENT_M = 0.35
PLAUSIBLE_EXTENT_M = (0.08, 2.0)


@dataclass
class Scan:
    """A scan in metres, in its own frame (only the units are changed).

    Attributes (N points):
        name: file stem, for messages and output names.
        points: (N, 3) vertex positions, metres.
        normals: (N, 3) unit normals (vertex normals of a mesh; for a point cloud
            estimated from 16 neighbours and turned away from the centroid).
        faces: (F, 3) triangles, or None for a point cloud.
        colors: (N, 3) linear RGB in [0, 1] per vertex, or None.
        texture: (H, W, 3) sRGB-decoded linear texture, with ``uv`` (N, 2) per vertex
            (trimesh splits vertices at UV seams), or None.
        boundary: (N,) vertices on an open boundary (holes, the cut neck).
        units: the units of the file ("m", "cm", "mm"); scale = metres per unit.
    """

    name: str
    points: np.ndarray
    normals: np.ndarray
    faces: np.ndarray | None = None
    colors: np.ndarray | None = None
    texture: np.ndarray | None = None
    uv: np.ndarray | None = None
    boundary: np.ndarray | None = None
    units: str = "m"
    scale: float = 1.0
    notes: list[str] = field(default_factory=list)

    @classmethod
    def from_mesh(cls, name: str, points: np.ndarray, faces: np.ndarray, **kw) -> Scan:
        """A mesh scan already in metres: normals and boundary computed."""
        points, faces = np.asarray(points, np.float64), np.asarray(faces, np.int64)
        return cls(name, points, vertex_normals(points, faces), faces,
                   boundary=open_boundary(faces, len(points)), **kw)

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None and len(self.faces) > 0

    @property
    def has_color(self) -> bool:
        return self.colors is not None or self.texture is not None

    @property
    def extent(self) -> float:
        """Largest bounding-box side, metres."""
        return float(np.ptp(self.points, axis=0).max())


def detect_units(extent: float, name: str = "scan") -> str:
    """The unit (m, cm or mm) that makes a scan ``extent`` units across head-sized.

    Args:
        extent: the largest bounding-box side, in the file's units.
    """
    if not (math.isfinite(extent) and extent > 0):
        raise HackError(f"{name}: expected a scan with some size, found extent {extent}.")
    best = min(UNITS, key=lambda u: abs(math.log(extent * UNITS[u] / TYPICAL_EXTENT_M)))
    size = extent * UNITS[best]
    if not PLAUSIBLE_EXTENT_M[0] <= size <= PLAUSIBLE_EXTENT_M[1]:
        raise HackError(f"{name}: cannot tell the units: it is {extent:.4g} units across, "
                        f"which is no head size in m, cm or mm. Pass --units m|cm|mm.")
    return best


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (colour-science's IEC 61966-2-1 decoding)."""
    import colour

    return np.clip(np.asarray(colour.cctf_decoding(np.clip(c, 0, 1), function="sRGB")), 0, 1)


def _read_points(path: Path) -> np.ndarray:
    """(N, 3+) array of a .xyz/.txt or .npy point file (columns x y z [nx ny nz] [r g b])."""
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
        else:
            arr = np.loadtxt(path, ndmin=2)
    except (ValueError, OSError, EOFError) as exc:
        raise HackError(f"{path}: not a point file ({exc}). Expected rows 'x y z' (optionally "
                        "normals and colours) or an (N, 3) .npy.") from exc
    arr = np.asarray(arr)
    if arr.dtype.kind not in "fiu" or arr.ndim != 2 or arr.shape[1] < 3:
        raise HackError(f"{path}: expected an (N, 3), (N, 6) or (N, 9) numeric array, found "
                        f"shape {arr.shape} of {arr.dtype}.")
    return arr.astype(np.float64)


#: an OBJ face corner: v, v/vt, v//vn or v/vt/vn (indices non-zero, negative: relative)
_OBJ_CORNER = re.compile(rb"-?[1-9][0-9]*(?:/-?[1-9][0-9]*(?:/-?[1-9][0-9]*)?|//-?[1-9][0-9]*)?")
#: a whole face line of one corner form (v, v/vt, v//vn, v/vt/vn): at least 3 corners
_OBJ_FACES = [re.compile(rb"f(?:[ \t]+-?[1-9][0-9]*%s){3,}[ \t]*" % form) for form in (
    rb"", rb"/-?[1-9][0-9]*", rb"//-?[1-9][0-9]*", rb"/-?[1-9][0-9]*/-?[1-9][0-9]*")]
#: a corner's vertex index (after the blank before it; relative ones are left out)
_OBJ_VERTEX_INDEX = re.compile(rb"[ \t]([0-9]+)")
#: values of the OBJ statements checked: name -> (fewest, most)
_OBJ_VALUES = {b"v": (3, 7), b"vn": (3, 3), b"vt": (1, 3)}


def check_obj_text(path: Path) -> list[str]:
    """Refuse an OBJ that is malformed or cut short (trimesh reads such a file without a
    word: a face cut to two corners is dropped, a file cut among its vertices becomes a
    point cloud), naming the file and line; returns notes for the report.

    Checked: ``v``, ``vn`` and ``vt`` lines hold numbers, as many on every line as on
    the first of their kind (a cut line has fewer); ``f`` lines hold at least three
    corners, each ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn`` and all of one form; vertex
    indices refer to vertices the file has; texture coordinates need faces. A file whose
    last line has no newline may still be cut inside a number: that is said in a note
    (with how much was read), not refused."""
    first: dict[bytes, tuple[int, int]] = {}  # kind -> (values, line)
    count = {b"v": 0, b"vt": 0, b"vn": 0, b"f": 0}
    top, top_line = 0, 0  # the largest vertex index a face uses, and its line
    face = _OBJ_FACES[0]
    last, lineno = b"", 0

    def bad(lineno: int, raw: bytes, what: str) -> HackError:
        line = raw.decode("utf-8", "replace").strip()
        shown = line if len(line) <= 60 else line[:57] + "..."
        return HackError(f"{path}:{lineno}: {what}, found {shown!r}. The file looks cut short "
                         "or damaged; export the scan again.")

    with path.open("rb") as fh:
        for lineno, raw in enumerate(fh, 1):
            last = raw
            words = raw.split()
            if not words or words[0] not in count:
                continue  # comments, groups, materials, smoothing, lines, points
            kind = words[0]
            count[kind] += 1
            if kind == b"f":
                text = raw.strip()
                if face.fullmatch(text) is None:
                    face = next((f for f in _OBJ_FACES if f.fullmatch(text)), None)
                    if face is None:
                        face = _OBJ_FACES[0]
                        odd = [w for w in words[1:] if _OBJ_CORNER.fullmatch(w) is None]
                        raise bad(lineno, raw, "expected a face of at least 3 corners"
                                  if len(words) < 4 else
                                  f"expected face corners like 7, 7/3, 7//2 or 7/3/2, and "
                                  f"{odd[0].decode('utf-8', 'replace')!r} is none of them"
                                  if odd else "expected the corners of a face in one form")
                most = max(map(int, _OBJ_VERTEX_INDEX.findall(raw)), default=0)
                if most > top:
                    top, top_line = most, lineno
                continue
            values = words[1:]
            lo, hi = _OBJ_VALUES[kind]
            name = kind.decode()
            try:
                [float(x) for x in values]
            except ValueError:
                raise bad(lineno, raw, f"expected numbers after {name!r}") from None
            if not lo <= len(values) <= hi:
                raise bad(lineno, raw, f"expected {lo}-{hi} numbers after {name!r}"
                          if lo < hi else f"expected {lo} numbers after {name!r}")
            n0, line0 = first.setdefault(kind, (len(values), lineno))
            if len(values) != n0:
                raise bad(lineno, raw, f"expected {n0} numbers after {name!r} as on line "
                          f"{line0}")
    if top > count[b"v"]:
        raise HackError(f"{path}:{top_line}: a face refers to vertex {top}, but the file has "
                        f"{count[b'v']:,}. The file looks cut short or damaged; export the "
                        "scan again.")
    if not count[b"f"] and count[b"vt"]:  # texture coordinates of no faces
        raise HackError(f"{path}:{lineno}: expected faces after the {count[b'v']:,} vertices "
                        f"and {count[b'vt']:,} texture coordinates, found the end of the file. "
                        "The file looks cut short; export the scan again.")
    if last and not last.endswith(b"\n"):
        note = (f"{path.name} does not end with a newline: it may be cut short; read "
                f"{count[b'v']:,} vertices and {count[b'f']:,} faces")
        return [note]
    return []


def _trimesh_geometry(path: Path):
    import trimesh

    try:
        geom = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many kinds for unreadable files
        raise HackError(f"{path}: cannot read it as a mesh or point cloud ({type(exc).__name__}: "
                        f"{exc}). Expected OBJ, PLY, STL, OFF, GLB/GLTF, XYZ or NPY.") from exc
    if isinstance(geom, trimesh.Scene):
        meshes = [g for g in geom.dump() if isinstance(g, trimesh.Trimesh)]
        if not meshes:
            clouds = [g for g in geom.geometry.values() if isinstance(g, trimesh.PointCloud)]
            if clouds:
                return clouds[0]
            raise HackError(f"{path}: the file holds no mesh or points.")
        geom = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    return geom


def _mesh_colors(mesh) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """(vertex colours (N, 3) linear, texture (H, W, 3) linear, uv (N, 2)) of a trimesh."""
    vis = getattr(mesh, "visual", None)
    if vis is None:
        return None, None, None
    kind = getattr(vis, "kind", None)
    if kind == "texture":
        mat = getattr(vis, "material", None)
        img = getattr(mat, "image", None) if mat is not None else None
        if img is None and mat is not None:
            img = getattr(mat, "baseColorTexture", None)
        uv = getattr(vis, "uv", None)
        if img is not None and uv is not None and len(uv) == len(mesh.vertices):
            tex = np.asarray(img.convert("RGB"), dtype=np.float64) / 255.0
            return None, srgb_to_linear(tex), np.asarray(uv, np.float64)
        return None, None, None
    if kind == "vertex":
        c = np.asarray(vis.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        if np.ptp(c) > 0:  # trimesh fills a default grey when the file has none
            return srgb_to_linear(c), None, None
    return None, None, None


def estimate_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """(N, 3) unit normals of a point cloud: the smallest principal axis of each point's
    ``k`` nearest neighbours, turned away from the cloud's centroid."""
    from scipy.spatial import cKDTree

    k = min(k, len(points))
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    n = vecs[:, :, 0]
    out = np.einsum("ni,ni->n", n, points - points.mean(0)) < 0
    n[out] *= -1
    return n


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals (zero-area neighbourhoods: +Z)."""
    fn = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    idx = faces.T.ravel()  # corner k of every face, k = 0, 1, 2
    w = np.tile(fn, (3, 1))
    vn = np.stack([np.bincount(idx, w[:, c], minlength=len(points)) for c in range(3)], 1)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return np.where(norm > 0, vn / np.maximum(norm, 1e-30), [0.0, 0.0, 1.0])


def smoothed(faces: np.ndarray, values: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Per-vertex ``values`` (N, C) averaged over each vertex and its mesh neighbours
    ``iterations`` times: a scan's noise (0.5 mm on 1-2 mm triangles) smoothed away for
    shading, so that its shadows and normals do not turn to salt."""
    import scipy.sparse as sp

    n = len(values)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1], np.stack([np.arange(n)] * 2, 1)])
    A = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    A = sp.diags(1.0 / np.maximum(np.asarray(A.sum(1)).ravel(), 1)) @ A
    out = values
    for _ in range(iterations):
        out = A @ out
    return out


def load_scan(path: str | Path, units: str | None = None, max_points: int = 5_000_000) -> Scan:
    """Read a scan (mesh or point cloud) into metres.

    Args:
        path: OBJ, PLY, STL, OFF, GLB/GLTF (meshes; PLY without faces is a point cloud),
            XYZ/TXT or NPY (points, optionally with normals and colours).
        units: "m", "cm" or "mm"; None detects them from the size.
    """
    path = Path(path)
    if not path.is_file():
        raise HackError(f"{path}: no such file. Pass a scan: "
                        f"{', '.join(MESH_SUFFIXES + POINT_SUFFIXES)}.")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES + POINT_SUFFIXES:
        raise HackError(f"{path}: unsupported scan format {suffix!r}; expected one of "
                        f"{', '.join(MESH_SUFFIXES + POINT_SUFFIXES)}.")
    if units is not None and units not in UNITS:
        raise HackError(f"--units: expected m, cm or mm, found {units!r}.")
    faces = colors = texture = uv = normals = None
    notes: list[str] = []
    if suffix in POINT_SUFFIXES:
        arr = _read_points(path)
        pts = arr[:, :3]
        if arr.shape[1] >= 6:
            normals = arr[:, 3:6]
        if arr.shape[1] >= 9:
            c = arr[:, 6:9]
            colors = srgb_to_linear(c / 255.0 if c.max() > 1.0 else c)
    else:
        import trimesh

        notes = check_obj_text(path) if suffix == ".obj" else []
        geom = _trimesh_geometry(path)
        pts = np.asarray(geom.vertices, dtype=np.float64)
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
            faces = np.asarray(geom.faces, dtype=np.int64)
            colors, texture, uv = _mesh_colors(geom)
        elif isinstance(geom, trimesh.PointCloud):
            c = getattr(geom, "colors", None)
            if c is not None and len(c) == len(pts) and np.ptp(np.asarray(c)[:, :3]) > 0:
                colors = srgb_to_linear(np.asarray(c, np.float64)[:, :3] / 255.0)
    if len(pts) == 0:
        raise HackError(f"{path}: the scan is empty (no vertices). Export the scan with its "
                        "geometry.")
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts).all(1)).sum())
        raise HackError(f"{path}: {bad} of {len(pts)} vertices are NaN or infinite. Clean the "
                        "scan (e.g. remove invalid points) and try again.")
    if len(pts) < 100:
        raise HackError(f"{path}: expected a scan of at least 100 points, found {len(pts)}.")
    if len(pts) > max_points:
        raise HackError(f"{path}: {len(pts):,} points; expected at most {max_points:,}. "
                        "Decimate the scan first.")
    u = units or detect_units(float(np.ptp(pts, axis=0).max()), path.name)
    pts = pts * UNITS[u]
    if faces is not None:
        if faces.min() < 0 or faces.max() >= len(pts):
            raise HackError(f"{path}: faces index vertices outside 0..{len(pts) - 1}.")
        normals = vertex_normals(pts, faces)
        boundary = open_boundary(faces, len(pts))
    else:
        if normals is None or not np.isfinite(normals).all():
            normals = estimate_normals(pts)
        normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        boundary = None
    notes += [] if units else [f"units detected: {u} (pass --units to override)"]
    return Scan(path.stem, pts, normals, faces, colors, texture, uv, boundary, u, UNITS[u],
                notes)


def transformed(scan: Scan, scale: float, R: np.ndarray, t: np.ndarray) -> Scan:
    """The scan moved by x -> scale * R x + t (normals rotated)."""
    return dataclasses.replace(scan, points=scale * scan.points @ R.T + t,
                               normals=scan.normals @ R.T)


def vertex_colors(scan: Scan) -> np.ndarray | None:
    """(N, 3) linear colour per vertex: its own, or its texture's at its UV; None if none."""
    if scan.colors is not None:
        return scan.colors
    if scan.texture is not None:
        return sample_texture(scan.texture, scan.uv)
    return None


class SurfaceIndex:
    """Dense samples of a scan's surface in a KD-tree.

    A mesh is sampled area-weighted at about ``spacing`` metres (its vertices included);
    a point cloud is its points. Each sample carries a normal, a colour (if any) and a
    flag for lying within ``boundary_margin`` of an open boundary.
    """

    def __init__(self, scan: Scan, spacing: float = 0.0008, boundary_margin: float = 0.006,
                 max_samples: int = 600_000, seed: int = 0):
        from scipy.spatial import cKDTree

        self.scan = scan
        pts, nrm, col = scan.points, scan.normals, vertex_colors(scan)
        if scan.is_mesh:
            p, n, c = self._sample_faces(scan, spacing, max_samples, seed)
            pts, nrm = np.concatenate([pts, p]), np.concatenate([nrm, n])
            col = None if col is None else np.concatenate([col, c])
        near_boundary = np.zeros(len(pts), bool)
        if scan.is_mesh and scan.boundary is not None and scan.boundary.any():
            bt = cKDTree(scan.points[scan.boundary])
            d, _ = bt.query(pts, k=1, distance_upper_bound=boundary_margin)
            near_boundary = np.isfinite(d)
        self.points, self.normals, self.colors = pts, nrm, col
        self.near_boundary = near_boundary
        self.tree = cKDTree(pts)

    @staticmethod
    def _sample_faces(scan: Scan, spacing: float, max_samples: int, seed: int):
        v, f = scan.points, scan.faces
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        n = int(min(max_samples, max(1000, area.sum() / spacing ** 2)))
        rng = np.random.default_rng(seed)
        fi = rng.choice(len(f), size=n, p=area / area.sum()) if area.sum() > 0 else \
            rng.integers(0, len(f), n)
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        w = np.stack([1 - s, s * (1 - r2), s * r2], 1)  # uniform barycentrics
        tri = f[fi]
        p = np.einsum("nk,nkc->nc", w, v[tri])
        nrm = np.einsum("nk,nkc->nc", w, scan.normals[tri])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        col = None
        if scan.colors is not None:
            col = np.einsum("nk,nkc->nc", w, scan.colors[tri])
        elif scan.texture is not None:
            col = sample_texture(scan.texture, np.einsum("nk,nkc->nc", w, scan.uv[tri]))
        return p, nrm, col

    def nearest(self, query: np.ndarray, max_distance: float = np.inf
                ) -> tuple[np.ndarray, np.ndarray]:
        """(distance (M,), sample index (M,)) of each query point's nearest sample; beyond
        ``max_distance``: inf and index = number of samples."""
        d, i = self.tree.query(np.asarray(query, np.float64), k=1,
                               distance_upper_bound=max_distance, workers=-1)
        return d, i


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of (M, 2) UVs (v up, wrapped) in an (H, W, 3) texture -> (M, 3)."""
    h, w = texture.shape[:2]
    x = (np.mod(uv[:, 0], 1.0) * w - 0.5)
    y = ((1.0 - np.mod(uv[:, 1], 1.0)) * h - 0.5)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0c, x1c = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    y0c, y1c = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    return ((1 - fx) * (1 - fy) * texture[y0c, x0c] + fx * (1 - fy) * texture[y0c, x1c]
            + (1 - fx) * fy * texture[y1c, x0c] + fx * fy * texture[y1c, x1c])
