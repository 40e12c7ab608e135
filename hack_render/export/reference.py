"""A small glTF evaluator in numpy, kept beside the writer as the reference to test it
against: it reads a ``.glb``/``.gltf`` as the specification says (accessors, sparse
accessors, morph targets, skins, node hierarchy, linear animation at a keyframe) and
returns the skinned vertices in the model's order through ``_HACK_VERTEX`` (or, for the
hair cards, which have none, per primitive).

Only what :mod:`.gltf` writes is supported (one skinned mesh, float attributes, LINEAR
samplers evaluated at their keyframes).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPE = {5126: "<f4", 5121: "u1", 5123: "<u2", 5125: "<u4", 5120: "i1", 5122: "<i2"}


def read_gltf(path: str | Path) -> tuple[dict, bytes]:
    """The JSON document and its binary buffer."""
    path = Path(path)
    raw = path.read_bytes()
    if raw[:4] == b"glTF":
        jlen, _ = struct.unpack_from("<II", raw, 12)  # after magic, version, length
        doc = json.loads(raw[20:20 + jlen])
        off = 20 + jlen
        blen, _ = struct.unpack_from("<II", raw, off)
        return doc, raw[off + 8:off + 8 + blen]
    doc = json.loads(raw)
    return doc, (path.parent / doc["buffers"][0]["uri"]).read_bytes()


def accessor(doc: dict, buf: bytes, i: int) -> np.ndarray:
    """Accessor ``i`` as (count, components) float64, sparse values applied."""
    a = doc["accessors"][i]
    nc = _NCOMP[a["type"]]
    dt = np.dtype(_DTYPE[a["componentType"]])
    if "bufferView" in a:
        bv = doc["bufferViews"][a["bufferView"]]
        start = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
        out = np.frombuffer(buf, dt, a["count"] * nc, start).reshape(a["count"], nc)
        out = out.astype(np.float64)
    else:
        out = np.zeros((a["count"], nc))
    sp = a.get("sparse")
    if sp:
        iv = doc["bufferViews"][sp["indices"]["bufferView"]]
        idx = np.frombuffer(buf, np.dtype(_DTYPE[sp["indices"]["componentType"]]), sp["count"],
                            iv.get("byteOffset", 0) + sp["indices"].get("byteOffset", 0))
        vv = doc["bufferViews"][sp["values"]["bufferView"]]
        vals = np.frombuffer(buf, dt, sp["count"] * nc,
                             vv.get("byteOffset", 0) + sp["values"].get("byteOffset", 0))
        out = out.copy()
        out[idx.astype(np.int64)] = vals.reshape(-1, nc)
    if a.get("normalized"):
        out = out / float(np.iinfo(dt).max)
    return out


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def node_matrix(node: dict) -> np.ndarray:
    """A glTF node's local transform (4, 4) from its translation, rotation (quaternion
    x, y, z, w) and scale (each optional)."""
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(np.asarray(node.get("rotation", [0, 0, 0, 1]), np.float64))
    m[:3, :3] *= np.asarray(node.get("scale", [1, 1, 1]))[None]
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def evaluate_primitives(path: str | Path, frame: int | None = None) -> list[np.ndarray]:
    """Skinned vertices (V_i, 3) of every primitive of the skinned mesh, in the file's
    order, at animation keyframe ``frame`` (None: the file's default state)."""
    doc, buf = read_gltf(path)
    return [posed for _, posed in _posed_primitives(doc, buf, frame)]


def _posed_primitives(doc: dict, buf: bytes, frame: int | None, keep=lambda prim: True):
    nodes = [dict(n) for n in doc["nodes"]]
    mesh_node = next(i for i, n in enumerate(nodes) if "mesh" in n)
    mesh = doc["meshes"][nodes[mesh_node]["mesh"]]
    weights = np.asarray(mesh.get("weights", []), np.float64)
    if frame is not None:
        anim = doc["animations"][0]
        for ch in anim["channels"]:
            smp = anim["samplers"][ch["sampler"]]
            out = accessor(doc, buf, smp["output"])
            node, path_ = ch["target"]["node"], ch["target"]["path"]
            if path_ == "weights":
                weights = out.reshape(-1, len(weights))[frame]
            else:
                nodes[node][path_] = out[frame].tolist()
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}

    def world(i: int) -> np.ndarray:
        return world(parent[i]) @ node_matrix(nodes[i]) if i in parent else node_matrix(nodes[i])

    skin = doc["skins"][nodes[mesh_node]["skin"]]
    ibm = accessor(doc, buf, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    jm = np.stack([world(j) @ ibm[k] for k, j in enumerate(skin["joints"])])  # (J, 4, 4)
    for prim in filter(keep, mesh["primitives"]):
        at = prim["attributes"]
        pos = accessor(doc, buf, at["POSITION"])
        for w, tgt in zip(weights, prim.get("targets", []), strict=True):
            if w != 0:
                pos = pos + w * accessor(doc, buf, tgt["POSITION"])
        blend = np.zeros((len(pos), 4, 4))
        s = 0
        while f"JOINTS_{s}" in at:
            j = accessor(doc, buf, at[f"JOINTS_{s}"]).astype(np.int64)
            wt = accessor(doc, buf, at[f"WEIGHTS_{s}"])
            blend += np.einsum("nk,nkab->nab", wt, jm[j])
            s += 1
        yield prim, np.einsum("nab,nb->na", blend[:, :3, :3], pos) + blend[:, :3, 3]


def evaluate(path: str | Path, frame: int | None = None, num_vertices: int | None = None
             ) -> np.ndarray:
    """Skinned vertices (N, 3) in the model's order at animation keyframe ``frame`` (None:
    the file's default state). Vertices absent from the file are NaN; primitives without
    ``_HACK_VERTEX`` (the hair cards) are left out."""
    doc, buf = read_gltf(path)
    posed = [(accessor(doc, buf, p["attributes"]["_HACK_VERTEX"])[:, 0].astype(np.int64), v)
             for p, v in _posed_primitives(doc, buf, frame,
                                           lambda p: "_HACK_VERTEX" in p["attributes"])]
    n = num_vertices or 1 + max(int(idx.max()) for idx, _ in posed)
    result = np.full((n, 3), np.nan)
    for idx, v in posed:
        result[idx] = v
    return result
