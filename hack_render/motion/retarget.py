"""HACK's neck motion on a glTF character with any neck chain.

The 8 HACK joints are mapped onto the character's neck bones, from the base of the neck to
the head: by a name map (each HACK joint to a bone; several may share one), or by arc
length (each HACK joint to the bone nearest its relative position along the column; the
chain named by ``--neck-chain`` or found by bone names containing "neck" up to "head").
Each bone's rotation is the product of its HACK joints' rotations, in chain order.

Retargeting in each bone's rest frame: HACK's joint frames are the model's axes at rest
(Y up, face +Z, glTF's convention too), so a HACK rotation R is about world axes; a bone
whose rest world rotation is Q turns by ``Q^-1 R Q`` in its own frame, and its animated
local rotation is ``r_rest Q^-1 R Q``. Composed down the chain, each bone's world rotation
becomes ``R_1 ... R_b Q_b``: the head turns exactly as HACK's skull does, whatever the
bones' rest orientations (the tests' round trip).

The animation is added to a copy of the character's glTF (the export's
:class:`~hack_render.export.gltf.GltfBuilder` and writer), as LINEAR rotation channels on
the mapped bones. A primitive without ``TEXCOORD_0`` gets a UV atlas from xatlas.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xatlas

from hack_render.errors import HackError
from hack_render.export.gltf import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    UINT,
    GltfBuilder,
    skin_material,
    write_document,
)
from hack_render.export.reference import accessor, node_matrix, read_gltf
from hack_render.geometry.rotations import axis_angle_to_matrix, matrix_to_quaternion
from hack_render.geometry.skeleton import JOINT_NAMES


@dataclass
class GltfCharacter:
    """A glTF document, its buffer, and each node's rest transforms.

    Attributes:
        doc, buf: the JSON document and its binary buffer.
        parents: parent node index per node (-1: a scene root).
        world: (n, 4, 4) rest world matrices of the nodes.
    """

    path: Path
    doc: dict
    buf: bytes
    parents: list[int]
    world: np.ndarray

    @property
    def names(self) -> list[str]:
        return [n.get("name", f"node{i}") for i, n in enumerate(self.doc.get("nodes", []))]

    def node(self, name: str) -> int:
        names = self.names
        if name not in names:
            raise HackError(f"{self.path}: no node named {name!r}; nodes: "
                            f"{', '.join(names[:40])}{' ...' if len(names) > 40 else ''}.")
        return names.index(name)


def _local(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T
    return node_matrix(node)


def load_gltf_character(path: str | Path) -> GltfCharacter:
    """Read a ``.glb``/``.gltf`` character with a skin; errors name the fix."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--target {path}: file not found.")
    try:
        doc, buf = read_gltf(path)
    except Exception as exc:
        raise HackError(f"--target {path}: not a readable glTF 2.0 file ({exc}).") from exc
    nodes = doc.get("nodes", [])
    if len(doc.get("buffers", [])) > 1:
        raise HackError(f"--target {path}: {len(doc['buffers'])} buffers; expected one (a "
                        ".glb, or a .gltf with one .bin): re-export it as .glb.")
    if not doc.get("skins") or not nodes:
        raise HackError(f"--target {path}: the glTF has no skin (skeleton); a target needs a "
                        "skinned mesh with a neck chain.")
    parents = [-1] * len(nodes)
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parents[c] = i
    world = np.zeros((len(nodes), 4, 4))
    done = [False] * len(nodes)

    def w(i: int) -> np.ndarray:
        if not done[i]:
            world[i] = _local(nodes[i]) if parents[i] < 0 else w(parents[i]) @ _local(nodes[i])
            done[i] = True
        return world[i]

    for i in range(len(nodes)):
        w(i)
    return GltfCharacter(path, doc, bytes(buf), parents, world)


def find_neck_chain(ch: GltfCharacter, chain: list[str] | None = None) -> list[int]:
    """Node indices of the neck chain, base first, head last: the names given, or the
    skin's bones named like "neck" followed by the first "head" bone above them."""
    if chain:
        idx = [ch.node(n) for n in chain]
        for a, b in itertools.pairwise(idx):
            if not _is_ancestor(ch, a, b):
                raise HackError(f"--neck-chain: {ch.names[a]!r} is not an ancestor of "
                                f"{ch.names[b]!r}; list the chain's bones from the base of the "
                                "neck up to the head.")
        return idx
    joints = {j for s in ch.doc["skins"] for j in s["joints"]}
    names = ch.names
    neck = [i for i in joints if "neck" in names[i].lower()]
    head = [i for i in joints if "head" in names[i].lower() and "end" not in names[i].lower()]
    if not neck and not head:
        raise HackError(f"--target {ch.path}: no neck chain found (no skin bone named like "
                        "'neck' or 'head'); name it with --neck-chain BONE1,...,HEAD or map the "
                        "joints with --name-map.")
    tip = next((h for h in sorted(head) if any(_is_ancestor(ch, n, h) for n in neck)),
               head[0] if head else max(neck, key=lambda i: _depth(ch, i)))
    path = [tip]
    while ch.parents[path[-1]] >= 0 and ch.parents[path[-1]] in neck:
        path.append(ch.parents[path[-1]])
    path = path[::-1]
    if len(path) < 2:
        raise HackError(f"--target {ch.path}: the neck chain is a single bone "
                        f"({names[path[0]]!r}); name the chain with --neck-chain.")
    return path


def _is_ancestor(ch: GltfCharacter, a: int, b: int) -> bool:
    while b >= 0:
        b = ch.parents[b]
        if b == a:
            return True
    return False


def _depth(ch: GltfCharacter, i: int) -> int:
    d = 0
    while ch.parents[i] >= 0:
        i, d = ch.parents[i], d + 1
    return d


def arc_length_map(hack_joints: np.ndarray, chain_pos: np.ndarray) -> list[int]:
    """For each HACK joint (8, 3) the index of the chain bone (B, 3) nearest its relative
    arc length (c7-t1 at 0, o-c1 at 1; the chain's first bone at 0, its last at 1)."""
    def rel(p):
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
        return s / max(s[-1], 1e-12)

    s, u = rel(hack_joints), rel(chain_pos)
    return [int(np.argmin(np.abs(u - x))) for x in s]


def joint_map(ch: GltfCharacter, hack_joints: np.ndarray, chain: list[str] | None = None,
              name_map: dict | None = None) -> tuple[list[int], list[int]]:
    """(bones, assignment): the chain's node indices and, per HACK joint, the index into
    ``bones`` that receives its rotation."""
    bones, assign = _joint_map(ch, hack_joints, chain, name_map)
    fixed = [ch.names[b] for b in bones if "matrix" in ch.doc["nodes"][b]]
    if fixed:
        raise HackError(f"--target {ch.path}: bones {fixed} store a matrix, which glTF does "
                        "not animate; re-export the character with translation/rotation/"
                        "scale nodes.")
    return bones, assign


def _joint_map(ch, hack_joints, chain, name_map):
    if name_map:
        unknown = sorted(set(name_map) - set(JOINT_NAMES))
        missing = [j for j in JOINT_NAMES if j not in name_map]
        if unknown or missing:
            raise HackError(f"--name-map: expected every HACK joint ({', '.join(JOINT_NAMES)}) "
                            f"mapped to a bone; unknown {unknown}, missing {missing}.")
        nodes = [ch.node(name_map[j]) for j in JOINT_NAMES]
        bones = sorted(set(nodes), key=lambda i: _depth(ch, i))
        assign = [bones.index(n) for n in nodes]
        if assign != sorted(assign):
            raise HackError("--name-map: the bones must follow the neck upwards (c7-t1's bone "
                            "at or below c6-c7's, ..., o-c1's the highest).")
        for a, b in itertools.pairwise(bones):
            if not _is_ancestor(ch, a, b):
                raise HackError(f"--name-map: {ch.names[a]!r} and {ch.names[b]!r} are not on "
                                "one chain (the first is not an ancestor of the second); map "
                                "the joints onto the neck's bones from its base to the head.")
        return bones, assign
    bones = find_neck_chain(ch, chain)
    return bones, arc_length_map(hack_joints, ch.world[bones, :3, 3])


def bone_rotations(theta: np.ndarray, assign: list[int], n_bones: int) -> np.ndarray:
    """World-axes rotation per bone and frame: theta (T, 8, 3) -> (T, B, 3, 3), each bone's
    HACK joints' rotations multiplied in chain order (identity for a bone with none)."""
    r = _matrices(theta)
    out = np.tile(np.eye(3), (len(r), n_bones, 1, 1))
    for j, b in enumerate(assign):
        out[:, b] = out[:, b] @ r[:, j]
    return out


def _quat(m: np.ndarray) -> np.ndarray:
    """(…, 3, 3) -> (…, 4) xyzw, w >= 0."""
    import torch

    q = matrix_to_quaternion(torch.as_tensor(m)).numpy()  # wxyz
    return np.concatenate([q[..., 1:], q[..., :1]], -1)


def _rest_frame(ch: GltfCharacter, node: int, rot: np.ndarray) -> np.ndarray:
    """Local rotations (T, 3, 3) of ``node`` that turn it by world-axes rotations ``rot``
    (T, 3, 3) about its rest orientation: ``r_rest Q^-1 R Q``."""
    q = ch.world[node, :3, :3]
    q = q / np.linalg.norm(q, axis=0, keepdims=True)  # rotation part (no scale)
    rest = _local(ch.doc["nodes"][node])[:3, :3]
    rest = rest / np.linalg.norm(rest, axis=0, keepdims=True)
    return rest @ q.T @ rot @ q


def _hemisphere(q: np.ndarray) -> np.ndarray:
    """One hemisphere between consecutive frames (axis 0), for interpolation."""
    for i in range(1, len(q)):
        flip = (q[i] * q[i - 1]).sum(-1) < 0
        q[i, flip] *= -1
    return q


def retarget(ch: GltfCharacter, bones: list[int], assign: list[int],
             theta: np.ndarray, global_orient: np.ndarray | None = None) -> np.ndarray:
    """Local rotations (T, B, 4) xyzw of the chain's bones: ``r_rest Q^-1 R Q`` per bone;
    ``global_orient`` (T, 3), when given, turns the first bone too (a chain that starts at
    the skeleton's root, see :func:`body_root`)."""
    rb = bone_rotations(theta, assign, len(bones))
    if global_orient is not None:
        rb[:, 0] = _matrices(global_orient) @ rb[:, 0]
    q = _quat(np.stack([_rest_frame(ch, b, rb[:, k]) for k, b in enumerate(bones)], 1))
    return _hemisphere(q)


def _matrices(r: np.ndarray) -> np.ndarray:
    import torch

    return axis_angle_to_matrix(torch.as_tensor(np.array(r, np.float64))).numpy()


def body_root(ch: GltfCharacter, bones: list[int]) -> int:
    """The node that carries HACK's global pose: the highest skin joint above the neck
    chain (the body's root, e.g. the hips), or the chain's first bone when none is."""
    joints = {j for s in ch.doc["skins"] for j in s["joints"]}
    root, i = bones[0], ch.parents[bones[0]]
    while i >= 0:
        if i in joints:
            root = i
        i = ch.parents[i]
    if "matrix" in ch.doc["nodes"][root]:
        raise HackError(f"--target {ch.path}: the root bone {ch.names[root]!r} stores a matrix, "
                        "which glTF does not animate; re-export the character with "
                        "translation/rotation/scale nodes.")
    return root


def root_tracks(ch: GltfCharacter, root: int, global_orient: np.ndarray,
                transl: np.ndarray) -> dict[str, np.ndarray]:
    """HACK's global pose on the body's root: {"rotation": (T, 4) xyzw (the global rotation
    about world axes, in the root's rest frame), "translation": (T, 3) (the rest
    translation plus ``transl`` metres along world axes)}."""
    node = ch.doc["nodes"][root]
    rot = _hemisphere(_quat(_rest_frame(ch, root, _matrices(global_orient))))
    p = ch.parents[root]
    lin = ch.world[p, :3, :3] if p >= 0 else np.eye(3)
    t = np.asarray(node.get("translation", [0.0, 0.0, 0.0]), np.float64)
    return {"rotation": rot, "translation": t + np.asarray(transl, np.float64) @ np.linalg.inv(lin).T}


@dataclass
class PosedPrimitive:
    """One triangle primitive, posed: its node, mesh and primitive indices, vertices
    (V, 3) world, faces (F, 3), each vertex's linear transform (V, 3, 3) (blended skin
    matrices, or its node's) and the node of its largest skin weight (V,) (-1: none)."""

    node: int
    mesh: int
    prim: int
    vertices: np.ndarray
    faces: np.ndarray
    linear: np.ndarray
    dominant: np.ndarray


def posed_primitives(ch: GltfCharacter, nodes: list[dict] | None = None,
                     morph: dict[int, np.ndarray] | None = None):
    """Every triangle primitive posed (glTF 2.0 skinning: joints' world matrices times
    inverse bind matrices; unskinned ones by their node's world matrix), morph targets
    first: yields :class:`PosedPrimitive`.

    Args:
        nodes: the document's nodes with animated values set (default: the rest pose).
        morph: mesh index -> its morph weights (default: the mesh's ``weights`` or 0).
    """
    nodes = ch.doc["nodes"] if nodes is None else nodes
    morph = morph or {}
    world: dict[int, np.ndarray] = {}

    def w(i: int) -> np.ndarray:
        if i not in world:
            local = _local(nodes[i])
            world[i] = local if ch.parents[i] < 0 else w(ch.parents[i]) @ local
        return world[i]

    for i, node in enumerate(nodes):
        if "mesh" not in node:
            continue
        mesh = ch.doc["meshes"][node["mesh"]]
        skin = ch.doc["skins"][node["skin"]] if "skin" in node else None
        if skin is not None:
            ibm = (accessor(ch.doc, ch.buf, skin["inverseBindMatrices"]).reshape(-1, 4, 4)
                   .transpose(0, 2, 1) if "inverseBindMatrices" in skin
                   else np.tile(np.eye(4), (len(skin["joints"]), 1, 1)))
            jm = np.stack([w(j) @ ibm[k] for k, j in enumerate(skin["joints"])])
        weights = morph.get(node["mesh"], mesh.get("weights"))
        for pi, prim in enumerate(mesh["primitives"]):
            if prim.get("mode", 4) != 4:
                continue
            at = prim["attributes"]
            pos = accessor(ch.doc, ch.buf, at["POSITION"])
            for wk, tgt in zip(weights if weights is not None else [], prim.get("targets", []),
                               strict=False):
                if wk != 0 and "POSITION" in tgt:
                    pos = pos + wk * accessor(ch.doc, ch.buf, tgt["POSITION"])
            pos = np.c_[pos, np.ones(len(pos))]
            dom = np.full(len(pos), -1)
            if skin is not None and "JOINTS_0" in at:
                m = np.zeros((len(pos), 4, 4))
                k, best = 0, np.zeros(len(pos))
                while f"JOINTS_{k}" in at:
                    jj = accessor(ch.doc, ch.buf, at[f"JOINTS_{k}"]).astype(np.int64)
                    ww = accessor(ch.doc, ch.buf, at[f"WEIGHTS_{k}"])
                    m += np.einsum("nk,nkab->nab", ww, jm[jj])
                    a = ww.argmax(1)
                    top = ww[np.arange(len(ww)), a]
                    dom = np.where(top > best, np.asarray(skin["joints"])[jj[np.arange(len(jj)), a]],
                                   dom)
                    best = np.maximum(best, top)
                    k += 1
            else:
                m = np.broadcast_to(w(i), (len(pos), 4, 4))
            v = np.einsum("nab,nb->na", m, pos)[:, :3]
            idx = (accessor(ch.doc, ch.buf, prim["indices"])[:, 0].astype(np.int64)
                   if "indices" in prim else np.arange(len(v)))
            yield PosedPrimitive(i, node["mesh"], pi, v, idx.reshape(-1, 3), m[:, :3, :3], dom)


def descendants(ch: GltfCharacter, node: int) -> set[int]:
    """``node`` and every node below it."""
    return {i for i in range(len(ch.parents)) if i == node or _is_ancestor(ch, node, i)}


def posed_nodes(ch: GltfCharacter, bones: list[int] | None = None,
                quats: np.ndarray | None = None, tracks: dict | None = None) -> list[dict]:
    """A copy of the nodes with local rotations ``quats`` (B, 4) xyzw on ``bones`` and
    ``tracks`` {node: {"rotation": (4,), "translation": (3,)}} set."""
    nodes = [dict(n) for n in ch.doc["nodes"]]
    for b, q in zip(bones or [], [] if quats is None else quats, strict=True):
        nodes[b]["rotation"] = [float(x) for x in q]
    for b, tr in (tracks or {}).items():
        for key, val in tr.items():
            nodes[b][key] = [float(x) for x in val]
    return nodes


def posed_mesh(ch: GltfCharacter, bones: list[int] | None = None,
               quats: np.ndarray | None = None, tracks: dict | None = None,
               morph: dict[int, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The character's triangles posed (:func:`posed_nodes`, :func:`posed_primitives`;
    default: the rest pose) -> vertices (V, 3), faces (F, 3) over every triangle primitive
    of the scene."""
    verts, faces, off = [], [], 0
    for p in posed_primitives(ch, posed_nodes(ch, bones, quats, tracks), morph):
        verts.append(p.vertices)
        faces.append(p.faces + off)
        off += len(p.vertices)
    if not verts:
        raise HackError(f"{ch.path}: no triangle mesh to show.")
    return np.concatenate(verts), np.concatenate(faces)


def add_uv_atlas(ch: GltfCharacter, resolution: int = 1024,
                 padding: int = 2) -> list[tuple[int, int]]:
    """Give every triangle primitive without ``TEXCOORD_0`` a UV atlas from xatlas (its
    vertices split at the atlas's seams, every attribute and morph target carried along),
    its charts ``padding`` texels apart at ``resolution`` texels (so a map baked at that
    size filters without bleeding between charts); returns the (mesh, primitive) indices
    of those that got one."""

    g = GltfBuilder()
    g.doc, g.bin = ch.doc, bytearray(ch.buf)
    done = []
    for m_i, mesh in enumerate(ch.doc.get("meshes", [])):
        for pi, prim in enumerate(mesh["primitives"]):
            if "TEXCOORD_0" in prim["attributes"] or prim.get("mode", 4) != 4:
                continue
            pos = accessor(g.doc, bytes(g.bin), prim["attributes"]["POSITION"])
            idx = (accessor(g.doc, bytes(g.bin), prim["indices"])[:, 0].astype(np.uint32)
                   if "indices" in prim else np.arange(len(pos), dtype=np.uint32))
            atlas = xatlas.Atlas()
            atlas.add_mesh(pos.astype(np.float32), idx.reshape(-1, 3).astype(np.uint32))
            pack = xatlas.PackOptions()
            pack.resolution, pack.padding, pack.bilinear = int(resolution), int(padding), True
            atlas.generate(pack_options=pack)
            vmap, faces, uvs = atlas[0]
            for key, acc in list(prim["attributes"].items()):
                a = g.doc["accessors"][acc]
                vals = accessor(g.doc, bytes(g.bin), acc)[vmap]
                if a["componentType"] != FLOAT and not a.get("normalized"):
                    vals = vals.astype(np.int64)
                prim["attributes"][key] = g.accessor(vals, a["componentType"], a["type"],
                                                     ARRAY_BUFFER, bounds=key == "POSITION")
            for tgt in prim.get("targets", []):
                for key, acc in list(tgt.items()):
                    vals = accessor(g.doc, bytes(g.bin), acc)[vmap]
                    tgt[key] = g.accessor(vals, FLOAT, g.doc["accessors"][acc]["type"],
                                          bounds=key == "POSITION")
            prim["attributes"]["TEXCOORD_0"] = g.accessor(uvs, FLOAT, "VEC2", ARRAY_BUFFER)
            prim["indices"] = g.accessor(faces.reshape(-1, 1).astype(np.uint32), UINT,
                                         "SCALAR", ELEMENT_ARRAY_BUFFER)
            done.append((m_i, pi))
    ch.buf = bytes(g.bin)
    return done


def _builder(ch: GltfCharacter):
    """A GltfBuilder appending to the character's own document and buffer (store
    ``bytes(g.bin)`` back into ``ch.buf`` when done)."""
    g = GltfBuilder()
    g.doc, g.bin = ch.doc, bytearray(ch.buf)
    return g


def add_morph_targets(ch: GltfCharacter, mesh: int, targets: dict[int, np.ndarray],
                      names: list[str]) -> int:
    """Append K morph targets to every primitive of mesh ``mesh``: ``targets`` maps a
    primitive index to its POSITION displacements (K, V, 3) (sparse accessors: only moved
    vertices stored); other primitives get empty ones (glTF wants one count per mesh).
    Names go to ``extras.targetNames``, 0 to the default weights. Returns the first new
    target's index."""
    g = _builder(ch)
    m = ch.doc["meshes"][mesh]
    old = len(m["primitives"][0].get("targets", []))
    for pi, prim in enumerate(m["primitives"]):
        count = ch.doc["accessors"][prim["attributes"]["POSITION"]]["count"]
        t = targets.get(pi)
        tl = prim.setdefault("targets", [])
        for k in range(len(names)):
            tl.append({"POSITION": g.sparse_vec3(np.zeros((count, 3)) if t is None else t[k])})
    extras = m.setdefault("extras", {})
    extras["targetNames"] = (list(extras.get("targetNames", [f"target_{i}" for i in range(old)]))
                             + list(names))
    m["weights"] = [float(x) for x in m.get("weights", [0.0] * old)] + [0.0] * len(names)
    ch.buf = bytes(g.bin)
    return old


def add_baked_material(ch: GltfCharacter, prim: dict, maps, name: str) -> int:
    """A material with baked maps (diffuse, specular, roughness, normal in the
    character's atlas; the export's :func:`~hack_render.export.gltf.skin_material`),
    assigned to ``prim``; the extensions it uses are declared."""
    g = _builder(ch)
    mat = skin_material(g, maps)
    ch.doc["materials"][mat]["name"] = name
    prim["material"] = mat
    used = set(ch.doc.get("extensionsUsed", []))
    used |= set(ch.doc["materials"][mat].get("extensions", {}))
    ch.doc["extensionsUsed"] = sorted(used)
    ch.buf = bytes(g.bin)
    return mat


def write_animated(ch: GltfCharacter, bones: list[int], quats: np.ndarray, fps: float,
                   output: str | Path, provenance: dict, tracks: dict | None = None,
                   morph_weights: dict[int, np.ndarray] | None = None) -> list[Path]:
    """A copy of the character with an animation ``hack_transfer`` (LINEAR rotations of
    ``bones``, quats (T, B, 4) xyzw; ``tracks`` {node: {"rotation" (T, 4), "translation"
    (T, 3)}}; ``morph_weights`` {mesh node: (T, K) every morph weight of its mesh})
    through the export's builder and writer."""
    g = GltfBuilder()
    g.doc = json.loads(json.dumps(ch.doc))
    g.doc.pop("buffers", None)
    for bv in g.doc.get("bufferViews", []):
        bv["buffer"] = 0
    g.bin = bytearray(ch.buf)
    times = g.accessor((np.arange(len(quats)) / fps).reshape(-1, 1), FLOAT, "SCALAR", bounds=True)
    samplers, channels = [], []

    def add(node: int, path: str, values: np.ndarray, atype: str) -> None:
        out = g.accessor(values, FLOAT, atype)
        samplers.append({"input": times, "output": out, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    for k, b in enumerate(bones):
        add(b, "rotation", quats[:, k], "VEC4")
    for node, tr in (tracks or {}).items():
        for path, values in tr.items():
            add(node, path, values, "VEC4" if path == "rotation" else "VEC3")
    for node, wts in (morph_weights or {}).items():
        add(node, "weights", np.asarray(wts).reshape(-1, 1), "SCALAR")
    g.doc.setdefault("animations", []).append({"name": "hack_transfer", "samplers": samplers,
                                               "channels": channels})
    g.doc.setdefault("asset", {"version": "2.0"}).setdefault("extras", {})["hack_transfer"] = \
        provenance
    return write_document(g, output)
