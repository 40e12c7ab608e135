"""From a parameter file (and a parameter sequence) to a rigged glTF person: the driver
behind `hack-render export`, kept apart from the CLI so tests and scripts can call it."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.export import rig as R
from hack_render.export.gltf import Animation, Pose, person_document, write_document
from hack_render.export.hair_cards import build_cards, groom_for
from hack_render.geometry.params import model_inputs
from hack_render.hair.style import HairStyle


def _pose_arrays(rig, theta, psi, global_orient, transl, tau):
    """Node rotations (T, 9, 4), root translations (T, 3) and morph weights (T, K)."""
    rot = R.axis_angle_quaternions(np.concatenate([global_orient[:, None], theta], 1))
    return rot, rig.rest_nodes[0] + transl, R.frame_weights(rig, psi, theta, tau)


def frames_from(kw: dict, seq, model) -> dict[str, np.ndarray]:
    """Per-frame arrays: the sequence's, or the parameter file's values where it has none."""
    t = 1 if seq is None else seq.frames
    out = {}
    for key, shape in (("theta", (8, 3)), ("psi", (model.num_expressions,)), ("tau", ()),
                       ("global_orient", (3,)), ("transl", (3,))):
        val = getattr(seq, key, None) if seq is not None else None
        if val is None:
            base = kw.get(key)
            base = np.zeros(shape) if base is None else base[0].double().numpy()
            val = np.broadcast_to(base, (t,) + shape)
        out[key] = np.asarray(val, np.float64)
    if seq is not None and seq.psi is not None and seq.psi.shape[1] != model.num_expressions:
        raise HackError(f"sequence: frame 0, key 'psi': expected {model.num_expressions} values "
                        f"(the model's expressions), found {seq.psi.shape[1]}.")
    return out


def export_person(model, params: dict, output: str | Path, sequence=None, maps=None,
                  influences: int = R.INFLUENCES, hair: HairStyle | None = None) -> dict:
    """Write a rigged glTF of one person; returns a report (sizes, timings, errors).

    Args:
        model: the geometry model.
        params: a checked parameter mapping (``geometry.params.check_params``): identity,
            larynx size and the default pose.
        output: ``.glb`` or ``.gltf`` path.
        sequence: a :class:`~hack_render.geometry.params.ParamSequence` or None.
        maps: skin maps or None.
        influences: skin weights per vertex, 4 or 8.
        hair: a style to add as hair cards (:mod:`.hair_cards`), or None: the parameter
            mapping's ``hair`` section if it has one, else no hair.
    """
    t0 = time.perf_counter()
    kw = model_inputs(model, params)
    frames = frames_from(kw, sequence, model)
    default = frames_from(kw, None, model)
    tau_max = max(np.abs(frames["tau"]).max(), np.abs(default["tau"]).max())
    tau_range = max(R.TAU_RANGE, math.ceil(tau_max / R.TAU_STEP - 1e-9) * R.TAU_STEP)
    if tau_range > 0.1:
        raise HackError(f"tau: a larynx slide of {tau_max:.3f} m is beyond the 0.1 m the "
                        "export covers; the model's slide is a few centimetres.")
    eta = float(kw["eta"][0]) if "eta" in kw else 0.0
    rig = R.build_rig(model, kw.get("beta"), eta, tau_range, R.TAU_STEP, influences)
    rot, trans, weights = _pose_arrays(rig, **default)
    pose = Pose(rot[0], trans[0] - rig.rest_nodes[0], weights[0])
    anim = None
    if sequence is not None:
        rot, trans, weights = _pose_arrays(rig, **frames)
        anim = Animation(np.arange(sequence.frames) / sequence.fps, rot, trans, weights)
    if hair is None and params.get("hair") is not None:
        hair = HairStyle.from_dict(params["hair"])
    cards = None
    if hair is not None:
        t1 = time.perf_counter()
        cards = build_cards(groom_for(model, hair), rig.base, model.faces.numpy(), hair.seed)
        hair_seconds = time.perf_counter() - t1
    doc = person_document(model, rig, pose, maps, anim, Path(output).stem,
                          None if cards is None else (hair, cards))
    written = write_document(doc, output)
    return {"files": [str(p) for p in written],
            "bytes": sum(p.stat().st_size for p in written),
            "seconds": time.perf_counter() - t0, "targets": len(rig.target_names),
            "frames": 0 if sequence is None else sequence.frames,
            "influences": influences, "weight_truncation_error_m": rig.weight_error_m,
            "larynx_slide_range_m": tau_range,
            "hair": None if cards is None else {
                "groups": {c.name: {"strands": c.strands, "cards": c.num_cards,
                                    "vertices": len(c.positions), "triangles": len(c.faces)}
                           for c in cards},
                "seconds": hair_seconds}}
