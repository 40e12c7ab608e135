"""`hack-render track` on real talking-head clips, scored against an independent detector.

    python bench/bench_track_real.py CLIPS_DIR                       # every clip listed
    python bench/bench_track_real.py CLIPS_DIR --max-frames 100 --clips RD_Radio2_000
    python bench/bench_track_real.py CLIPS_DIR --keep /tmp/trk --rescore   # score only

The clips are not in the repository: ``bench/track_real_clips.json`` lists them (file
name, source repository, path, commit, licence) and ``--fetch-help`` prints how to get
them; the benchmark reads them from the folder given (``CLIPS_DIR/NAME``).

Per clip, the command is run as a user would (``python -m hack_render.cli track CLIP -o
OUT --quiet`` plus ``--track-args``), with its exit code, wall seconds and per-stage
timings (its ``report.json``). Then MediaPipe's face mesh (``vision.detect.detect_faces(
img, "mesh")``) is run on every frame at the tracker's working size, independently of the
tracker (which uses dlib and the fit's refiner), and MediaPipe's attention mesh (its lips
and eyes refined: ``mesh68_hand.attention_mesh``) on the face it found; the attention
mesh's 468 points read as the 68 of the iBUG convention by the index pairs calibrated on
hand-placed points (``--reference hand``, the default: ``bench/mesh68_hand.py``), or the
plain mesh's by the fitter's map calibrated on the model's own renders (``--reference
model_map``; each row scores the other too), and the tracked
model's projected points (``tracked_landmarks.npz``) are scored against it: NME over the
chin and the 51 inner points (``bench_real_photos.fit_against_mesh``'s set), in units of
the mesh's outer-eye distance, per frame; reported: median and p90 over the frames where
the mesh finds a face, the jitter (mean frame-to-frame acceleration, px/frame^2) of the
tracked points and of the mesh's own, the frames the tracker lost, and the tracker's own
status (``report.json``'s ``status``). ``--fit-first``: also the photo fitter
(``hack-render fit --no-photometric``) on the clip's first frame, scored the same way
(``bench_real_photos.run_fit``), as the reference.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MANIFEST = ROOT / "bench" / "track_real_clips.json"
from mesh68_hand import IDX  # the chin and the 51 inner points


def mesh_dense(clip_path: Path, max_side: int, frames: int) -> np.ndarray:
    """MediaPipe's face mesh on every frame at the working size: (T, 468, 3), NaN where it
    finds no face."""
    from hack_render.track.video import open_clip
    from hack_render.vision.detect import detect_faces

    clip = open_clip(clip_path, max_side)
    out = np.full((frames, 468, 3), np.nan)
    for i, img in enumerate(clip.read(0, frames)):
        faces = detect_faces(img, "mesh")
        if faces and faces[0].dense is not None:
            out[i] = np.asarray(faces[0].dense, np.float64)
    return out


def mesh_attention(clip_path: Path, max_side: int, dense: np.ndarray) -> np.ndarray:
    """MediaPipe's attention mesh on every frame at the working size, on the face the plain
    mesh found there (``dense``, (T, 468, 3)): (T, 468, 2), NaN where either finds none."""
    from mesh68_hand import attention_mesh

    from hack_render.track.video import open_clip

    out = np.full((len(dense), 468, 2), np.nan)
    for i, img in enumerate(open_clip(clip_path, max_side).read(0, len(dense))):
        if np.isfinite(dense[i]).all():
            pts = attention_mesh(img, dense[i])
            if pts is not None:
                out[i] = pts
    return out


def references(dense: np.ndarray, attention: np.ndarray,
               pairs: np.ndarray | None) -> dict[str, np.ndarray]:
    """The meshes read as the 68, (T, 68, 2) each: ``hand``, the attention mesh's (T, 468,
    2) points by the hand-calibrated index pairs (``mesh68_hand``; the reference), and
    ``model_map``, the plain mesh's (T, 468, 3) by the shipped map (``vision.dense68``,
    calibrated on the plain mesh of the model's renders: the fitter's)."""
    from mesh68_hand import to68

    from hack_render.vision.dense68 import load_map

    dmap = load_map()
    out = {"model_map": np.array([dmap.to68(d) for d in dense])}
    if pairs is not None:
        out["hand"] = np.array([to68(pairs, d) for d in attention])
    return out


def score(tracked: np.ndarray, mesh: np.ndarray) -> dict:
    """Per-frame NME of the tracked points against the mesh's (chin + inner 51, by the
    mesh's outer-eye distance), summarised; jitter of both."""
    from bench_real_photos import nme

    from hack_render.track.outputs import jitter

    ok = np.isfinite(mesh).all(axis=(1, 2))
    per = np.full(len(mesh), np.nan)
    for i in np.flatnonzero(ok):
        iod = float(np.linalg.norm(mesh[i, 36] - mesh[i, 45]))
        per[i] = nme(tracked[i], mesh[i], iod, IDX)
    v = per[ok]
    iod = np.linalg.norm(mesh[:, 36] - mesh[:, 45], axis=1)
    return {"frames_scored": int(ok.sum()),
            "nme_median": float(np.median(v)) if len(v) else None,
            "nme_p90": float(np.percentile(v, 90)) if len(v) else None,
            "nme_mean": float(np.mean(v)) if len(v) else None,
            "outer_eye_px_median": float(np.nanmedian(iod)),
            "jitter_tracked_px": jitter(np.where(ok[:, None, None], tracked, np.nan)[:, IDX]),
            "jitter_mesh_px": jitter(mesh[:, IDX]),
            "per_frame_nme": [None if not np.isfinite(x) else round(float(x), 5)
                              for x in per]}


def run_track(clip: Path, out: Path, args) -> dict:
    cmd = [sys.executable, "-m", "hack_render.cli", "track", str(clip), "-o", str(out),
           "--quiet", "--max-side", str(args.max_side)]
    if args.max_frames:
        cmd += ["--max-frames", str(args.max_frames)]
    cmd += args.track_args.split()
    import resource

    t = time.time()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run(cmd, capture_output=True, text=True, check=False)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    row = {"command": " ".join(cmd[2:]), "exit": p.returncode,
           "seconds": round(time.time() - t, 1),
           # the command's CPU time (all threads): the figure a loaded machine distorts
           # least (wall seconds on a shared 2-core machine are not the command's own)
           "cpu_seconds": round(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, 1),
           "load_average_1min": round(__import__("os").getloadavg()[0], 1),
           "stderr_warnings": [ln for ln in p.stderr.splitlines()
                               if ln.startswith("warning:")]}
    if p.returncode:
        row["message"] = (p.stderr or p.stdout).strip().splitlines()[-3:]
    return row


def clip_row(name: str, path: Path, out: Path, args) -> dict:
    row: dict = {"clip": name}
    saved = out / "bench_track_row.json"   # the command's exit, seconds (a rescore keeps them)
    if not args.rescore:
        row["track"] = run_track(path, out, args)
        if out.is_dir():
            saved.write_text(json.dumps(row["track"]))
    elif saved.is_file():
        row["track"] = json.loads(saved.read_text())
    rep_path, pts_path = out / "report.json", out / "tracked_landmarks.npz"
    if not (rep_path.is_file() and pts_path.is_file()):
        return row
    rep = json.loads(rep_path.read_text())
    with np.load(pts_path) as z:
        tracked = z["points"].astype(np.float64)
    T = len(tracked)
    row.update({"frames": T, "fps": rep.get("fps"), "status": rep.get("status"),
                "warnings": rep.get("warnings", []), "lost_frames": rep.get("lost_count"),
                "tracker_nme_vs_own_detector_median": rep["landmark_nme"]["median"],
                "timings_s": {k: round(v, 1) for k, v in rep["timings_s"].items()
                              if not k.endswith("_cpu_s")},
                "outline": rep.get("outline"), "larynx": rep.get("larynx"),
                "identity": rep.get("identity")})
    cache = out / "mesh_dense.npy"
    if cache.is_file() and len(np.load(cache)) == T:
        dense = np.load(cache)
    else:
        t = time.time()
        dense = mesh_dense(path, args.max_side, T)
        row["mesh_seconds"] = round(time.time() - t, 1)
        np.save(cache, dense)
    attention = None
    if args.pairs is not None:
        cache = out / "mesh_attention.npy"
        if cache.is_file() and len(np.load(cache)) == T:
            attention = np.load(cache)
        else:
            t = time.time()
            attention = mesh_attention(path, args.max_side, dense)
            row["attention_mesh_seconds"] = round(time.time() - t, 1)
            np.save(cache, attention)
    refs = references(dense, attention, args.pairs)
    mesh = refs.pop("hand" if args.pairs is not None else "model_map")
    row["reference"] = "hand" if args.pairs is not None else "model_map"
    row.update(score(tracked, mesh))
    with np.load(out / "landmarks.npz") as z:   # the tracker's own detector against the mesh:
        det = z["points"][:T].astype(np.float64)   # the floor two detectors leave
    row["detector_vs_mesh"] = {k: v for k, v in score(det, mesh).items()
                               if k in ("nme_median", "nme_p90", "jitter_tracked_px")}
    # (the detector's points' own jitter, under the name score() gives the points it scores)
    row["detector_vs_mesh"]["jitter_px"] = row["detector_vs_mesh"].pop("jitter_tracked_px")
    for name_, other in refs.items():            # the other reading of the same mesh
        row[f"vs_{name_}"] = {k: v for k, v in score(tracked, other).items()
                              if k in ("nme_median", "nme_p90", "per_frame_nme")}
    if args.fit_first:
        from bench_real_photos import run_fit

        from hack_render.track.video import open_clip

        img = next(iter(open_clip(path, args.max_side).read(0, 1)))
        fit = run_fit(name, img, photometric=False, keep=out / "fit_first")
        row["fit_first_frame"] = {k: fit.get(k) for k in ("exit", "seconds",
                                                          "fit_vs_mesh_iod", "fit_vs_dlib_iod",
                                                          "landmark_residual_iod")}
        # the fitted points against this table's reference on the same frame, beside the
        # tracked points' (the fitter's default detector is dlib, as the tracker's)
        npz = out / "fit_first" / name / "params.npz"
        if npz.is_file() and np.isfinite(mesh[0]).all():
            with np.load(npz) as z:
                fitted = z["view0_landmarks_fitted"].astype(np.float64)[:, :2]
            from bench_real_photos import nme

            iod = float(np.linalg.norm(mesh[0, 36] - mesh[0, 45]))
            row["fit_first_frame"]["nme_vs_reference"] = nme(fitted, mesh[0], iod, IDX)
            row["fit_first_frame"]["tracked_frame0_nme"] = nme(tracked[0], mesh[0], iod, IDX)
    return row


def summary(rows: list, key: str | None = None) -> dict:
    """The table's summary; ``key``: of the rows' ``key`` scores (the other reference)."""
    if key is not None:
        rows = [r[key] for r in rows if key in r]
        return summary(rows) if rows else {}
    v = [r["nme_median"] for r in rows if r.get("nme_median") is not None]
    allf = [x for r in rows for x in r.get("per_frame_nme", []) if x is not None]
    return {"clips": len(rows), "clips_scored": len(v),
            "worst_clip_median": max(v) if v else None,
            "median_of_clip_medians": float(np.median(v)) if v else None,
            "all_frames_median": float(np.median(allf)) if allf else None,
            "all_frames_p90": float(np.percentile(allf, 90)) if allf else None,
            "clips_over_5pc": sum(x > 0.05 for x in v),
            "clips_over_4pc": sum(x > 0.04 for x in v)} | _fit_first_summary(rows)


def _fit_first_summary(rows: list) -> dict:
    """With ``--fit-first``: the median over clips of the photo fitter's NME on the first
    frame and of the tracked points' on the same frame."""
    f = [r["fit_first_frame"] for r in rows if "nme_vs_reference" in
         (r.get("fit_first_frame") or {})]
    if not f:
        return {}
    return {"fit_first_frame_median": float(np.median([x["nme_vs_reference"] for x in f])),
            "tracked_frame0_median": float(np.median([x["tracked_frame0_nme"] for x in f])),
            "fit_first_clips": len(f)}


def table(res: dict) -> str:
    """The docs' table (markdown) of a result file."""
    lines = [("| clip | frames | NME median / p90 | jitter tracked / mesh / dlib (px/frame^2) | "
               "dlib vs mesh | lost | status | wall / CPU s | identity fit / outline s |"),
             "|---|---|---|---|---|---|---|---|---|"]
    for r in res["clips"]:
        if r.get("nme_median") is None:
            lines.append(f"| {r['clip']} | - | failed: {(r.get('track') or {}).get('message')} "
                         "| | | | | |")
            continue
        tr, tm = r.get("track") or {}, r.get("timings_s") or {}
        lines.append(
            f"| {r['clip']} | {r['frames']} | {100 * r['nme_median']:.1f} / "
            f"{100 * r['nme_p90']:.1f} % | {r['jitter_tracked_px']:.2f} / "
            f"{r['jitter_mesh_px']:.2f} / "
            f"{(r.get('detector_vs_mesh') or {}).get('jitter_px', float('nan')):.2f} | "
            f"{100 * (r.get('detector_vs_mesh') or {}).get('nme_median', float('nan')):.1f} % | "
            f"{r['lost_frames']} | {r['status']} | "
            f"{tr.get('seconds', '-')} / {tr.get('cpu_seconds', '-')} | "
            f"{tm.get('identity_fit_s', 0):.0f} / {tm.get('outline_s', 0):.0f} |")
    s = res["summary"]
    lines.append(f"| **all** | | median of clip medians {100 * s['median_of_clip_medians']:.1f} %, "
                 f"all frames {100 * s['all_frames_median']:.1f} / "
                 f"{100 * s['all_frames_p90']:.1f} %; worst clip "
                 f"{100 * s['worst_clip_median']:.1f} % | | | | | | |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips_dir", type=Path, nargs="?", default=None)
    ap.add_argument("--clips", nargs="*", help="clip names (default: all in the manifest "
                    "found in CLIPS_DIR)")
    ap.add_argument("--max-frames", type=int, default=100)
    ap.add_argument("--max-side", type=int, default=512)
    ap.add_argument("--track-args", default="", help="more of the command's options, as "
                    "one string (e.g. '--tau fixed --no-outline')")
    ap.add_argument("--keep", type=Path, default=Path("/tmp/bench_track_real"),
                    help="the tracker's outputs, per clip (KEEP/NAME)")
    ap.add_argument("--rescore", action="store_true", help="score the outputs already in "
                    "KEEP without tracking again")
    ap.add_argument("--fit-first", action="store_true",
                    help="also the photo fitter on each clip's first frame")
    ap.add_argument("--fetch-help", action="store_true", help="print how to get the clips")
    ap.add_argument("--table", type=Path, help="print the markdown table of a result file "
                    "and exit")
    ap.add_argument("--reference", choices=("hand", "model_map"), default="hand",
                    help="the 68 the table scores against: 'hand', MediaPipe's attention "
                    "mesh read by the index pairs calibrated on hand-placed points "
                    "(bench/mesh68_hand.py, bench/results/mesh68_hand.json), or 'model_map', "
                    "the plain mesh read by the shipped map calibrated on the model's renders; "
                    "each row also scores the other")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "track_real.json"),
                    help="result file")
    args = ap.parse_args(argv)
    from mesh68_hand import load_pairs

    args.pairs = load_pairs() if args.reference == "hand" else None
    if args.table:
        print(table(json.loads(args.table.read_text())))
        return 0
    manifest = json.loads(MANIFEST.read_text())
    if args.fetch_help or args.clips_dir is None:
        print(manifest["how_to_get"])
        for c in manifest["clips"]:
            print(f"  {c['name']}: {c['repo']} {c['path']} @ {c['commit']} (blob {c['blob']})")
        return 0
    names = args.clips or [c["name"] for c in manifest["clips"]]
    rows = []
    for name in names:
        path = args.clips_dir / f"{name}.mp4"
        if not path.is_file():
            print(f"{name}: {path} not found; skipped", file=sys.stderr)
            continue
        row = clip_row(name, path, args.keep / name, args)
        rows.append(row)
        short = {k: row.get(k) for k in ("clip", "status", "nme_median", "nme_p90",
                                         "jitter_tracked_px", "jitter_mesh_px",
                                         "lost_frames")}
        short["seconds"] = (row.get("track") or {}).get("seconds")
        print(json.dumps(short), flush=True)
        write(args, rows, names, manifest)   # after every clip: a stopped run keeps them
    print(json.dumps(write(args, rows, names, manifest)["summary"]))
    return 0


def write(args, rows, names, manifest) -> dict:
    from provenance import write_result

    res = {"clips": [{k: v for k, v in r.items() if k != "per_frame_nme"} | {
        "per_frame_nme": r.get("per_frame_nme")} for r in rows],
        "summary": summary(rows), "reference": args.reference,
        "summary_other_reference": summary(rows, "vs_model_map" if args.reference == "hand"
                                           else "vs_hand"),
        "max_frames": args.max_frames, "max_side": args.max_side,
        "track_args": args.track_args,
        "sources": {c["name"]: {k: c[k] for k in ("repo", "path", "commit", "licence")}
                    for c in manifest["clips"] if c["name"] in names}}
    write_result(args.out, res)
    return res


if __name__ == "__main__":
    raise SystemExit(main())
