"""Tracker accuracy and speed on clips rendered with known per-frame parameters.

Each clip is the default model rendered by the project (``hack_render.track.synthetic``:
a procedural identity and skin, whole-head motion over the 8 neck joints, a jaw opening,
a smile and a brow raise, the averaged swallow, the key light turning), then tracked by
``hack_render.track.cli.track_video`` as the command would. Reported per clip and
overall: joint angle error (theta, degrees), head rotation error, expression error on the
active shapes, the larynx slide's error (mm, RMSE and correlation with the true swallow;
beside it, the error of holding the keyframe fit's tau, what the tracker did before it
tracked tau), how far the tracked neck sits from the true one in the image (px), jitter
of theta against the truth's, landmark error, lost frames, the speed of landmark-driven
tracking (frames/s: landmarks, per-frame solve and smoothing; the keyframe fit is timed
apart), of the outline stage and of the photometric tau stage. By default each clip is
tracked with and without the outline stage (``--outline both``), side by side.

    python bench/bench_track.py                 # 2 clips, 72 frames at 640x480
    python bench/bench_track.py --frames 24 --clips 1 --size 320x240   # quick
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", type=int, default=2)
    ap.add_argument("--frames", type=int, default=72)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--fps", type=float, default=24.0)
    ap.add_argument("--keyframes", type=int, default=4)
    ap.add_argument("--photometric", action="store_true",
                    help="run the keyframe fit's photometric stage (default: landmarks only)")
    ap.add_argument("--refine", action="store_true",
                    help="refine dlib's points with the fit's landmark refiner (the "
                    "command's --refine; default off, as the command)")
    ap.add_argument("--tau", choices=("photometric", "fixed"), default="photometric",
                    help="how track finds the larynx's slide (the command's default: fixed)")
    ap.add_argument("--outline", choices=("both", "on", "off"), default="both",
                    help="the outline stage: on, off, or each clip tracked both ways "
                         "(the command's default: on)")
    ap.add_argument("--masks", choices=("head_neck", "person"), default="head_neck",
                    help="person: the keyframe fit's silhouette term and the outline stage "
                         "on the person mask, as before issue 63 (on these bald renders the "
                         "person mask is the head's exact outline); default: the command's "
                         "(no silhouette in the keyframe fit, outline on the head-and-neck "
                         "mask)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "track.json"))
    args = ap.parse_args(argv)

    import torch

    from hack_render.fit.config import load_config
    from hack_render.track import pipeline
    from hack_render.track.cli import track_video
    from hack_render.track.synthetic import render_clip

    torch.set_num_threads(args.threads)
    w, h = (int(x) for x in args.size.split("x"))
    over = {} if args.photometric else {"photometric": {"enabled": False}}
    if not args.refine:   # the command's default (--no-refine): dlib's own points
        over["landmarks"] = {"refiner": "off"}
    cfg = load_config(None, over)
    if args.masks == "person":  # the tracker's two switches (track/pipeline.py), as before
        pipeline.IDENTITY_SILHOUETTE = "person"
        pipeline.OUTLINE_MASK = "person"
    clips = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.clips):
            folder = Path(tmp) / f"clip{k}"
            t0 = time.perf_counter()
            render_clip(folder, frames=args.frames, fps=args.fps, size=(w, h), seed=10 + k,
                        spp=args.spp, focal_mm=85.0, progress=True)
            render_s = time.perf_counter() - t0
            truth = dict(np.load(folder / "truth.npz"))
            ways = {"both": (True, False), "on": (True,), "off": (False,)}[args.outline]
            for outline in ways:
                cpu0 = time.process_time()
                out = folder / ("out" if outline else "out_no_outline")
                res, _ = track_video(folder / "frames", out, keyframes=args.keyframes,
                                     fps=args.fps, config=cfg, progress=True, truth=truth,
                                     larynx=args.tau == "photometric", outline=outline)
                held = float(res.fit.tau.detach().reshape(-1)[0])
                rep = json.loads((out / "report.json").read_text())
                t = rep["truth"]
                clips.append({
                    "seed": 10 + k, "outline": outline, "frames": args.frames, "size": [w, h],
                    "spp": args.spp, "render_s": render_s,
                    "cpu_s": time.process_time() - cpu0,
                    "theta_joint_deg_mean": t["theta_joint_deg"]["mean"],
                    "theta_joint_deg_max": t["theta_joint_deg"]["max"],
                    "head_deg_mean": t["head_deg"]["mean"],
                    "neck_px_mean": t["neck_px"]["mean"],
                    "psi_active_abs_mean": t["psi_abs"]["active_mean"],
                    "tau_mm_mean": t["tau_mm"]["mean"], "tau_mm_max": t["tau_mm"]["max"],
                    "tau_mm_rmse": t["tau_mm"]["rmse"],
                    "tau_correlation": t["tau_mm"]["correlation"],
                    "tau_truth_range_mm": t["tau_mm"]["truth_range"],
                    "tau_held_mm_mean": float(1e3 * np.abs(truth["tau"] - held).mean()),
                    "tau_fps": rep["larynx"].get("fps"),
                    "outline_stage": rep["outline"],
                    "theta_jitter_deg": rep["jitter"]["theta_deg_per_frame2"],
                    "theta_jitter_truth_deg": t["jitter_truth"]["theta_deg_per_frame2"],
                    "landmark_nme_median": rep["landmark_nme"]["median"],
                    "lost_frames": rep["lost_count"],
                    "tracking_fps": rep["tracking_fps"],
                    "timings_s": rep["timings_s"],
                })
                print(json.dumps(clips[-1], indent=1))
    def mean(key, outline):
        vals = [c[key] for c in clips if c["outline"] is outline and c[key] is not None]
        return float(np.mean(vals)) if vals else None
    from provenance import write_result

    result = {
        "what": "hack-render track on clips rendered with known parameters (procedural)",
        "keyframe_fit": "photometric" if args.photometric else "landmarks only",
        "landmark_refiner": "dlib" if args.refine else "off",
        "tau": args.tau,
        "masks": args.masks,
        "clips": clips,
        "summary": {("outline" if o else "no_outline"): {
            k: mean(k, o) for k in ("theta_joint_deg_mean", "neck_px_mean",
                                    "psi_active_abs_mean", "tau_mm_mean", "tau_mm_rmse",
                                    "tau_correlation", "tau_held_mm_mean", "tau_fps",
                                    "theta_jitter_deg", "theta_jitter_truth_deg",
                                    "landmark_nme_median", "tracking_fps")}
            for o in (True, False) if any(c["outline"] is o for c in clips)},
    }
    print(json.dumps(result["summary"], indent=1))
    print(f"wrote {write_result(args.out, result)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
