"""Motion synthesis and transfer (issue 26) on synthetic and procedural data.

    python bench/bench_motion.py [--threads 2] [--out bench/results/motion.json]
    python bench/bench_motion.py --only transfer|gltf   # one part, the file's others kept

- head -> neck: the 2-layer, 512-unit MLP trained on 9 synthetic neck sequences (240
  frames each, ``hack_render.motion.synthetic.neck_rule``: NOT captured motion), per-joint
  mean angle error on 3 held-out ones against ``distribute_head_rotation``;
- expressions -> tau: the transformer trained on 20 synthetic sequences whose tau is a
  known lagged function of jawOpen, mouthFunnel and mouthPucker, autoregressive error on 4
  held-out ones;
- transfer: the procedural long-necked character over the pose-space stress test's
  families (200 poses), against its plain LBS and the person's model on the same poses;
- transfer onto a glTF character: the procedural long-necked character written as a
  plain glTF (``character.long_neck_gltf``: skin only, no UVs, 6 bones), through
  ``transfer`` with the default maps A(0) baked at ``--bake-size``: CPU seconds per stage,
  the alignment found (the character's skull is known: 0.85, 1, 1.35), and how well the
  bake lands: with a diffuse map that encodes HACK's atlas position (baked in float), the
  error of every covered texel against the same surface point's true atlas position, in
  texels of HACK's 1024-high atlas (a point on one of HACK's UV seams is right on either
  side, so the largest errors there are not misplacements);
- swallow: the packaged curve's figures.

Writes ``bench/results/motion.json`` (commit, date, machine, command first).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import ROOT, write_result


def head_to_neck(steps: int) -> dict:
    from hack_render.motion import head_to_neck as H
    from hack_render.motion import synthetic as S

    seqs = S.neck_sequences(12, 240, seed=1)
    t0 = time.perf_counter()
    m = H.train(seqs[:9], steps=steps, progress=False)
    return {"train_sequences": 9, "held_out_sequences": 3, "steps": steps,
            "seconds": round(time.perf_counter() - t0, 1), **H.compare(m, seqs[9:])}


def larynx(steps: int, tmp: Path) -> dict:
    from hack_render.geometry import load_default_model
    from hack_render.motion import larynx_motion as L
    from hack_render.motion import synthetic as S

    names = list(load_default_model().expression_names)
    data = S.larynx_sequences(24, names, frames=200, seed=3)
    cfg = L.LarynxConfig(num_expressions=len(names), steps=steps, layers=1,
                         feedback_noise_cm=0.2)
    t0 = time.perf_counter()
    model, _ = L.train(data[:20], cfg, tmp, progress=False)
    sec = time.perf_counter() - t0
    return {"train_sequences": 20, "held_out_sequences": 4, "steps": steps, "layers": 1,
            "d_model": cfg.d_model, "seconds": round(sec, 1), **L.evaluate(model, data[20:])}


def transfer(poses: int) -> dict:
    from hack_render.geometry import load_default_model
    from hack_render.geometry.deformation import model_deformation, sample_pose_space
    from hack_render.motion import character as C

    model = load_default_model()
    t0 = time.perf_counter()
    ch = C.long_neck_character(model)
    crig = C.character_rig(model, ch)
    rig_s = time.perf_counter() - t0
    theta = torch.cat(list(sample_pose_space(poses, seed=2100).values())).numpy()
    a = C.pose_checks(crig, model, theta)
    b = C.pose_checks(C.lbs_only(crig), model, theta)
    h = model_deformation(model, torch.zeros(1, 20), torch.as_tensor(theta).float())

    def fig(d):
        s = np.asarray(d["stretch"])
        return {"stretch_median": round(float(np.median(s)), 3),
                "stretch_p99": round(float(np.quantile(s, 0.99)), 3),
                "stretch_max": round(float(s.max()), 3),
                "poses_folding": int((np.asarray(d["folded"]) > 0).sum())}

    return {"poses": len(theta), "rig_seconds": round(rig_s, 1),
            "long_neck": fig(a), "long_neck_lbs": fig(b),
            "person": fig({k: getattr(h, k).numpy() for k in ("stretch", "folded")}),
            "poses_folding_more_than_lbs": int((a["folded"] > b["folded"]).sum()),
            "largest_stretch_excess_over_lbs": round(float((a["stretch"] - b["stretch"]).max()), 3)}


def transfer_gltf(bake_size: int, tmp: Path) -> dict:
    from hack_render.export import rig as R
    from hack_render.export.reference import accessor
    from hack_render.geometry import load_default_model
    from hack_render.geometry.params import ParamSequence, save_sequence
    from hack_render.motion import character as C
    from hack_render.motion import retarget as RT
    from hack_render.motion import surface_transfer as ST
    from hack_render.motion.transfer import run_transfer
    from hack_render.render.materials import SkinMaps
    from hack_render.render.parts import Topology
    from hack_render.render.skin_maps import skin_maps

    model = load_default_model()
    src = C.long_neck_gltf(model, tmp / "long_neck.glb")
    t = 48
    psi = np.zeros((t, model.num_expressions))
    psi[:, model.expression_names.index("jawOpen")] = 0.5 - 0.5 * np.cos(np.linspace(0, 4 * np.pi, t))
    go = np.zeros((t, 3))
    go[:, 1] = 0.6 * np.sin(np.linspace(0, 2 * np.pi, t))
    seq = ParamSequence(fps=24.0, theta=np.zeros((t, 8, 3)), psi=psi,
                        tau=0.01 * np.sin(np.linspace(0, 2 * np.pi, t)), global_orient=go)
    motion = save_sequence(tmp / "anim.npz", seq)
    out = {"frames": t, "bake_size": bake_size}
    t0 = time.process_time()
    rep = run_transfer(model, motion, str(src), tmp / "a", {}, maps=skin_maps([0.0]),
                       bake_size=bake_size, progress=False)
    out["cpu_seconds_total"] = round(time.process_time() - t0, 1)
    out["cpu_seconds"] = rep["target"]["cpu_seconds"]
    out["alignment"] = rep["target"]["alignment"]
    out["maps"] = next(iter(rep["target"]["maps"].values()))
    out["morph_targets"] = next(iter(rep["target"]["morph_targets"].values()))
    out["glb_mb"] = round(Path(rep["files"][0]).stat().st_size / 2 ** 20, 1)
    # where the bake lands: a diffuse that encodes the atlas position (u / 2, v)
    h = 512
    uu, vv = np.meshgrid((np.arange(2 * h) + 0.5) / h, 1 - (np.arange(h) + 0.5) / h)
    enc = SkinMaps(np.stack([uu / 2, vv, 0 * uu], -1).astype(np.float32),
                   np.zeros((h, 2 * h, 1), np.float32), np.zeros((h, 2 * h, 1), np.float32))
    ch = RT.load_gltf_character(src)
    RT.add_uv_atlas(ch, bake_size)
    rest = next(RT.posed_primitives(ch))
    prim = ch.doc["meshes"][0]["primitives"][0]
    tmpl = np.round(accessor(ch.doc, ch.buf, prim["attributes"]["_HACK_VERTEX"])[:, 0]).astype(int)
    uv = accessor(ch.doc, ch.buf, prim["attributes"]["TEXCOORD_0"])
    bones = [ch.node(n) for n in ("neck_01", "neck_02", "neck_03", "head")]
    surface = ST.hack_surface(model, R.build_rig(model, None, 1.0), ch.world[bones, :3, 3],
                              rest.vertices[rest.dominant == ch.node("head")])
    baked, _ = ST.bake_maps(surface, enc, rest.vertices, rest.faces, uv, bake_size)
    face, bary = ST.rasterize_atlas(uv[rest.faces], bake_size)
    cov = np.flatnonzero(face.ravel() >= 0)
    f, b = face.ravel()[cov], bary.reshape(-1, 3)[cov].astype(np.float64)
    topo = Topology.from_model(model)
    key = {tuple(sorted(x)): i for i, x in enumerate(topo.faces.tolist())}
    tv = tmpl[rest.faces[f]]
    tf = np.array([key[tuple(sorted(x))] for x in tv.tolist()])
    corner = (topo.faces[tf][:, None, :] == tv[:, :, None]).argmax(2)
    truth = np.einsum("qk,qkc->qc", b, topo.uvs[topo.uv_faces[tf][np.arange(len(tf))[:, None],
                                                                   corner]])
    got = baked["diffuse"].reshape(-1, 3)[cov]
    err = np.maximum(np.abs(2 * got[:, 0] - truth[:, 0]), np.abs(got[:, 1] - truth[:, 1]))
    # in texels of HACK's 1024-high atlas (float maps: no 8-bit quantisation)
    out["bake_error_hack_texels_at_1024"] = {
        "median": round(1024 * float(np.median(err)), 3),
        "p99": round(1024 * float(np.quantile(err, 0.99)), 2),
        "max": round(1024 * float(err.max()), 1),
        "fraction_over_4": round(float((1024 * err > 4).mean()), 4), "covered_texels": len(err)}
    return out


def swallow() -> dict:
    from importlib import resources

    from hack_render.motion.swallow import load_swallow_curve

    c = load_swallow_curve(resources.files("hack_render") / "data" / "swallow_tau.npz")
    return {"swallows": c.count, "peak_mm": round(1e3 * float(c.tau.max()), 2),
            "rise_s": round(c.rise_s, 3), "fall_s": round(c.fall_s, 3),
            "std_max_mm": round(1e3 * float(c.std.max()), 2),
            "provenance": c.provenance.get("kind")}


#: --only's parts and their entries in the results file
ONLY = {"gltf": "transfer_gltf", "transfer": "transfer"}
PARTS = ("head_to_neck", "larynx_motion", "transfer", "transfer_gltf", "swallow")


def entries_from(old: dict) -> dict:
    """Each entry's commit and date in the results file ``old`` (its JSON): those recorded
    in ``entries_from`` (or the older ``other_entries_from``, which ``--only gltf`` wrote
    for every entry but ``transfer_gltf``), and the file's own commit and date for the
    rest (its last run's)."""
    if "entries_from" in old:
        out = dict(old["entries_from"])
    elif "other_entries_from" in old:
        out = {k: old["other_entries_from"] for k in PARTS if k != "transfer_gltf"}
    else:
        out = {}
    own = {k: old.get(k) for k in ("commit", "date")}
    return {k: out.get(k, own) for k in PARTS if k in old}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--h2n-steps", type=int, default=1500)
    ap.add_argument("--larynx-steps", type=int, default=600)
    ap.add_argument("--poses", type=int, default=200)
    ap.add_argument("--bake-size", type=int, default=1024)
    ap.add_argument("--only", choices=list(ONLY), help="run one part and update its entry in "
                    "the existing results file (each entry's commit and date in "
                    "'entries_from')")
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/motion.json")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.only:
        import json
        import tempfile

        old = json.loads(args.out.read_text())
        res = {k: v for k, v in old.items() if k not in ("commit", "date", "machine", "command")}
        key = ONLY[args.only]
        res["entries_from"] = entries_from(old)
        res.pop("other_entries_from", None)
        if key == "transfer_gltf":
            with tempfile.TemporaryDirectory() as tmp:
                res[key] = transfer_gltf(args.bake_size, Path(tmp))
        else:
            res[key] = transfer(args.poses)
        res["entries_from"].pop(key, None)  # this run's: the file's own commit and date
        print(key, res[key])
        print(f"wrote {write_result(args.out, res)}")
        return
    res = {"threads": args.threads, "data": "synthetic and procedural (no captured motion)"}
    res["head_to_neck"] = head_to_neck(args.h2n_steps)
    print("head_to_neck", res["head_to_neck"], flush=True)
    res["larynx_motion"] = larynx(args.larynx_steps, args.out.with_suffix(".ckpt.tmp.npz"))
    args.out.with_suffix(".ckpt.tmp.npz").unlink(missing_ok=True)
    print("larynx_motion", res["larynx_motion"], flush=True)
    res["transfer"] = transfer(args.poses)
    print("transfer", res["transfer"], flush=True)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        res["transfer_gltf"] = transfer_gltf(args.bake_size, Path(tmp))
    print("transfer_gltf", res["transfer_gltf"], flush=True)
    res["swallow"] = swallow()
    print("swallow", res["swallow"])
    print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
