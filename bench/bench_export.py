"""Export figures (issue 23): file size, export time, the Khronos validator's verdict, the
skin-weight truncation error, and how closely the file (read by the reference evaluator and,
when a Python with bpy is given, by Blender) poses like the model's forward pass.

    python bench/bench_export.py [--blender-python /path/to/python-with-bpy]
    python bench/bench_export.py --hair      # the hair cards' figures (issue 61)

Writes bench/results/export.json, or with --hair export_hair.json (bench/provenance.py's
fields). The person: beta
(0.8, -1.2, 0.5), AU12 0.6 + jawOpen 0.25, eta 1.3, skin maps A(0); the animation: the
turntable's look-around + swallow, 48 frames at 24 fps, with random expressions.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import write_result  # noqa: E402

from hack_render.export import rig as R  # noqa: E402
from hack_render.export.hair_cards import blend, build_cards, groom_for  # noqa: E402
from hack_render.export.person import export_person  # noqa: E402
from hack_render.export.reference import evaluate, evaluate_primitives, read_gltf  # noqa: E402
from hack_render.geometry import load_default_model  # noqa: E402
from hack_render.geometry.params import (  # noqa: E402
    ParamSequence,
    check_params,
    model_inputs,
    save_sequence,
)
from hack_render.hair.style import HairStyle  # noqa: E402
from hack_render.render import turntable as tt  # noqa: E402
from hack_render.render.skin_maps import skin_maps  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PARAMS = {"beta": [0.8, -1.2, 0.5], "expression": "AU12=0.6,jawOpen=0.25", "eta": 1.3}


def forward_frames(model, seq) -> np.ndarray:
    kw = model_inputs(model, check_params(PARAMS))
    t = seq.frames
    kw = {k: v.expand(t, *v.shape[1:]) for k, v in kw.items()}
    kw.update(theta=torch.as_tensor(seq.theta, dtype=torch.float32),
              psi=torch.as_tensor(seq.psi, dtype=torch.float32),
              tau=torch.as_tensor(seq.tau, dtype=torch.float32))
    with torch.no_grad():
        return model(**kw).vertices.double().numpy()


def validator(files: list[Path]) -> list[dict] | str:
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        return "node not installed"
    root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True,
                          check=False).stdout.strip()
    r = subprocess.run([node, str(ROOT / "tests" / "gltf_validate.js"), *map(str, files)],
                       capture_output=True, text=True, check=False, env={"NODE_PATH": root})
    if r.returncode:
        return f"validator failed: {r.stderr[-300:]}"
    return [json.loads(line) for line in r.stdout.splitlines()]


#: The hair figures' styles (``--hair``): a short cut with a full beard, long hair.
HAIR_STYLES = {"short_full_beard": {"archetype": "short", "beard": "full"},
               "long": {"archetype": "long", "color": "brown"}}


def hair_figures(model, seq, maps, out: str) -> None:
    """Hair cards (issue 61): per style at lod 1, the cards and vertices per group, the file
    size against the same file without hair, the time to grow and build the cards, how far
    a card's root row strays from the posed skin over the 48 frames (reference evaluator),
    and the validator's verdict."""
    faces = model.faces.numpy()
    res: dict = {"person": PARAMS, "frames": seq.frames, "influences": 4, "styles": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base = export_person(model, check_params(PARAMS), tmp / "bald.glb", seq, maps, 4)
        res["bald"] = {"bytes": base["bytes"], "export_seconds": base["seconds"]}
        files = [tmp / "bald.glb"]
        for name, spec in HAIR_STYLES.items():
            style = HairStyle.from_dict(spec)
            glb = tmp / f"{name}.glb"
            rep = export_person(model, check_params(PARAMS), glb, seq, maps, 4, style)
            files.append(glb)
            rig = R.build_rig(model, torch.tensor([PARAMS["beta"]]), PARAMS["eta"])
            cards = build_cards(groom_for(model, style), rig.base, faces, style.seed)
            hair_prims = [i for i, p in enumerate(read_gltf(glb)[0]["meshes"][0]["primitives"])
                          if "hair" in p.get("extras", {})]
            worst = 0.0
            for k in range(seq.frames):
                skin = evaluate(glb, k, model.num_vertices)
                posed = evaluate_primitives(glb, k)
                for i, c in zip(hair_prims, cards, strict=True):
                    want = blend(skin, faces, c.tri[c.root], c.bary[c.root])
                    worst = max(worst, float(np.linalg.norm(posed[i][c.root] - want,
                                                            axis=1).max()))
            res["styles"][name] = {
                "style": spec, "groups": rep["hair"]["groups"], "bytes": rep["bytes"],
                "bytes_over_bald": rep["bytes"] - base["bytes"],
                "hair_seconds": rep["hair"]["seconds"], "export_seconds": rep["seconds"],
                "root_row_max_distance_to_posed_skin_mm_over_frames": 1e3 * worst}
        v = validator(files)
        res["validator"] = v if isinstance(v, str) else [
            {k: r[k] for k in ("errors", "warnings", "infos")} | {"file": Path(r["file"]).name}
            for r in v]
    print(json.dumps(res, indent=1))
    write_result(out, res)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blender-python", default=None, help="a Python with bpy installed")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "export.json"))
    ap.add_argument("--hair", action="store_true", help="the hair cards' figures only "
                    "(bench/results/export_hair.json)")
    args = ap.parse_args()
    model = load_default_model()
    look = tt.motion_sequence(tt.TurntableSpec(48, look_around=True, swallow=True, fps=24))
    psi = np.clip(np.random.default_rng(0).normal(0.15, 0.2, (48, model.num_expressions)), 0, 1)
    seq = ParamSequence(24.0, look.theta, psi, look.tau)
    maps = skin_maps([0.0])
    if args.hair:
        out = args.out if args.out != ap.get_default("out") else \
            str(ROOT / "bench" / "results" / "export_hair.json")
        hair_figures(model, seq, maps, out)
        return
    want = forward_frames(model, seq)
    res: dict = {"person": PARAMS, "frames": 48}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for inf in (4, 8):
            glb = tmp / f"person{inf}.glb"
            secs = [export_person(model, check_params(PARAMS), glb, seq, maps, inf)["seconds"]
                    for _ in range(3)]
            rep = export_person(model, check_params(PARAMS), glb, seq, maps, inf)
            err = []
            for k in range(48):
                got = evaluate(glb, k, model.num_vertices)
                used = ~np.isnan(got[:, 0])
                err.append(float(np.linalg.norm(got[used] - want[k][used], axis=1).max()))
            res[f"influences_{inf}"] = {
                "bytes": rep["bytes"], "targets": rep["targets"],
                "export_seconds_median_of_3": statistics.median(secs),
                "weight_truncation_error_at_limits_mm": 1e3 * rep["weight_truncation_error_m"],
                "reference_evaluator_max_error_mm_over_48_frames": 1e3 * max(err),
                "vertices_in_file": int(used.sum()), "model_vertices": model.num_vertices}
            if args.blender_python:
                b = []
                for k in (6, 12, 24, 36):
                    out = tmp / f"b{k}.npz"
                    subprocess.run([args.blender_python, str(ROOT / "tests" / "blender_eval.py"),
                                    str(glb), "24", str(k), str(out)], check=True,
                                   capture_output=True)
                    d = np.load(out)
                    b.append(float(np.linalg.norm(d["vertices"] - want[k][d["index"]],
                                                  axis=1).max()))
                res[f"influences_{inf}"]["blender_max_error_mm_frames_6_12_24_36"] = 1e3 * max(b)
        sp = tmp / "seq.npz"
        save_sequence(sp, seq)
        (tmp / "p.json").write_text(json.dumps(PARAMS))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "hack_render.cli", "export", "--params",
                        str(tmp / "p.json"), "--sequence", str(sp), "-o", str(tmp / "cli.glb")],
                       check=True, capture_output=True)
        res["cli_wall_seconds"] = time.perf_counter() - t0
        v = validator([tmp / "person4.glb", tmp / "person8.glb"])
        res["validator"] = v if isinstance(v, str) else [
            {k: r[k] for k in ("errors", "warnings", "infos")} | {"file": Path(r["file"]).name}
            for r in v]
    # the slide's in-betweens and the look-around's truncation error, for the record
    rig = R.build_rig(model, torch.tensor([PARAMS["beta"]]), PARAMS["eta"], influences=4)
    res["weight_truncation_error_look_around_mm"] = 1e3 * R.weight_truncation_error(
        model, rig, torch.as_tensor(look.theta))
    print(json.dumps(res, indent=1))
    write_result(args.out, res)


if __name__ == "__main__":
    main()
