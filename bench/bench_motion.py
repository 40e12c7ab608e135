"""Motion synthesis and transfer (issue 26) on synthetic and procedural data.

    python bench/bench_motion.py [--threads 2] [--out bench/results/motion.json]

- head -> neck: the 2-layer, 512-unit MLP trained on 9 synthetic neck sequences (240
  frames each, ``hack_render.motion.synthetic.neck_rule``: NOT captured motion), per-joint
  mean angle error on 3 held-out ones against ``distribute_head_rotation``;
- expressions -> tau: the transformer trained on 20 synthetic sequences whose tau is a
  known lagged function of jawOpen, mouthFunnel and mouthPucker, autoregressive error on 4
  held-out ones;
- transfer: the procedural long-necked character over the pose-space stress test's
  families (200 poses), against its plain LBS and the person's model on the same poses;
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


def swallow() -> dict:
    from importlib import resources

    from hack_render.motion.swallow import load_swallow_curve

    c = load_swallow_curve(resources.files("hack_render") / "data" / "swallow_tau.npz")
    return {"swallows": c.count, "peak_mm": round(1e3 * float(c.tau.max()), 2),
            "rise_s": round(c.rise_s, 3), "fall_s": round(c.fall_s, 3),
            "std_max_mm": round(1e3 * float(c.std.max()), 2),
            "provenance": c.provenance.get("kind")}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--h2n-steps", type=int, default=1500)
    ap.add_argument("--larynx-steps", type=int, default=600)
    ap.add_argument("--poses", type=int, default=200)
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/motion.json")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    res = {"threads": args.threads, "data": "synthetic and procedural (no captured motion)"}
    res["head_to_neck"] = head_to_neck(args.h2n_steps)
    print("head_to_neck", res["head_to_neck"], flush=True)
    res["larynx_motion"] = larynx(args.larynx_steps, args.out.with_suffix(".ckpt.tmp.npz"))
    args.out.with_suffix(".ckpt.tmp.npz").unlink(missing_ok=True)
    print("larynx_motion", res["larynx_motion"], flush=True)
    res["transfer"] = transfer(args.poses)
    print("transfer", res["transfer"], flush=True)
    res["swallow"] = swallow()
    print("swallow", res["swallow"])
    print(f"wrote {write_result(args.out, res)}")


if __name__ == "__main__":
    main()
