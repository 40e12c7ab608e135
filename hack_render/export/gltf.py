"""Writing a rigged person (:class:`~hack_render.export.rig.ExportRig`) as glTF 2.0.

Layout of the file:

- one mesh, one primitive per render part (``render/parts.py``: skin face, skin back,
  mouth, teeth, sclera, iris, lacrimal film, eyelashes), each split at its UV seams, with
  ``_HACK_VERTEX`` (float, the model's vertex index of every glTF vertex), ``POSITION``,
  ``NORMAL``, ``TEXCOORD_0``, ``JOINTS_0``/``WEIGHTS_0`` (and ``_1`` with 8 influences),
  and ``COLOR_0`` on the iris (and on each part a fit's bake coloured:
  ``SkinMaps.part_rgb``, from ``--textures``' ``parts.npz``);
- with hair (:mod:`.hair_cards`), one more primitive per strand group (scalp, brows,
  lashes, beard; ``extras.hair`` names it) of alpha-textured cards: ``POSITION``,
  ``NORMAL``, ``TEXCOORD_0``, the root triangle's blended skin weights, every morph target
  (the root's blended deltas) and no ``_HACK_VERTEX``; its lashes replace the eyelash part;
- morph targets named in ``mesh.extras.targetNames`` (the model's expression names first),
  stored as sparse accessors: only the vertices a target moves are written, a target that
  moves none of a part's vertices has no data at all (an accessor of zeros);
- a skin over 9 nodes (``thorax`` root, then the model's joints), inverse bind matrices
  from the rest pose; the nodes' default transforms and the mesh's default weights are the
  parameter file's pose, so the file at rest shows what `hack-render mesh` shows;
- materials: the skin (base colour, roughness and metallic, normal map; specular intensity
  through ``KHR_materials_specular`` with skin's index of refraction 1.4 through
  ``KHR_materials_ior``), one material per other part, and per hair group a two-sided,
  alpha-masked material with its procedural strand texture;
- an animation ``sequence`` when a parameter sequence is given: per frame, each node's
  rotation, the root's translation and every morph weight (expressions, larynx slide
  in-betweens, pose correctives from the pose feature), linearly interpolated.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from appearance.colour_space import srgb_encode
from hack_render.errors import HackError
from hack_render.export.hair_cards import HAIR_ALPHA_CUTOFF, HAIR_ROUGHNESS
from hack_render.export.rig import pose_split
from hack_render.io import atomic_path
from hack_render.render.materials import EYELASH_OPACITY, iris_vertex_colors, material_base_colours
from hack_render.render.parts import Topology, split_parts, vertex_normals

FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPE = {FLOAT: "<f4", UBYTE: "u1", USHORT: "<u2", UINT: "<u4"}
#: Perceptual roughness of the non-skin parts (sqrt of the renderer's GGX alpha).
PART_ROUGHNESS = {"mouth": 0.45, "teeth": 0.39, "sclera": 0.22, "iris": 0.3,
                  "lacrimal": 0.17, "eyelashes": 0.55}
SKIN_IOR = 1.4


class GltfBuilder:
    """Accumulates a glTF document and its one binary buffer."""

    def __init__(self):
        self.doc: dict = {"asset": {"version": "2.0", "generator": "hack-render export"},
                          "buffers": [], "bufferViews": [], "accessors": []}
        self.bin = bytearray()

    def _add(self, key: str, item: dict) -> int:
        self.doc.setdefault(key, []).append(item)
        return len(self.doc[key]) - 1

    def view(self, data: bytes, target: int | None = None) -> int:
        """A buffer view over ``data`` (4-byte aligned)."""
        self.bin += b"\0" * (-len(self.bin) % 4)
        item = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target is not None:
            item["target"] = target
        self.bin += data
        return self._add("bufferViews", item)

    def accessor(self, arr: np.ndarray, ctype: int, atype: str, target: int | None = None,
                 bounds: bool = False) -> int:
        """An accessor over ``arr`` (count x components), stored as ``ctype``."""
        a = np.ascontiguousarray(arr, _DTYPE[ctype]).reshape(len(arr), -1)
        item = {"bufferView": self.view(a.tobytes(), target), "componentType": ctype,
                "count": len(a), "type": atype}
        if bounds:
            item["min"], item["max"] = _bounds(a, ctype)
        return self._add("accessors", item)

    def sparse_vec3(self, values: np.ndarray) -> int:
        """A float VEC3 accessor of ``values`` (n, 3) storing only its nonzero rows (none:
        an accessor of zeros without data)."""
        v = np.asarray(values, np.float32)
        rows = np.flatnonzero(np.any(v != 0, axis=1))
        item = {"componentType": FLOAT, "count": len(v), "type": "VEC3"}
        zero = np.zeros((1, 3), np.float32)  # the rows not stored are zeros
        full = v[rows] if len(rows) == len(v) else np.vstack([v[rows], zero])
        item["min"], item["max"] = _bounds(full, FLOAT)
        if len(rows):
            ityp = USHORT if len(v) < 65536 else UINT
            item["sparse"] = {
                "count": len(rows),
                "indices": {"bufferView": self.view(rows.astype(_DTYPE[ityp]).tobytes()),
                            "componentType": ityp},
                "values": {"bufferView": self.view(v[rows].tobytes())}}
        return self._add("accessors", item)

    def image(self, png: bytes, name: str) -> int:
        return self._add("images", {"bufferView": self.view(png), "mimeType": "image/png",
                                    "name": name})

    def texture(self, png: bytes, name: str) -> int:
        if "samplers" not in self.doc:
            self._add("samplers", {"magFilter": 9729, "minFilter": 9987, "wrapS": 33071,
                                   "wrapT": 33071})
        return self._add("textures", {"sampler": 0, "source": self.image(png, name)})

    def glb(self) -> bytes:
        """The binary container: header, JSON chunk, BIN chunk."""
        self.bin += b"\0" * (-len(self.bin) % 4)
        self.doc["buffers"] = [{"byteLength": len(self.bin)}]
        js = json.dumps(self.doc, separators=(",", ":")).encode()
        js += b" " * (-len(js) % 4)
        total = 12 + 8 + len(js) + 8 + len(self.bin)
        return b"".join([struct.pack("<III", 0x46546C67, 2, total),
                         struct.pack("<II", len(js), 0x4E4F534A), js,
                         struct.pack("<II", len(self.bin), 0x004E4942), bytes(self.bin)])

    def gltf(self, bin_name: str) -> tuple[str, bytes]:
        """JSON text naming ``bin_name`` as its buffer, and the buffer's bytes."""
        self.bin += b"\0" * (-len(self.bin) % 4)
        self.doc["buffers"] = [{"byteLength": len(self.bin), "uri": bin_name}]
        return json.dumps(self.doc, indent=1), bytes(self.bin)


def _bounds(a: np.ndarray, ctype: int) -> tuple[list, list]:
    lo, hi = a.min(0), a.max(0)
    cast = float if ctype == FLOAT else int
    return [cast(x) for x in lo], [cast(x) for x in hi]


@dataclass(frozen=True)
class Animation:
    """Per-frame values of a clip: times (T,) s; rotations (T, 9, 4) xyzw per node; root
    translation (T, 3); morph weights (T, K)."""

    times: np.ndarray
    rotations: np.ndarray
    root_translation: np.ndarray
    weights: np.ndarray


def png_bytes(img: np.ndarray, srgb: bool) -> bytes:
    """An 8-bit PNG of a [0, 1] float image (H, W[, C]), sRGB-encoded if ``srgb``."""

    img = np.clip(np.asarray(img, np.float64), 0.0, 1.0)
    if srgb:
        img = srgb_encode(img)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    buf = io.BytesIO()
    iio.imwrite(buf, np.round(img * 255).astype(np.uint8), extension=".png")
    return buf.getvalue()


def skin_material(g: GltfBuilder, maps) -> int:
    """The skin material from :class:`~hack_render.render.materials.SkinMaps` (linear
    albedo, specular intensity (scale of skin's F0), perceptual roughness, normals)."""
    rough = maps.roughness[..., 0]
    # one RGBA image: G roughness, B metallic (0), A specular intensity
    mrs = np.stack([np.zeros_like(rough), rough, np.zeros_like(rough), maps.specular[..., 0]], -1)
    mrs_tex = g.texture(png_bytes(mrs, False), "skin_roughness_specular")
    mat = {"name": "skin", "pbrMetallicRoughness": {
        "baseColorTexture": {"index": g.texture(png_bytes(maps.diffuse, True), "skin_albedo")},
        "metallicFactor": 0.0, "roughnessFactor": 1.0,
        "metallicRoughnessTexture": {"index": mrs_tex}},
        # F0 = ((ior - 1) / (ior + 1))^2 * specular = 0.028 * intensity, as the renderer's
        "extensions": {"KHR_materials_ior": {"ior": SKIN_IOR},
                       "KHR_materials_specular": {"specularFactor": 1.0,
                                                  "specularTexture": {"index": mrs_tex}}}}
    if maps.normal is not None:
        mat["normalTexture"] = {"index": g.texture(png_bytes(0.5 * maps.normal + 0.5, False),
                                                   "skin_normal")}
    return g._add("materials", mat)


def part_material(g: GltfBuilder, part: str, rgb, vertex_colours: bool = False) -> int:
    """A plain material for a non-skin part (colour from the renderer's BSDFs; white when
    the part's vertices carry its colours, ``COLOR_0``: the iris's pupil, iris and limbus,
    or a fit's bake, ``SkinMaps.part_rgb``)."""
    mat = {"name": part, "pbrMetallicRoughness": {
        "baseColorFactor": [*map(float, rgb), 1.0], "metallicFactor": 0.0,
        "roughnessFactor": PART_ROUGHNESS.get(part, 0.5)}}
    if vertex_colours:
        mat["pbrMetallicRoughness"]["baseColorFactor"] = [1.0, 1.0, 1.0, 1.0]
    if part in ("lacrimal", "eyelashes"):  # thin shells and cards, seen from both sides
        mat["doubleSided"] = True
    if part == "eyelashes":
        mat["pbrMetallicRoughness"]["baseColorFactor"][3] = EYELASH_OPACITY
        mat["alphaMode"] = "BLEND"
    return g._add("materials", mat)


@dataclass(frozen=True)
class Pose:
    """The default state of the file: rotations (9, 4) xyzw per node (root first), root
    translation (3,), morph weights (K,)."""

    rotations: np.ndarray
    root_translation: np.ndarray
    weights: np.ndarray


def _mat4_translation(p: np.ndarray) -> np.ndarray:
    """Column-major 4 x 4 translation matrices (n, 16) for offsets p (n, 3)."""
    m = np.tile(np.eye(4).reshape(1, 16), (len(p), 1))
    m[:, 12:15] = p
    return m


def person_document(model, rig, pose: Pose, maps=None, animation: Animation | None = None,
                    name: str = "hack_person", hair=None) -> GltfBuilder:
    """Assemble the glTF document of a rigged person (see the module docstring).

    Args:
        model: the geometry model (topology, materials, joint names).
        rig: :class:`~hack_render.export.rig.ExportRig` of the person.
        pose: the default state (the parameter file's pose).
        maps: skin maps (``render.materials.SkinMaps``) or None (a plain skin colour).
        animation: the clip, or None.
        hair: None, or (style, cards): the :class:`~hack_render.hair.style.HairStyle` and
            its :class:`~hack_render.export.hair_cards.CardGroup` list, written as one
            primitive per group (:func:`hair_primitive`).
    """
    g = GltfBuilder()
    parts, axes = split_parts(Topology.from_model(model), rig.base)
    normals = vertex_normals(rig.base, model.faces.numpy())
    iris_rgb = getattr(maps, "iris_rgb", None)  # a fit's texture folder: the person's
    sclera_rgb = getattr(maps, "sclera_rgb", None)
    part_rgb = getattr(maps, "part_rgb", None) or {}
    colours = material_base_colours(model.material_names, iris_rgb, sclera_rgb)
    part_colour = {"mouth": colours.get("M_GumsTongue"), "teeth": colours.get("M_Teeth"),
                   "sclera": colours.get("M_ScleraLeft"), "iris": colours.get("M_IrisLeft"),
                   "lacrimal": colours.get("M_LacrimalFluid"),
                   "eyelashes": colours.get("M_EyeLashes")}
    skin_mat = skin_material(g, maps) if maps is not None else g._add("materials", {
        "name": "skin", "pbrMetallicRoughness": {"baseColorFactor": [0.46, 0.29, 0.22, 1.0],
                                                 "metallicFactor": 0.0, "roughnessFactor": 0.5}})
    n_inf = rig.joints4.shape[1]
    prims = []
    if hair is not None and any(c.name == "lashes" for c in hair[1]):
        parts = [p for p in parts if p.name != "eyelashes"]  # the strands' cards replace them
    for part in parts:
        gi = part.gather
        attrs = {"POSITION": g.accessor(rig.base[gi], FLOAT, "VEC3", ARRAY_BUFFER, bounds=True),
                 "NORMAL": g.accessor(normals[gi], FLOAT, "VEC3", ARRAY_BUFFER),
                 "_HACK_VERTEX": g.accessor(gi.astype(np.float32), FLOAT, "SCALAR",
                                            ARRAY_BUFFER, bounds=True)}
        if part.name.startswith("skin"):  # the textured parts (atlas coordinates)
            attrs["TEXCOORD_0"] = g.accessor(part.texcoords, FLOAT, "VEC2", ARRAY_BUFFER)
        for s in range(n_inf // 4):
            attrs[f"JOINTS_{s}"] = g.accessor(rig.joints4[gi, 4 * s:4 * s + 4], UBYTE, "VEC4",
                                              ARRAY_BUFFER)
            attrs[f"WEIGHTS_{s}"] = g.accessor(rig.weights4[gi, 4 * s:4 * s + 4], FLOAT, "VEC4",
                                               ARRAY_BUFFER)
        baked = part_rgb.get(part.name)  # a fit's bake of the photo (linear RGB)
        if baked is not None and np.shape(baked) != (len(gi), 3):
            raise HackError(f"part colours {part.name!r}: expected one per vertex of the "
                            f"part, ({len(gi)}, 3), found {np.shape(baked)} (another "
                            "model's?).")
        if baked is not None:
            attrs["COLOR_0"] = g.accessor(np.asarray(baked, np.float32), FLOAT, "VEC3",
                                          ARRAY_BUFFER)
        elif part.name == "iris" and axes:
            attrs["COLOR_0"] = g.accessor(iris_vertex_colors(rig.base[gi], axes, iris_rgb,
                                                             sclera_rgb),
                                          FLOAT, "VEC3", ARRAY_BUFFER)
        ityp = USHORT if len(gi) < 65536 else UINT
        prim = {"attributes": attrs, "mode": 4,
                "indices": g.accessor(part.faces.reshape(-1, 1), ityp, "SCALAR",
                                      ELEMENT_ARRAY_BUFFER),
                "material": skin_mat if part.name.startswith("skin") else
                part_material(g, part.name, part_colour.get(part.name) or (0.5, 0.5, 0.5),
                              "COLOR_0" in attrs),
                "targets": [{"POSITION": g.sparse_vec3(t[gi])} for t in rig.targets]}
        prims.append(prim)
    if hair is not None:
        weights = model.skinning_weights.double().numpy()
        faces = model.faces.numpy()
        prims += [hair_primitive(g, cards, rig, faces, weights) for cards in hair[1]]
    g._add("meshes", {"name": name, "primitives": prims,
                      "weights": [float(w) for w in pose.weights],
                      "extras": {"targetNames": list(rig.target_names)}})
    _skeleton(g, rig, pose)
    mesh_node = g._add("nodes", {"name": name, "mesh": 0, "skin": 0})
    g.doc["scenes"] = [{"name": name, "nodes": [0, mesh_node]}]
    g.doc["scene"] = 0
    if animation is not None:
        _animation(g, animation, mesh_node)
    g.doc["extensionsUsed"] = sorted({k for m in g.doc["materials"]
                                      for k in m.get("extensions", {})})
    if not g.doc["extensionsUsed"]:
        del g.doc["extensionsUsed"]
    g.doc["asset"]["extras"] = {"hack": {
        "target_slots": {k: [s.start, s.stop] for k, s in rig.slots.items()},
        "larynx_slide_m": [float(t) for t in rig.tau_grid], "eta": rig.eta,
        "influences": n_inf, "weight_truncation_error_m": rig.weight_error_m,
        "joints": list(model.joint_names), "root": rig.node_names[0],
        "pose_targets": [[f, sg] for f, sg, _ in pose_split(model.num_joints)]
        if rig.slots["pose"].stop > rig.slots["pose"].start else [],
        # each joint's pose weights times g = s^2 / (s^2 + c^4), s = 3 - trace R, c this
        # angle in radians (geometry.lbs.pose_gate); null: ungated. pose_gate_chain = l:
        # s + l |n|^2, n the sum of the joints' axial vectors (R - R^T) / 2 (0: s alone)
        "pose_gate_deg": (None if rig.pose_gate_rad is None
                          else math.degrees(rig.pose_gate_rad)),
        "pose_gate_chain": rig.pose_gate_chain,
        # format 5: the flexion block's targets (slot "flex"), weights max(0, 1 - |phi_x -
        # knot| / width) exp(-(phi_y^2 + phi_z^2) / purity^2) c^coherence, phi the axis-angle
        # of the joints' net rotation (the product of their local rotations), c = |sum a_k| /
        # sum |a_k|, a_k the x of joint k's (R - R^T) / 2; null: none
        "flex": rig.flex,
        "joint_limits_deg": model.rotation_limits_deg.tolist(),
        "units": "metres, Y up, face along +Z"}}
    if hair is not None:
        g.doc["asset"]["extras"]["hack"]["hair"] = {
            "style": hair[0].to_dict(),
            "groups": {c.name: {"strands": c.strands, "cards": c.num_cards,
                                "vertices": len(c.positions)} for c in hair[1]},
            "cards": "alpha-textured ribbons, one per clump of strands, rooted on the skin; "
                     "each card column carries its root point's skin weights and morph "
                     "deltas (moves rigidly with the skin under it)",
            "texture": "procedural strand texture (hack-render), colour from melanin by an "
                       "approximate mapping; not a photograph or a render"}
    return g


def hair_primitive(g: GltfBuilder, cards, rig, faces: np.ndarray, weights: np.ndarray
                   ) -> dict:
    """One strand group's cards (:class:`~hack_render.export.hair_cards.CardGroup`) as a
    skinned primitive with every morph target of the mesh (the blend of the root
    triangle's deltas, sparse) and its alpha-masked, two-sided strand material."""
    n_inf = rig.joints4.shape[1]
    joints, w = cards.skin_weights(weights, faces, n_inf)
    attrs = {"POSITION": g.accessor(cards.positions, FLOAT, "VEC3", ARRAY_BUFFER, bounds=True),
             "NORMAL": g.accessor(cards.normals, FLOAT, "VEC3", ARRAY_BUFFER),
             "TEXCOORD_0": g.accessor(cards.uv, FLOAT, "VEC2", ARRAY_BUFFER)}
    for s in range(n_inf // 4):
        attrs[f"JOINTS_{s}"] = g.accessor(joints[:, 4 * s:4 * s + 4], UBYTE, "VEC4",
                                          ARRAY_BUFFER)
        attrs[f"WEIGHTS_{s}"] = g.accessor(w[:, 4 * s:4 * s + 4], FLOAT, "VEC4", ARRAY_BUFFER)
    ityp = USHORT if len(cards.positions) < 65536 else UINT
    return {"attributes": attrs, "mode": 4,
            "indices": g.accessor(cards.faces.reshape(-1, 1), ityp, "SCALAR",
                                  ELEMENT_ARRAY_BUFFER),
            "material": hair_material(g, cards),
            "targets": [{"POSITION": g.sparse_vec3(cards.morph(t, faces))}
                        for t in rig.targets],
            "extras": {"hair": cards.name, "cards": cards.num_cards,
                       "strands": cards.strands}}


def hair_material(g: GltfBuilder, cards) -> int:
    """The cards' material: the procedural strand texture (sRGB colour, linear alpha) as
    base colour, alpha MASK, two-sided."""
    tex = cards.texture
    rgba = np.concatenate([srgb_encode(np.clip(tex[..., :3], 0, 1)), tex[..., 3:]], -1)
    image = g.texture(png_bytes(rgba, False), f"hair_{cards.name}_strands_procedural")
    eu, pheo = (float(x) for x in cards.melanin)
    return g._add("materials", {
        "name": f"hair_{cards.name}",
        "pbrMetallicRoughness": {"baseColorTexture": {"index": image},
                                 "metallicFactor": 0.0, "roughnessFactor": HAIR_ROUGHNESS},
        "alphaMode": "MASK", "alphaCutoff": HAIR_ALPHA_CUTOFF, "doubleSided": True,
        "extras": {"hack": {"procedural": True, "mean_melanin": [eu, pheo],
                            "texture": "procedural strand texture; colour by an approximate "
                                       "melanin-to-RGB mapping (hack_render.export."
                                       "hair_cards.melanin_rgb)"}}})


def _skeleton(g: GltfBuilder, rig, pose: Pose) -> None:
    """Nodes 0..8 (root first) with the default pose, and the skin over them."""
    rest = rig.rest_nodes
    kids: dict[int, list[int]] = {}
    for i, p in enumerate(rig.parents):
        if p >= 0:
            kids.setdefault(p, []).append(i)
    for i, nm in enumerate(rig.node_names):
        p = rig.parents[i]
        t = rest[i] + pose.root_translation if p < 0 else rest[i] - rest[p]
        node = {"name": nm, "translation": [float(x) for x in t],
                "rotation": [float(x) for x in pose.rotations[i]]}
        if i in kids:
            node["children"] = kids[i]
        g._add("nodes", node)
    ibm = g.accessor(_mat4_translation(-rest), FLOAT, "MAT4")
    g._add("skins", {"name": "neck", "joints": list(range(len(rest))), "skeleton": 0,
                     "inverseBindMatrices": ibm})


def _animation(g: GltfBuilder, anim: Animation, mesh_node: int) -> None:
    times = g.accessor(anim.times.reshape(-1, 1), FLOAT, "SCALAR", bounds=True)
    samplers, channels = [], []

    def add(node: int, path: str, values: np.ndarray, atype: str) -> None:
        out = g.accessor(values.reshape(-1, _NCOMP[atype]), FLOAT, atype)
        samplers.append({"input": times, "output": out, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    for i in range(anim.rotations.shape[1]):
        add(i, "rotation", anim.rotations[:, i], "VEC4")
    add(0, "translation", anim.root_translation, "VEC3")
    add(mesh_node, "weights", anim.weights.reshape(-1, 1), "SCALAR")
    g._add("animations", {"name": "sequence", "samplers": samplers, "channels": channels})


def write_document(g: GltfBuilder, path: str | Path) -> list[Path]:
    """Write ``.glb`` (one file) or ``.gltf`` (+ ``.bin`` beside it), each under a
    temporary name renamed into place, the ``.bin`` first."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".glb", ".gltf"):
        raise HackError(f"-o {path}: expected a .glb or .gltf output, found "
                        f"{suffix or 'no suffix'}.")
    if suffix == ".glb":
        files = [(path, g.glb())]
    else:
        text, data = g.gltf(path.with_suffix(".bin").name)
        files = [(path.with_suffix(".bin"), data), (path, text.encode())]
    try:
        # every file written under its temporary name, then renamed in order (the .bin
        # before the .gltf that names it): the stack renames the last entered first
        with contextlib.ExitStack() as stack:
            tmps = [stack.enter_context(atomic_path(t)) for t, _ in reversed(files)][::-1]
            for tmp, (_, data) in zip(tmps, files, strict=True):
                tmp.write_bytes(data)
    except OSError as exc:
        raise HackError(f"-o {path}: cannot write ({exc.strerror or exc}). Choose a writable "
                        "output path.") from exc
    return [t for t, _ in files]
