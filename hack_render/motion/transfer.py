"""`hack-render transfer`: HACK motion (a parameter sequence) on another character.

Targets:

- a character in the model's topology (``.npz``, :mod:`.character`), or the procedural
  test character ``procedural:long-neck``: expressions, larynx and pose correctives by
  deformation transfer, the neck by its own joints with HACK's per-joint rotations;
  output: an animated glTF through the export's writer, a turntable, and the pose-space
  stress test's measures on every frame (``report.json``);
- a glTF character with any neck chain (:mod:`.retarget`): the neck's rotations retargeted
  onto its bones; output: a copy of it with the animation added (and a UV atlas where it
  had none) and a turntable (skinned per frame, ray cast, grey). Expressions need the
  model's topology and are not transferred to it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from hack_render.errors import HackError

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
    from hack_render.export import rig as R
    from hack_render.export.gltf import Animation, Pose, person_document, write_document
    from hack_render.export.person import _frames_from
    from hack_render.geometry.params import model_inputs
    from hack_render.motion.character import character_rig, lbs_only, pose_checks

    t0 = time.perf_counter()
    kw = model_inputs(model, params)
    eta = float(kw["eta"][0]) if "eta" in kw else 0.0
    frames = _frames_from(kw, seq, model)
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
    import imageio.v3 as iio
    from tqdm import tqdm

    from hack_render.render.image_io import atomic_path, to_srgb8
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.video import write_gif, write_mp4
    from scenes import cameras as cams
    from scenes import lights

    w = h = int(resolution) + int(resolution) % 2
    settings = RenderSettings(w, h, spp, 8, 0)
    pts = verts.reshape(-1, 3)
    if frame_above is not None and (pts[:, 1] > frame_above).any():
        pts = pts[pts[:, 1] > frame_above]
    lo, hi = pts.min(0), pts.max(0)
    target, extent = 0.5 * (lo + hi), float((hi - lo).max())
    pick = (np.arange(frames) * len(verts)) // frames

    def cam(i: int):
        return cams.orbit(w, h, 50.0, 360.0 * i / frames, 5.0, target=tuple(target),
                          extent=extent, name=f"frame_{i:04d}")

    head = HeadScene(Topology.from_model(model), verts[pick[0]], lights.preset(lighting), cam(0),
                     settings, maps, None, variant)
    images = []
    for i in tqdm(range(frames), desc="turntable", unit="frame", disable=not progress):
        head.set_vertices(verts[pick[i]])
        head.set_camera(cam(i))
        img = to_srgb8(head.render(seed=i)[..., :3], 0.0, "aces")
        with atomic_path(folder / "frames" / f"frame_{i:04d}.png") as tmp:
            iio.imwrite(tmp, img, extension=".png")
        images.append(img)
    out = []
    if "mp4" in formats:
        out.append(write_mp4(folder / "turntable.mp4", images, fps))
    if "gif" in formats:
        out.append(write_gif(folder / "turntable.gif", images, fps))
    return out


def prepare_gltf(model, path: Path, chain: list[str] | None = None,
                 name_map: dict | None = None):
    """Load a glTF character and map HACK's joints onto its neck (every check before any
    output is written): (character, bones, assignment)."""
    import torch

    from hack_render.motion import retarget as RT

    ch = RT.load_gltf_character(path)
    with torch.no_grad():
        hack_joints = model(beta=torch.zeros(1, 0, dtype=model.template.dtype)).rest_joints[0]
    bones, assign = RT.joint_map(ch, hack_joints.double().numpy(), chain, name_map)
    return ch, bones, assign


def render_gltf_turntable(ch, bones: list[int], quats: np.ndarray, folder: Path,
                          frames: int = 24, fps: int = 24, resolution: int = 192,
                          spp: int = 16, formats: tuple = ("mp4", "gif"),
                          variant: str | None = None, progress: bool = True) -> list[Path]:
    """An orbiting turntable of a glTF character under its retargeted animation: skinned
    per frame (:func:`retarget.posed_mesh`), ray cast and shaded grey (the render layer's
    ``MeshViews``; its materials are not read), ``spp`` as supersampling (its square root
    per side)."""
    import imageio.v3 as iio
    from tqdm import tqdm

    from hack_render.motion.retarget import posed_mesh
    from hack_render.render.image_io import atomic_path, to_srgb8
    from hack_render.render.mesh_views import MeshViews
    from hack_render.render.video import write_gif, write_mp4
    from scenes import cameras as cams

    w = h = int(resolution) + int(resolution) % 2
    pick = (np.arange(frames) * len(quats)) // frames
    posed = [posed_mesh(ch, bones, quats[k]) for k in pick]
    pts = np.concatenate([v for v, _ in posed])
    lo, hi = pts.min(0), pts.max(0)
    target, extent = 0.5 * (lo + hi), float((hi - lo).max())
    ss = max(1, round(spp ** 0.5))
    images = []
    for i in tqdm(range(frames), desc="turntable", unit="frame", disable=not progress):
        cam = cams.orbit(w, h, 50.0, 360.0 * i / frames, 5.0, target=tuple(target),
                         extent=extent, name=f"frame_{i:04d}")
        rgba = MeshViews(*posed[i], None, w, h, variant).render(cam, ss)
        rgb = rgba[..., :3] + (1 - rgba[..., 3:]) * 0.18  # grey backdrop
        img = to_srgb8(rgb, 0.0, "aces")
        with atomic_path(folder / "frames" / f"frame_{i:04d}.png") as tmp:
            iio.imwrite(tmp, img, extension=".png")
        images.append(img)
    out = []
    if "mp4" in formats:
        out.append(write_mp4(folder / "turntable.mp4", images, fps))
    if "gif" in formats:
        out.append(write_gif(folder / "turntable.gif", images, fps))
    return out


def transfer_gltf(ch, bones: list[int], assign: list[int], seq, outdir: Path,
                  by_name: bool, turntable: dict | None = None, progress: bool = True) -> dict:
    """A glTF character: the neck's rotations retargeted onto its chain, written as a copy
    with the animation added (and a UV atlas where a primitive had none), and a turntable."""
    from hack_render.geometry.skeleton import JOINT_NAMES
    from hack_render.motion import retarget as RT

    t0 = time.perf_counter()
    quats = RT.retarget(ch, bones, assign, seq.theta)
    atlas = RT.add_uv_atlas(ch)
    mapping = {j: ch.names[bones[b]] for j, b in zip(JOINT_NAMES, assign, strict=True)}
    prov = {"source": str(ch.path), "mapping": mapping,
            "method": "name map" if by_name else "arc length along the neck chain",
            "dropped": "expressions, larynx, global_orient and transl (they need the model's "
                       "topology or a body root)", "uv_atlas_primitives": atlas}
    files = RT.write_animated(ch, bones, quats, seq.fps, outdir / f"{ch.path.stem}_hack.glb",
                              prov)
    if turntable:
        files += render_gltf_turntable(ch, bones, quats, outdir / "turntable",
                                       progress=progress, **turntable)
    return {"target": prov, "frames": seq.frames, "fps": seq.fps,
            "files": [str(f) for f in files], "seconds": round(time.perf_counter() - t0, 2)}


def run_transfer(model, motion: Path, target: str, outdir: Path, params: dict | None = None,
                 chain: list[str] | None = None, name_map: dict | None = None,
                 influences: int = 4, turntable: dict | None = None,
                 progress: bool = True, maps=None) -> dict:
    """Check every input, then transfer and write ``report.json`` beside the outputs (the
    output folder is created only once the inputs are known good)."""
    from hack_render.geometry.params import load_sequence
    from hack_render.motion.character import load_character, long_neck_character

    kind = target_kind(target)
    seq = load_sequence(motion, model.num_expressions)
    if kind == "gltf":
        ch, bones, assign = prepare_gltf(model, Path(target), chain, name_map)
        outdir.mkdir(parents=True, exist_ok=True)
        report = transfer_gltf(ch, bones, assign, seq, outdir, bool(name_map), turntable,
                               progress)
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
