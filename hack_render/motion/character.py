"""Characters in the model's topology with their own neck joints (paper Sec. 6.2: the
giraffe "has the same topology as the HACK template model and is in rest pose").

A character file is an ``.npz`` with ``vertices`` (N, 3) metres in the model's vertex order
and rest pose, ``joints`` (8, 3) its neck joints c7-t1 ... o-c1, optionally
``skinning_weights`` (N, 9) (root first; default: the model's), and a JSON ``meta`` string
(``name``, ``provenance``). :func:`long_neck_character` makes the procedural test
character from the template.

The character is animated like HACK (:func:`character_rig`): the person's targets
(personalised expressions, larynx slide in-betweens, pose correctives; ``export.rig``) are
moved onto the character's rest shape by deformation transfer (Sumner & Popovic 2004;
``motion.deformation_transfer``), and its skeleton is its own joints, posed by HACK's
per-joint rotations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.export import rig as R
from hack_render.export.gltf import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    UBYTE,
    UINT,
    GltfBuilder,
    write_document,
)
from hack_render.export.rig import frame_weights, top_weights
from hack_render.geometry.deformation import SkinTopology, deformation_stats, skin_topology
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms, skin
from hack_render.io.npz import write_npz
from hack_render.motion.deformation_transfer import TargetSolver, source_gradients
from hack_render.motion.surface_transfer import skin_faces

FORMAT = "hack-character"


@dataclass
class Character:
    """A rest-pose character in the model's topology.

    Attributes:
        vertices: (N, 3) metres.
        joints: (8, 3) neck joints c7-t1 ... o-c1, metres.
        weights: (N, 9) skinning weights, root first, rows summing to 1.
        meta: ``name`` and ``provenance`` (say "procedural" or where it came from).
    """

    vertices: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return str(self.meta.get("name", "character"))

    def save(self, path: str | Path) -> Path:
        return write_npz(path, {
            "vertices": self.vertices.astype(np.float64),
            "joints": self.joints.astype(np.float64),
            "skinning_weights": self.weights.astype(np.float32),
            "meta": np.str_(json.dumps({"format": FORMAT, "version": 1, **self.meta}))})


def check_character(ch: Character, model, where: str = "character") -> Character:
    """Shapes, finiteness, weights and a neck that rises: else a HackError naming the fix."""
    n = model.num_vertices
    v, j, w = (np.asarray(a, np.float64) for a in (ch.vertices, ch.joints, ch.weights))
    if v.shape != (n, 3):
        raise HackError(f"{where}: 'vertices' expected ({n}, 3) (the model's topology and "
                        f"vertex order), found {v.shape}. A character in another topology is a "
                        "glTF target with a neck chain (--neck-chain or --name-map).")
    if j.shape != (8, 3):
        raise HackError(f"{where}: 'joints' expected (8, 3), the neck joints c7-t1 ... o-c1, "
                        f"found {j.shape}: a target needs a neck chain.")
    if w.shape != (n, 9):
        raise HackError(f"{where}: 'skinning_weights' expected ({n}, 9) (root first), found "
                        f"{w.shape}.")
    for name, a in (("vertices", v), ("joints", j), ("skinning_weights", w)):
        if not np.isfinite(a).all():
            raise HackError(f"{where}: '{name}' contains NaN or inf.")
    if np.abs(w.sum(1) - 1).max() > 1e-3 or (w < 0).any():
        raise HackError(f"{where}: 'skinning_weights' rows must be >= 0 and sum to 1 (largest "
                        f"error {np.abs(w.sum(1) - 1).max():.3g}).")
    seg = np.linalg.norm(np.diff(j, axis=0), axis=1)
    if (seg < 1e-4).any() or j[-1, 1] <= j[0, 1]:
        raise HackError(f"{where}: the neck joints must be distinct and rise from c7-t1 to "
                        f"o-c1 (Y up); found segment lengths {np.round(seg * 1e3, 2)} mm and "
                        f"heights {j[0, 1]:.3f} -> {j[-1, 1]:.3f} m.")
    return Character(v, j, w, dict(ch.meta))


def load_character(path: str | Path, model) -> Character:
    """Read a character ``.npz`` (module docstring) and check it against ``model``."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"--target {path}: file not found.")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:
        raise HackError(f"--target {path}: not a readable .npz ({exc}).") from exc
    missing = [k for k in ("vertices", "joints") if k not in arrays]
    if missing:
        raise HackError(f"--target {path}: keys {missing} are missing; a character file holds "
                        "'vertices' (N, 3) and 'joints' (8, 3) (its neck chain).")
    meta = json.loads(str(arrays["meta"])) if "meta" in arrays else {}
    w = arrays.get("skinning_weights")
    if w is None:
        w = model.skinning_weights.double().numpy()
    return check_character(Character(arrays["vertices"], arrays["joints"], w,
                                     {"name": path.stem, **meta}), model, f"--target {path}")


def long_neck_character(model, base: np.ndarray | None = None, joints: np.ndarray | None = None,
                        neck_scale: float = 2.5, snout: float = 1.35) -> Character:
    """The procedural long-necked test character, made from the template: the neck
    lengthened ``neck_scale`` times along the spine (every node moved away from c7-t1 along
    the column, vertices by their skinning weights), the skull stretched ``snout`` times
    forward and narrowed (blended by the o-c1 weight). Procedural, not an artist's model.

    Args:
        base: (N, 3) the rest mesh to reshape (default: the template, larynx included).
        joints: (8, 3) its neck joints (default: the template's).
    """
    if not (1.0 <= neck_scale <= 5.0 and 0.5 <= snout <= 2.0):
        raise HackError(f"long-neck character: expected neck_scale in [1, 5] and snout in "
                        f"[0.5, 2], found {neck_scale}, {snout}.")
    with torch.no_grad():
        out = model(beta=torch.zeros(1, 0, dtype=model.template.dtype))
    v = out.rest_vertices[0].double().numpy() if base is None else np.asarray(base, np.float64)
    j = out.rest_joints[0].double().numpy() if joints is None else np.asarray(joints, np.float64)
    w = model.skinning_weights.double().numpy()
    nodes = np.concatenate([j[:1], j])  # root at c7-t1
    moved = nodes[0] + neck_scale * (nodes - nodes[0])
    v2 = v + w @ (moved - nodes)
    head = w[:, -1:]  # the o-c1 weight: 1 on the skull, 0 below the neck
    centre = moved[-1]
    scale = np.array([0.85, 1.0, snout])
    v2 = v2 + head * ((v2 - centre) * (scale - 1.0))
    meta = {"name": "long_neck", "provenance": {
        "kind": "procedural", "source": "hack_render.motion.character.long_neck_character: "
        f"the HACK template's neck lengthened {neck_scale}x along the spine, the skull "
        f"stretched {snout}x forward and narrowed to 0.85x; not an artist's model"}}
    return Character(v2, moved[1:], w, meta)


@dataclass
class CharacterRig:
    """A character ready to animate and export: an ``export.rig.ExportRig`` (base = the
    character's rest, targets transferred, nodes = its joints) and its full weights."""

    rig: object
    weights: np.ndarray
    parents: tuple[int, ...]

    def pose(self, psi=None, theta=None, tau=None, global_orient=None, transl=None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices (T, N, 3) and node rotations (T, 9, 3, 3) for T frames
        (theta (T, 8, 3) required; psi (T, E), tau (T,), global_orient, transl (T, 3))."""
        theta = np.asarray(theta, np.float64)
        t = len(theta)
        r = self.rig
        wts = frame_weights(r, psi, theta, tau)
        rest = r.base[None] + np.einsum("tk,knc->tnc", wts, r.targets, optimize=True)
        go = np.zeros((t, 3)) if global_orient is None else np.asarray(global_orient, np.float64)
        rot = local_rotations(torch.as_tensor(theta), torch.as_tensor(go))
        nodes = torch.as_tensor(r.rest_nodes)[None].expand(t, -1, -1)
        _, rel = rigid_transforms(rot, nodes, chain_parents(self.parents))
        verts = skin(torch.as_tensor(rest), torch.as_tensor(self.weights), rel).numpy()
        if transl is not None:
            verts = verts + np.asarray(transl, np.float64)[:, None]
        return verts, rel[..., :3, :3].numpy()


def _transfer_targets(model, src_base: np.ndarray, dst_base: np.ndarray,
                      targets: np.ndarray, chunk: int = 16) -> np.ndarray:
    """Deformation transfer of morph targets (K, N, 3) from ``src_base`` to ``dst_base``
    (both (N, 3), the model's topology): the vertices some target moves are solved for,
    the others stay put. A mesh component that every target leaves whole-free (a tooth, an
    eye's lacrimal film: no fixed vertex to anchor its position, so the Poisson system
    would be singular there) takes the source's displacements as they are."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    faces = model.faces.numpy()
    n = len(dst_base)
    free = np.any(targets != 0, axis=(0, 2))
    if not free.any():
        return np.zeros_like(targets)
    ring = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adj = sparse.coo_matrix((np.ones(len(ring)), (ring[:, 0], ring[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    anchored = np.zeros(label.max() + 1, bool)
    anchored[np.unique(label[~free])] = True
    solve = free & anchored[label]
    out = np.zeros_like(targets)
    copy = free & ~solve
    out[:, copy] = targets[:, copy]
    near = faces[solve[faces].any(1)]
    solver = TargetSolver(dst_base, near, solve)
    for s in range(0, len(targets), chunk):
        part = targets[s:s + chunk].astype(np.float64)
        grads = np.stack([source_gradients(src_base, src_base + d, solver.faces) for d in part])
        res = solver.transfer(grads) - dst_base[None]
        out[s:s + chunk, solve] = res[:, solve].astype(targets.dtype)
    return out


def character_rig(model, character: Character, beta=None, eta: float = 1.0,
                  influences: int = 4, tau_range: float | None = None) -> CharacterRig:
    """The person (``beta``, ``eta``) rigged for export, then moved onto ``character``:
    targets by deformation transfer, the skeleton at the character's joints, its weights."""
    tau_range = R.TAU_RANGE if tau_range is None else tau_range
    human = R.build_rig(model, beta, eta, tau_range, R.TAU_STEP, influences)
    targets = np.zeros_like(human.targets)
    for sl in human.slots.values():  # one solve per kind: each kind's own free vertices
        if sl.stop > sl.start:
            targets[sl] = _transfer_targets(model, human.base, character.vertices,
                                            human.targets[sl])
    j4, w4 = R.top_weights(character.weights, influences)
    rig = replace(human, base=np.asarray(character.vertices, np.float64), targets=targets,
                  rest_nodes=np.concatenate([character.joints[:1], character.joints]),
                  joints4=j4, weights4=w4)
    shim = SimpleNamespace(skinning_weights=torch.as_tensor(character.weights),
                           parents=model.parents, rotation_limits_deg=model.rotation_limits_deg)
    rig.weight_error_m = R.weight_truncation_error(shim, rig)
    return CharacterRig(rig, np.asarray(character.weights, np.float64), tuple(model.parents))


def lbs_only(crig: CharacterRig) -> CharacterRig:
    """The same character without pose correctives (plain LBS), the stress test's reference."""
    r = crig.rig
    t = r.targets.copy()
    t[r.slots["pose"]] = 0.0
    return CharacterRig(replace(r, targets=t), crig.weights, crig.parents)


def pose_checks(crig: CharacterRig, model, theta: np.ndarray, psi=None) -> dict:
    """The pose-space stress test's measures (``geometry.deformation``) on a character:
    per pose, the largest skin-edge stretch and compression and the folded skin triangles,
    against the character at zero pose with the same expression. theta (P, 8, 3)."""
    topo = skin_topology(model)
    topo = SkinTopology(topo.faces, topo.edges,
                        torch.as_tensor(crig.weights)[topo.faces].mean(1))
    theta = np.asarray(theta, np.float64)
    p = len(theta)
    e = crig.rig.num_expressions
    ps = None if psi is None else np.broadcast_to(np.asarray(psi, np.float64), (p, e))
    rest, _ = crig.pose(None if ps is None else ps[:1], np.zeros((1, 8, 3)))
    out = {"stretch": [], "compression": [], "folded": []}
    for s in range(0, p, 32):
        verts, rots = crig.pose(None if ps is None else ps[s:s + 32], theta[s:s + 32])
        st = deformation_stats(torch.as_tensor(rest), torch.as_tensor(verts),
                               torch.as_tensor(rots), topo)
        for k, acc in out.items():
            acc.append(getattr(st, k).numpy())
    return {k: np.concatenate(v) for k, v in out.items()}


#: The procedural glTF character's bones (:func:`long_neck_gltf`) and the HACK nodes
#: (root, then c7-t1 ... o-c1) each one takes the skinning weight of.
GLTF_BONES = {"hips": (), "spine": (0,), "neck_01": (1, 2), "neck_02": (3, 4),
              "neck_03": (5, 6, 7), "head": (8,)}


def long_neck_gltf(model, path: str | Path, character: Character | None = None,
                   hips_drop: float = 0.3) -> Path:
    """The procedural long-necked character (:func:`long_neck_character`) written as a
    plain glTF character of its own: the skin's triangles only (no eyes, teeth or mouth
    interior), no UVs and no materials, a skeleton of 6 bones (``hips`` and ``spine``
    below, ``neck_01`` at c7-t1, ``neck_02`` at c5-c6, ``neck_03`` at c3-c4, ``head`` at
    o-c1) and 4 skin weights per vertex summed from HACK's onto them (:data:`GLTF_BONES`);
    ``_HACK_VERTEX`` holds each vertex's template index (as the export's), for tests.
    A test target for the glTF path; labelled procedural in ``asset.extras``."""
    ch = long_neck_character(model) if character is None else character
    faces, _ = skin_faces(model)
    used = np.unique(faces)
    v = ch.vertices[used]
    f = np.searchsorted(used, faces)
    nodes9 = np.concatenate([ch.joints[:1], ch.joints])
    heads = {"hips": nodes9[0] - [0.0, hips_drop, 0.0], "spine": nodes9[0] - [0.0, 0.1, 0.0],
             "neck_01": nodes9[1], "neck_02": nodes9[3], "neck_03": nodes9[5],
             "head": nodes9[8]}
    names = list(GLTF_BONES)
    w = np.zeros((len(used), len(names)))
    for b, src in enumerate(GLTF_BONES.values()):
        for s in src:
            w[:, b] += ch.weights[used, s]
    j4, w4 = top_weights(w, 4)
    g = GltfBuilder()
    attrs = {"POSITION": g.accessor(v, FLOAT, "VEC3", ARRAY_BUFFER, bounds=True),
             "JOINTS_0": g.accessor(j4, UBYTE, "VEC4", ARRAY_BUFFER),
             "WEIGHTS_0": g.accessor(w4, FLOAT, "VEC4", ARRAY_BUFFER),
             "_HACK_VERTEX": g.accessor(used.astype(np.float32), FLOAT, "SCALAR", ARRAY_BUFFER,
                                        bounds=True)}
    g._add("meshes", {"name": ch.name, "primitives": [{"attributes": attrs, "mode": 4,
           "indices": g.accessor(f.reshape(-1, 1), UINT, "SCALAR", ELEMENT_ARRAY_BUFFER)}]})
    for i, n in enumerate(names):
        t = heads[n] - (heads[names[i - 1]] if i else 0.0)
        node = {"name": n, "translation": [float(x) for x in t]}
        if i + 1 < len(names):
            node["children"] = [i + 1]
        g._add("nodes", node)
    ibm = np.tile(np.eye(4).reshape(1, 16), (len(names), 1))
    ibm[:, 12:15] = -np.stack([heads[n] for n in names])
    g._add("skins", {"joints": list(range(len(names))),
                     "inverseBindMatrices": g.accessor(ibm, FLOAT, "MAT4")})
    body = g._add("nodes", {"name": ch.name, "mesh": 0, "skin": 0})
    g.doc["scenes"] = [{"nodes": [0, body]}]
    g.doc["scene"] = 0
    g.doc["asset"]["extras"] = {"character": ch.meta, "note": "procedural test character for "
                                "the glTF path of hack-render transfer (skin only, no UVs)"}
    return write_document(g, path)[0]
