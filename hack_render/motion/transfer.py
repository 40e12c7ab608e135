"""`hack-render transfer`: HACK motion (a parameter sequence) on another character.

Targets:

- a character in the model's topology (``.npz``, :mod:`.character`), or the procedural
  test character ``procedural:long-neck``: expressions, larynx and pose correctives by
  deformation transfer, the neck by its own joints with HACK's per-joint rotations;
  output: an animated glTF through the export's writer, a turntable, and the pose-space
  stress test's measures on every frame (``report.json``);
- a glTF character with any neck chain (:mod:`.retarget`): the neck's rotations retargeted
  onto its bones, the global pose onto its body's root; expressions and the larynx (size
  and slide) as morph targets, and the skin maps baked into its UV atlas (xatlas where it
  had none), both by closest-point transfer from HACK's surface laid onto it
  (:mod:`.surface_transfer`, derived); output: a copy of it with the animation added and
  a turntable (skinned per frame, ray cast, coloured by the baked diffuse).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
from tqdm import tqdm

from appearance.colour_space import srgb_decode
from hack_render.errors import HackError
from hack_render.export import rig as R
from hack_render.export.gltf import Animation, Pose, person_document, write_document
from hack_render.export.person import frames_from
from hack_render.export.reference import accessor
from hack_render.geometry.params import load_sequence, model_inputs
from hack_render.geometry.skeleton import JOINT_NAMES
from hack_render.io import atomic_path
from hack_render.io.image import to_srgb8
from hack_render.motion import retarget as RT
from hack_render.motion import surface_transfer as ST
from hack_render.motion.character import (
    character_rig,
    lbs_only,
    load_character,
    long_neck_character,
    pose_checks,
)
from hack_render.motion.retarget import posed_mesh, posed_primitives
from hack_render.render.mesh_views import MeshViews
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from hack_render.render.video import write_gif, write_mp4
from scenes import cameras as cams
from scenes import lights

PROCEDURAL = {"procedural:long-neck"}


def target_kind(target: str) -> str:
    """'procedural', 'character' (.npz) or 'gltf' (.glb/.gltf), else a HackError."""
    if target in PROCEDURAL:
        return "procedural"
    suffix = Path(target).suffix.lower()
    if suffix == ".npz":
        return "character"
    if suffix in (".glb", ".gltf"):
        return "gltf"
    raise HackError(f"--target {target}: expected a character .npz (the model's topology, "
                    f"with its neck joints), a .glb/.gltf with a neck chain, or one of "
                    f"{', '.join(sorted(PROCEDURAL))}; found {suffix or 'no suffix'}.")


def _summary(stats: dict, lbs: dict) -> dict:
    return {"frames": len(stats["stretch"]),
            "stretch_median": float(np.median(stats["stretch"])),
            "stretch_max": float(stats["stretch"].max()),
            "compression_max": float(stats["compression"].max()),
            "folded_frames": int((stats["folded"] > 0).sum()),
            "folded_triangles_max": int(stats["folded"].max()),
            "lbs_stretch_max": float(lbs["stretch"].max()),
            "lbs_folded_triangles_max": int(lbs["folded"].max()),
            "frames_folding_more_than_lbs": int((stats["folded"] > lbs["folded"]).sum())}


def transfer_topology(model, character, seq, params: dict, outdir: Path, *,
                      influences: int = 4, turntable: dict | None = None,
                      progress: bool = True, maps=None) -> dict:
    """A same-topology character: its rig, the animated glTF, the measures, the turntable.
    ``maps``: skin maps in the model's UV atlas (the character shares it), for both."""
    t0 = time.perf_counter()
    kw = model_inputs(model, params)
    eta = float(kw["eta"][0]) if "eta" in kw else 0.0
    frames = frames_from(kw, seq, model)
    tau_max = float(np.abs(frames["tau"]).max())
    tau_range = max(R.TAU_RANGE, np.ceil(tau_max / R.TAU_STEP - 1e-9) * R.TAU_STEP)
    if tau_range > 0.1:  # as the export: in-betweens cover the sequence's slides
        raise HackError(f"tau: a larynx slide of {tau_max:.3f} m is beyond the 0.1 m the "
                        "export covers; the model's slide is a few centimetres.")
    crig = character_rig(model, character, kw.get("beta"), eta, influences, float(tau_range))
    rig = crig.rig
    rot = R.axis_angle_quaternions(np.concatenate([frames["global_orient"][:, None],
                                                   frames["theta"]], 1))
    weights = R.frame_weights(rig, frames["psi"], frames["theta"], frames["tau"])
    anim = Animation(np.arange(seq.frames) / seq.fps, rot, rig.rest_nodes[0] + frames["transl"],
                     weights)
    pose = Pose(R.axis_angle_quaternions(np.zeros((9, 3))), np.zeros(3),
                np.zeros(len(rig.target_names)))
    doc = person_document(model, rig, pose, maps, anim, character.name)
    doc.doc["asset"]["extras"]["hack"]["character"] = character.meta
    files = write_document(doc, outdir / f"{character.name}.glb")
    stats = pose_checks(crig, model, frames["theta"], frames["psi"])
    lbs = pose_checks(lbs_only(crig), model, frames["theta"], frames["psi"])
    report = {"target": character.meta, "frames": seq.frames, "fps": seq.fps,
              "files": [str(f) for f in files], "weight_truncation_error_m": rig.weight_error_m,
              "deformation": _summary(stats, lbs)}
    if turntable:
        verts, _ = crig.pose(frames["psi"], frames["theta"], frames["tau"],
                             frames["global_orient"], frames["transl"])
        below = float(character.joints[0, 1]) - 0.04  # from just below c7-t1
        report["files"] += [str(p) for p in render_turntable(
            model, verts, outdir / "turntable", progress=progress, frame_above=below,
            maps=maps, **turntable)]
    report["seconds"] = round(time.perf_counter() - t0, 2)
    return report


def _orbit(folder: Path, frames: int, size: int, target: np.ndarray, extent: float,
           render, fps: int, formats: tuple, progress: bool) -> list[Path]:
    """The turntable loop shared by both kinds of character: frame i of ``frames`` with the
    camera at ``360 i / frames`` degrees about ``target``, ``render(i, camera)`` -> linear
    RGB (size, size, 3); PNG frames (each written under a temporary name), then videos."""

    images = []
    for i in tqdm(range(frames), desc="turntable", unit="frame", disable=not progress):
        cam = cams.orbit(size, size, 50.0, 360.0 * i / frames, 5.0, target=tuple(target),
                         extent=extent, name=f"frame_{i:04d}")
        img = to_srgb8(render(i, cam), 0.0, "aces")
        with atomic_path(folder / "frames" / f"frame_{i:04d}.png") as tmp:
            iio.imwrite(tmp, img, extension=".png")
        images.append(img)
    out = []
    if "mp4" in formats:
        out.append(write_mp4(folder / "turntable.mp4", images, fps))
    if "gif" in formats:
        out.append(write_gif(folder / "turntable.gif", images, fps))
    return out


def _framing(pts: np.ndarray) -> tuple[np.ndarray, float]:
    lo, hi = pts.min(0), pts.max(0)
    return 0.5 * (lo + hi), float((hi - lo).max())


def render_turntable(model, verts: np.ndarray, folder: Path, frames: int = 24, fps: int = 24,
                     resolution: int = 192, spp: int = 16, formats: tuple = ("mp4", "gif"),
                     variant: str | None = None, progress: bool = True,
                     frame_above: float | None = None, lighting: str = "overcast_sun",
                     maps=None) -> list[Path]:
    """An orbiting turntable of a posed character (verts (T, N, 3), the model's topology):
    frame i of ``frames`` shows motion frame ``i T / frames``, the camera at ``360 i /
    frames`` degrees, framed on the vertices above height ``frame_above`` (the neck and
    head; default: all) over the motion. Lit by an environment (``lighting``): the studio's
    soft boxes stand around a human head and would be in view of a taller character."""
    w = int(resolution) + int(resolution) % 2
    pts = verts.reshape(-1, 3)
    if frame_above is not None and (pts[:, 1] > frame_above).any():
        pts = pts[pts[:, 1] > frame_above]
    target, extent = _framing(pts)
    pick = (np.arange(frames) * len(verts)) // frames
    head = None

    def render(i, cam):
        nonlocal head
        if head is None:
            head = HeadScene(Topology.from_model(model), verts[pick[0]], lights.preset(lighting),
                             cam, RenderSettings(w, w, spp, 8, 0), maps, None, variant)
        head.set_vertices(verts[pick[i]])
        head.set_camera(cam)
        return head.render(seed=i)[..., :3]

    return _orbit(folder, frames, w, target, extent, render, fps, formats, progress)


def prepare_gltf(model, path: Path, chain: list[str] | None = None,
                 name_map: dict | None = None):
    """Load a glTF character and map HACK's joints onto its neck (every check before any
    output is written): (character, bones, assignment)."""
    import torch

    ch = RT.load_gltf_character(path)
    with torch.no_grad():
        hack_joints = model(beta=torch.zeros(1, 0, dtype=model.template.dtype)).rest_joints[0]
    bones, assign = RT.joint_map(ch, hack_joints.double().numpy(), chain, name_map)
    RT.body_root(ch, bones)  # its checks too
    return ch, bones, assign


def render_gltf_turntable(ch, bones: list[int], quats: np.ndarray, folder: Path,
                          frames: int = 24, fps: int = 24, resolution: int = 192,
                          spp: int = 16, formats: tuple = ("mp4", "gif"),
                          variant: str | None = None, progress: bool = True,
                          tracks: dict | None = None, morph: dict | None = None,
                          colours=None) -> list[Path]:
    """An orbiting turntable of a glTF character under its retargeted animation: skinned
    per frame (:func:`retarget.posed_mesh`; ``tracks`` and ``morph`` (mesh index -> (T, K)
    weights) as the animation's), ray cast (the render layer's ``MeshViews``) and shaded
    with ``colours`` (V,) linear RGB per vertex (the baked diffuse) or grey; ``spp`` as
    supersampling (its square root per side)."""
    w = int(resolution) + int(resolution) % 2
    pick = (np.arange(frames) * len(quats)) // frames
    posed = [posed_mesh(ch, bones, quats[k],
                        {n: {p: v[k] for p, v in tr.items()} for n, tr in (tracks or {}).items()},
                        {m: wt[k] for m, wt in (morph or {}).items()}) for k in pick]
    target, extent = _framing(np.concatenate([v for v, _ in posed]))
    ss = max(1, round(spp ** 0.5))

    def render(i, cam):
        rgba = MeshViews(*posed[i], colours, w, w, variant).render(cam, ss)
        return rgba[..., :3] + (1 - rgba[..., 3:]) * 0.18  # grey backdrop

    return _orbit(folder, frames, w, target, extent, render, fps, formats, progress)


def _rest_primitives(ch) -> list:
    return list(posed_primitives(ch))


def bake_onto_gltf(model, ch, rig, bones: list[int], prims: list[tuple[int, int]], maps,
                   size: int) -> tuple[dict, dict[int, int], slice]:
    """HACK's surface onto a glTF character (:mod:`.surface_transfer`): the maps baked into
    the atlas of primitives ``prims`` ((mesh, primitive) pairs), the person's expression
    and larynx targets as morph targets of every skinned mesh they reach; ``ch`` is
    changed in place. Returns a report, the index of each moved mesh's first HACK target
    and the rig's target slice they are."""
    t0 = time.process_time()
    rest = _rest_primitives(ch)
    head = RT.descendants(ch, bones[-1])
    head_pts = np.concatenate([p.vertices[np.isin(p.dominant, list(head))] for p in rest])
    surface = ST.hack_surface(model, rig, ch.world[bones, :3, 3], head_pts)
    report = {"alignment": surface.info, "maps": {}, "morph_targets": {},
              "cpu_seconds": {"align": round(time.process_time() - t0, 2)}}
    t0 = time.process_time()
    for p in rest:
        prim = ch.doc["meshes"][p.mesh]["primitives"][p.prim]
        if maps is not None and (p.mesh, p.prim) in prims:
            uv = accessor(ch.doc, ch.buf, prim["attributes"]["TEXCOORD_0"])
            baked, stats = ST.bake_maps(surface, maps, p.vertices, p.faces, uv, size)
            RT.add_baked_material(ch, prim, SimpleNamespace(**baked),
                                  f"hack_skin_baked_{p.mesh}_{p.prim}")
            report["maps"][f"mesh {p.mesh} primitive {p.prim}"] = stats
    report["cpu_seconds"]["bake"] = round(time.process_time() - t0, 2)
    t0 = time.process_time()
    keep = slice(0, rig.slots["larynx_slide"].stop)  # expressions, larynx size and slide
    moved: dict[int, dict[int, np.ndarray]] = {}
    for p in rest:
        if "skin" not in ch.doc["nodes"][p.node] or p.mesh in moved and p.prim in moved[p.mesh]:
            continue
        d, _ = ST.transfer_displacements(surface, rig.targets[keep], p.vertices)
        if np.any(d != 0):  # world displacements at rest -> the mesh's own frame
            lin = np.where(np.abs(np.linalg.det(p.linear))[:, None, None] > 1e-12, p.linear,
                           np.eye(3))
            d = np.einsum("vab,kvb->kva", np.linalg.inv(lin), d).astype(np.float32)
            moved.setdefault(p.mesh, {})[p.prim] = d
    first = {}
    names = [f"hack_{n}" for n in rig.target_names[keep]]
    for mesh, per_prim in moved.items():
        first[mesh] = RT.add_morph_targets(ch, mesh, per_prim, names)
        jaw = names.index("hack_jawOpen") if "hack_jawOpen" in names else 0
        report["morph_targets"][f"mesh {mesh}"] = {
            "targets": len(names), "first": first[mesh],
            "vertices_moved": int(sum(np.any(t != 0, axis=(0, 2)).sum()
                                      for t in per_prim.values())),
            "jawOpen_max_mm": round(1e3 * max(float(np.linalg.norm(t[jaw], axis=1).max())
                                              for t in per_prim.values()), 2)}
    report["cpu_seconds"]["morph_targets"] = round(time.process_time() - t0, 2)
    return report, first, keep


def transfer_gltf(model, ch, bones: list[int], assign: list[int], seq, outdir: Path,
                  by_name: bool, params: dict | None = None, maps=None, bake_size: int = 1024,
                  turntable: dict | None = None, progress: bool = True) -> dict:
    """A glTF character: HACK's global pose on its body's root, the neck's rotations on
    its chain, expressions and larynx as morph targets, the maps baked into its atlas (a
    UV atlas added where a primitive had none); written as a copy with the animation
    added, and a turntable."""
    t0 = time.perf_counter()
    kw = model_inputs(model, params or {})
    eta = float(kw["eta"][0]) if "eta" in kw else 1.0
    fr = frames_from(kw, seq, model)
    tau_max = float(np.abs(fr["tau"]).max())
    rig = R.build_rig(model, kw.get("beta"), eta,
                      max(R.TAU_RANGE, np.ceil(tau_max / R.TAU_STEP - 1e-9) * R.TAU_STEP))
    atlas = RT.add_uv_atlas(ch, bake_size)
    baked, first, keep = bake_onto_gltf(model, ch, rig, bones, atlas, maps, bake_size)
    root = RT.body_root(ch, bones)
    tracks = RT.root_tracks(ch, root, fr["global_orient"], fr["transl"])
    if root == bones[0]:  # the chain starts at the root: it turns the first bone
        quats = RT.retarget(ch, bones, assign, fr["theta"], fr["global_orient"])
        tracks = {root: {"translation": tracks["translation"]}}
    else:
        quats = RT.retarget(ch, bones, assign, fr["theta"])
        tracks = {root: tracks}
    fw = R.frame_weights(rig, fr["psi"], fr["theta"], fr["tau"])[:, keep]
    fw[:, rig.slots["larynx_size"]] = rig.eta  # the person's larynx size, held
    morph, node_weights = {}, {}
    for mesh, k0 in first.items():
        default = np.asarray(ch.doc["meshes"][mesh]["weights"][:k0], np.float64)
        morph[mesh] = np.concatenate([np.broadcast_to(default, (len(fw), k0)), fw], 1)
        for n, node in enumerate(ch.doc["nodes"]):
            if node.get("mesh") == mesh:
                node_weights[n] = morph[mesh]
    mapping = {j: ch.names[bones[b]] for j, b in zip(JOINT_NAMES, assign, strict=True)}
    prov = {"source": str(ch.path), "mapping": mapping,
            "method": "name map" if by_name else "arc length along the neck chain",
            "global_pose": f"global_orient and transl on {ch.names[root]!r} (the body's root)",
            "uv_atlas_primitives": len(atlas), "derived": {
                "maps": "HACK's skin maps baked onto the character's atlas by closest-point "
                        "transfer from the aligned HACK surface: derived, not painted",
                "morph_targets": "the person's expression and larynx targets moved onto the "
                                 "character by closest-point transfer (faded out away from "
                                 "HACK's skin): derived, not sculpted"},
            "dropped": "pose correctives (HACK's skinning, not the character's)", **baked}
    files = RT.write_animated(ch, bones, quats, seq.fps, outdir / f"{ch.path.stem}_hack.glb",
                              prov, tracks, node_weights)
    if turntable:
        files += render_gltf_turntable(ch, bones, quats, outdir / "turntable",
                                       progress=progress, tracks=tracks, morph=morph,
                                       colours=_vertex_colours(ch, maps), **turntable)
    return {"target": prov, "frames": seq.frames, "fps": seq.fps,
            "files": [str(f) for f in files], "seconds": round(time.perf_counter() - t0, 2)}


def _vertex_colours(ch, maps) -> np.ndarray | None:
    """Linear RGB per vertex of :func:`retarget.posed_mesh` from the baked base colour
    textures (nearest texel at each vertex's UV), grey where a primitive has none."""

    if maps is None:
        return None
    out = []
    for p in _rest_primitives(ch):
        prim = ch.doc["meshes"][p.mesh]["primitives"][p.prim]
        mat = ch.doc.get("materials", [{}])[prim["material"]] if "material" in prim else {}
        tex = mat.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        col = np.full((len(p.vertices), 3), 0.6)
        if tex is not None and "TEXCOORD_0" in prim["attributes"] and \
                mat.get("name", "").startswith("hack_skin_baked"):
            img_i = ch.doc["textures"][tex["index"]]["source"]
            bv = ch.doc["bufferViews"][ch.doc["images"][img_i]["bufferView"]]
            o = bv.get("byteOffset", 0)
            img = srgb_decode(iio.imread(ch.buf[o:o + bv["byteLength"]]) / 255.0)
            uv = accessor(ch.doc, ch.buf, prim["attributes"]["TEXCOORD_0"])
            s = img.shape[0]
            col = img[np.clip((uv[:, 1] * s).astype(int), 0, s - 1),
                      np.clip((uv[:, 0] * s).astype(int), 0, s - 1), :3]
        out.append(col)
    return np.concatenate(out)


def run_transfer(model, motion: Path, target: str, outdir: Path, params: dict | None = None,
                 chain: list[str] | None = None, name_map: dict | None = None,
                 influences: int = 4, turntable: dict | None = None,
                 progress: bool = True, maps=None, bake_size: int = 1024) -> dict:
    """Check every input, then transfer and write ``report.json`` beside the outputs (the
    output folder is created only once the inputs are known good). ``maps``: the skin maps
    (the model's atlas) shown by a same-topology character, or baked into a glTF
    character's atlas at ``bake_size`` texels."""
    kind = target_kind(target)
    seq = load_sequence(motion, model.num_expressions)
    if kind == "gltf":
        ch, bones, assign = prepare_gltf(model, Path(target), chain, name_map)
        outdir.mkdir(parents=True, exist_ok=True)
        report = transfer_gltf(model, ch, bones, assign, seq, outdir, bool(name_map), params,
                               maps, bake_size, turntable, progress)
    else:
        if chain or name_map:
            raise HackError("--neck-chain and --name-map apply to glTF targets; a character "
                            "in the model's topology carries its 8 neck joints.")
        character = (long_neck_character(model) if kind == "procedural"
                     else load_character(target, model))
        if seq.tau is not None and np.abs(seq.tau).max() > 0.1:
            raise HackError(f"{motion}: key 'tau': a larynx slide of "
                            f"{np.abs(seq.tau).max():.3f} m; expected at most 0.1 m (the "
                            "model's slide is a few centimetres).")
        outdir.mkdir(parents=True, exist_ok=True)
        report = transfer_topology(model, character, seq, params or {}, outdir,
                                   influences=influences, turntable=turntable,
                                   progress=progress, maps=maps)
    report["motion"] = str(motion)
    path = outdir / "report.json"
    path.write_text(json.dumps(report, indent=2))
    report["files"].append(str(path))
    return report
