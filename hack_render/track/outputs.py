"""What `hack-render track` writes: the parameter sequence, the person, the camera, the
landmarks, the overlay video and the report."""

from __future__ import annotations

import threading
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hack_render.fit.camera import R0
from hack_render.fit.outputs import write_all
from hack_render.geometry.params import save_params, save_sequence
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.io import atomic_path, write_json
from hack_render.track import draw
from hack_render.track.pipeline import Background, TrackResult, sequence_of
from hack_render.track.solve import landmark_error
from hack_render.track.video import Mp4Writer
from scenes.cameras import Camera

#: render passes of the identity's overlay sheets (``fit.outputs.write_overlays``)
IDENTITY_SHEET_PASSES = 4
#: threads drawing the overlay's frames (each alone: the video is the same either way)
OVERLAY_THREADS = 2


def jitter(x: np.ndarray) -> float:
    """Mean magnitude of the frame-to-frame acceleration of a (T, ...) series: the
    trailing axis is one vector (a point's x, y; a joint's axis-angle), the axes between
    are averaged over (frames with NaN are skipped)."""
    x = np.asarray(x, np.float64)
    if len(x) < 3:
        return float("nan")
    x = x.reshape(len(x), -1, x.shape[-1]) if x.ndim > 1 else x.reshape(len(x), 1, 1)
    a = x[2:] - 2 * x[1:-1] + x[:-2]
    return float(np.nanmean(np.linalg.norm(a, axis=-1)))


def frame_vertices(result: TrackResult, start: int, stop: int) -> np.ndarray:
    """The fitted model's vertices (stop - start, N, 3) for frames start .. stop - 1."""
    fit, p = result.fit, result.params
    model = result.fit.model
    sl = slice(start, stop)
    with torch.no_grad():
        theta = distribute_head_rotation(torch.as_tensor(p.h[sl]).float(), clamp=False)
        out = model(beta=fit.beta.detach(), psi=torch.as_tensor(p.psi[sl]).float(), theta=theta,
                    global_orient=torch.as_tensor(p.g[sl]).float(),
                    transl=torch.as_tensor(p.t[sl]).float(),
                    eta=fit.eta.detach().expand(stop - start),
                    tau=torch.as_tensor(result.tau[sl]).float())
    return out.vertices.numpy()


def skin_faces(model) -> np.ndarray:
    """(F,) the triangles of the model's skin (``M_Face``, ``M_BackHead``): a closed
    surface seen from outside (its holes filled by the eyes and the mouth), so the
    overlay's rasteriser culls their back faces."""
    names = [n for n in ("M_Face", "M_BackHead") if n in model.material_names]
    ids = [list(model.material_names).index(n) for n in names]
    return np.isin(model.face_material.numpy(), ids)


def write_overlay(result: TrackResult, path: Path, progress: bool = True,
                  stop: threading.Event | None = None, cpu: list | None = None) -> Path:
    """MP4 at the clip's rate: each frame with the fitted model drawn over it (shaded,
    60 % opacity; rasterised, :func:`~hack_render.render.raster.render_shaded`: the image
    of the mesh viewer's ray caster in a fraction of its time), the detected landmarks
    (green) and the model's (red); lost frames say so in a red band
    (:func:`~hack_render.track.draw.draw_frame`). ``stop``: set, the video is abandoned
    (nothing written) at the next frame; ``cpu``: a list that gets the drawing threads'
    CPU seconds."""

    clip, cam = result.clip, result.camera
    w, h = clip.work
    K = np.array([[cam.focal, 0, w / 2], [0, cam.focal, h / 2], [0, 0, 1.0]])
    camera = (K, R0.double().numpy(), np.asarray(cam.cam_t, np.float64), w, h)
    model = result.fit.model
    faces = model.faces.numpy()
    closed = skin_faces(model)
    _, _, uv = landmark_error(result.rig, cam, result.params, result.landmarks.points,
                              result.landmarks.found)
    lm = result.landmarks
    chunk = 16
    verts = None
    drawn: list[float] = []   # the drawing threads' CPU seconds
    # frames drawn by OVERLAY_THREADS threads (the rasteriser's NumPy releases the GIL:
    # 1.6x one thread on 2 cores; worker processes were slower still, their frames
    # pickled both ways), written in order; each frame is drawn alone, so the video is
    # the same bits as drawn one by one
    ctx = draw.frame_context(faces, closed, camera)
    pool = ThreadPoolExecutor(OVERLAY_THREADS, thread_name_prefix="overlay")
    pending: deque = deque()

    def take():
        frame, sec = pending.popleft().result()
        drawn.append(sec)
        out.write(frame)

    with Mp4Writer(path, (w, h), clip.fps) as out, pool:
        for i, img in enumerate(tqdm(clip.read(), total=clip.frames, desc="overlay",
                                     unit="frame", disable=not progress, leave=False)):
            if stop is not None and stop.is_set():
                raise _Stopped
            if i % chunk == 0:
                verts = frame_vertices(result, i, min(clip.frames, i + chunk))
            pending.append(pool.submit(draw.draw_frame, ctx, i, img, verts[i % chunk],
                                       lm.points[i], uv[i],
                                       None if lm.found[i] else str(lm.why[i])))
            if len(pending) > 2 * OVERLAY_THREADS:
                take()
        while pending:
            take()
    if cpu is not None:
        cpu.append(sum(drawn))
    return path


def report_dict(result: TrackResult, truth: dict | None = None) -> dict:
    """The report: per-frame landmark error, jitter, lost frames, timings (and errors
    against ``truth`` when given: theta, psi, tau per frame)."""
    lm = result.landmarks
    err_px, nme, uv = landmark_error(result.rig, result.camera, result.params, lm.points,
                                     lm.found)
    seq = sequence_of(result)
    fps = result.clip.fps
    lost = [{"frame": int(i), "why": lm.why[i]} for i in np.flatnonzero(~lm.found)]
    n = result.clip.frames
    stages = ("landmarks", "per_frame", "smoothing")
    track_s = sum(result.timings.get(f"{k}_s", 0.0) for k in stages)
    track_cpu = sum(result.timings.get(f"{k}_cpu_s", 0.0) for k in stages)
    rep = {
        "source": str(result.clip.source), "frames": n, "fps": fps,
        "size": list(result.clip.size), "working_size": list(result.clip.work),
        "keyframes": result.keyframes,
        "camera": result.camera.to_dict(),
        "landmark_error_px": {"mean": float(np.nanmean(err_px)),
                              "median": float(np.nanmedian(err_px)),
                              "max": float(np.nanmax(err_px))},
        "landmark_nme": {"mean": float(np.nanmean(nme)), "median": float(np.nanmedian(nme)),
                         "normalised_by": "outer-eye distance (landmarks 37 and 46)"},
        "jitter": {"landmarks_px_per_frame2": jitter(np.where(lm.found[:, None, None], uv,
                                                              np.nan)),
                   "detected_landmarks_px_per_frame2": jitter(lm.points),
                   "theta_deg_per_frame2": float(np.degrees(jitter(seq.theta))),
                   "head_deg_per_frame2": float(np.degrees(jitter(result.params.h)))},
        "lost_frames": lost,
        "lost_count": len(lost),
        # frames whose landmarks came from the face mesh (dlib found no face there)
        "mesh_fallback_frames": [i for i, src in enumerate(lm.source) if src == "mesh"],
        "timings_s": result.timings,
        # landmark-driven tracking (landmarks, per-frame solve, smoothing; not the keyframe
        # fit): frames per wall second, and per CPU second (the figure a loaded machine
        # does not distort)
        "tracking_fps": n / track_s if track_s > 0 else None,
        "tracking_fps_cpu": n / track_cpu if track_cpu > 0 else None,
        "larynx": _larynx_report(result),
        "outline": _outline_report(result),
        "notes": result.notes,
        # "poor": the warnings say why (also printed on stderr); the threshold is
        # pipeline.FAR_NME of the outer-eye distance
        "status": "poor" if result.warnings else "ok",
        "warnings": list(result.warnings),
        "per_frame": [{"frame": i, "found": bool(lm.found[i]),
                       "landmark_error_px": None if not lm.found[i] else float(err_px[i]),
                       "head_deg": np.degrees(result.params.h[i]).round(3).tolist(),
                       "tau_mm": round(1e3 * float(result.tau[i]), 3),
                       "tau_confidence": None if result.larynx is None else
                       round(float(result.larynx.confidence[i]), 4),
                       "outline_px": _outline_px(result, i)} for i in range(n)],
    }
    if truth is not None:
        rep["truth"] = truth_errors(result, truth)
    return rep


def _outline_px(result: TrackResult, i: int) -> float | None:
    """Frame i's mean distance (px) of the model's contour from the person mask's border
    after the outline stage (None: no mask, or the stage did not run)."""
    o = result.outline
    if o is None or not np.isfinite(o.after[i]):
        return None
    return round(float(o.after[i]), 3)


def _outline_report(result: TrackResult) -> dict:
    """The outline stage: frames with a person mask, how they were made, the contour's
    median distance from the mask's border before and after, and the stage's speed."""
    o = result.outline
    if o is None:
        return {"ran": False}
    sec = result.timings.get("outline_s", 0.0)
    cpu = result.timings.get("outline_cpu_s", 0.0)
    n = result.clip.frames
    return {"ran": True, **o.report(),
            "fps": n / sec if sec > 0 else None, "fps_cpu": n / cpu if cpu > 0 else None}


def _larynx_report(result: TrackResult) -> dict:
    """How tau was found, and the photometric stage's speed."""
    lt = result.larynx
    if lt is None:
        return {"method": "fixed: the keyframe fit's tau on every frame (--tau fixed)"}
    sec = result.timings.get("larynx_s", 0.0)
    cpu = result.timings.get("larynx_cpu_s", 0.0)
    if getattr(lt, "fallback", False):
        seen = int((lt.pixels > 0).sum())
        return {"method": "fixed: the neck's larynx region was not seen (in "
                          f"{seen} frames); the keyframe fit's tau on every frame, "
                          "confidence 0",
                "pixels_median": 0.0, "confidence_median": 0.0,
                "fps": len(lt.tau) / sec if sec > 0 else None}
    return {"method": "photometric: the neck's shading at a grid of slides, the light "
                      "refitted per frame and slide, then the least-cost smooth path",
            "grid_mm": (1e3 * lt.grid).round(3).tolist(),
            "pixels_median": float(np.median(lt.pixels[lt.pixels > 0])) if (lt.pixels > 0).any()
            else 0.0,
            "confidence_median": float(np.median(lt.confidence)),
            "fps": len(lt.tau) / sec if sec > 0 else None,
            "fps_cpu": len(lt.tau) / cpu if cpu > 0 else None}


def truth_errors(result: TrackResult, truth: dict) -> dict:
    """Errors against a clip's known parameters (``synthetic.render_clip``'s truth)."""
    seq = sequence_of(result)
    th = np.degrees(np.linalg.norm(seq.theta - truth["theta"], axis=-1))  # (T, 8)
    psi = np.abs(seq.psi - truth["psi"])
    active = np.abs(truth["psi"]).max(0) > 0.05
    tau = 1e3 * np.abs(np.asarray(result.tau) - truth["tau"])
    moving = np.ptp(truth["tau"]) > 0 and np.ptp(result.tau) > 0
    head = np.degrees(np.abs(result.params.h - truth["h"]))
    neck = neck_offset_px(result, truth)
    return {"theta_joint_deg": {"mean": float(th.mean()), "max": float(th.max())},
            "neck_px": {"mean": float(neck.mean()), "max": float(neck.max())},
            "head_deg": {"mean": head.mean(0).tolist(), "max": head.max(0).tolist()},
            "psi_abs": {"mean": float(psi.mean()),
                        "active_mean": float(psi[:, active].mean()) if active.any() else None},
            "tau_mm": {"mean": float(tau.mean()), "rmse": float(np.sqrt((tau ** 2).mean())),
                       "max": float(tau.max()),
                       "truth_range": float(1e3 * np.ptp(truth["tau"])),
                       "correlation": float(np.corrcoef(result.tau, truth["tau"])[0, 1])
                       if moving else None},
            "jitter_truth": {"theta_deg_per_frame2": float(np.degrees(jitter(truth["theta"])))},
            "per_frame_theta_deg": th.mean(1).round(3).tolist(),
            "per_frame_neck_px": neck.round(3).tolist(),
            "per_frame_tau_mm": tau.round(3).tolist()}


def neck_offset_px(result: TrackResult, truth: dict) -> np.ndarray:
    """(T,) how far the tracked neck sits from the true one in the image: the length of
    the mean image offset (px) of the larynx region's vertices, the tracked model through
    the tracked camera against the true model (``truth``: beta, theta, psi, tau, K,
    cam_t; torso and translation zero) through the true camera."""
    model = result.fit.model
    T = result.clip.frames
    w, h = result.clip.work
    cam = result.camera
    K = np.array([[cam.focal, 0, w / 2], [0, cam.focal, h / 2], [0, 0, 1.0]])
    R = R0.double().numpy()
    est_cam = Camera(K, R, np.asarray(cam.cam_t, np.float64), w, h, "tracked")
    true_cam = Camera(np.asarray(truth["K"], np.float64), R,
                      np.asarray(truth["cam_t"], np.float64), w, h, "truth")
    lv = model.larynx_vertices.numpy()
    est = frame_vertices(result, 0, T)[:, lv]
    with torch.no_grad():
        true = model(beta=torch.as_tensor(truth["beta"]).float().reshape(1, -1).expand(T, -1),
                     psi=torch.as_tensor(truth["psi"]).float(),
                     theta=torch.as_tensor(truth["theta"]).float(),
                     tau=torch.as_tensor(truth["tau"]).float()).vertices[:, lv].numpy()
    return np.array([np.linalg.norm((est_cam.project(est[i].astype(np.float64))
                                     - true_cam.project(true[i].astype(np.float64))).mean(0))
                     for i in range(T)])


def write_larynx_plot(result: TrackResult, path: Path, truth: dict | None = None) -> Path:
    """``larynx.png``: each frame's relative cost of every slide (darker: the frame's
    shading fits that slide better; grey columns: frames not scored) with the chosen
    path over it (and the truth's, when given), and each frame's confidence."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lt = result.larynx
    T = len(lt.tau)
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 4.6), sharex=True,
                                 gridspec_kw={"height_ratios": [3, 1]})
    cost = np.ma.masked_invalid(lt.cost.T)
    ax.imshow(np.minimum(cost, np.nanpercentile(lt.cost, 95)) if np.isfinite(lt.cost).any()
              else cost, origin="lower", aspect="auto", cmap="magma",
              extent=(-0.5, T - 0.5, 1e3 * lt.grid[0], 1e3 * lt.grid[-1]))
    ax.plot(np.arange(T), 1e3 * lt.tau, color="#3ddc84", lw=2, label="tracked tau")
    if truth is not None and "tau" in truth:
        ax.plot(np.arange(T), 1e3 * np.asarray(truth["tau"])[:T], "--", color="#7fd3ff",
                lw=1.2, label="truth")
    ax.set_ylabel("larynx slide tau (mm)")
    ax.set_title("each frame's cost of each slide (dark: fits) and the path chosen", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    bx.bar(np.arange(T), lt.confidence, color="#4c72b0", width=0.9)
    bx.set_ylabel("confidence")
    bx.set_xlabel("frame")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


def write_tracked_points(result: TrackResult, path: Path) -> Path:
    """The tracked model's 68 landmarks projected in every frame (``points`` (T, 68, 2),
    working-size pixels; lost frames included: the priors' pose), for scoring the track
    against another detector (``bench/bench_track_real.py``)."""
    lm = result.landmarks
    _, _, uv = landmark_error(result.rig, result.camera, result.params, lm.points, lm.found)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, points=uv.astype(np.float32), found=lm.found,
                 working_size=np.array(result.clip.work))
    return path


class _Stopped(Exception):
    """The overlay was abandoned (the command failed or was interrupted meanwhile)."""


def _overlay_unless_stopped(result: TrackResult, path: Path, progress: bool,
                            stop: threading.Event, cpu: list) -> Path | None:
    """:func:`write_overlay`, or None where the caller abandoned it (``stop`` set: the
    identity's files failed or the command was interrupted; nothing is written)."""
    try:
        return write_overlay(result, path, progress, stop=stop, cpu=cpu)
    except _Stopped:
        return None


def start_identity_files(fit, outdir: Path, timings: dict) -> Background:
    """The keyframe fit's files (``outdir``/identity: ``fit.outputs.write_all``) written in
    a thread (``timings`` gets ``identity_files_s`` and its thread's CPU seconds): started
    by ``track_clip`` as soon as the fit ends, so they are written while the per-frame
    stages run on the other core; :func:`write_outputs` waits for them. The sheets take
    :data:`IDENTITY_SHEET_PASSES` render passes (16 spp), not the photo fit's 16 (their
    80 path-traced renders took about a tenth of the command's CPU time; the render
    panel is a little noisier)."""
    return Background(timings, "identity_files", write_all, fit, outdir / "identity",
                      sheet_passes=IDENTITY_SHEET_PASSES)


def write_outputs(result: TrackResult, fitter, outdir: Path, overlay: bool = True,
                  progress: bool = True, truth: dict | None = None) -> list[Path]:
    """Everything; the report last. Returns the paths written. The overlay video is
    written in a thread while the identity's files are (``pipeline.Background``;
    ``timings_s`` gets ``overlay_s`` and ``overlay_cpu_s``, its drawing workers' CPU
    included)."""
    written = []
    stop, workers = threading.Event(), []
    job = Background(result.timings, "overlay", _overlay_unless_stopped, result,
                      outdir / "overlay.mp4", progress, stop, workers) if overlay else None
    try:
        # the keyframe fit's files: written since the fit ended where track_clip started
        # them (start_identity_files), else here, beside the overlay's thread
        ident = result.identity_job or start_identity_files(result.fit, outdir,
                                                            result.timings)
        written += ident.result()
        person = {"beta": result.fit.beta[0].detach().tolist(), "eta": float(result.fit.eta)}
        written.append(save_params(outdir / "person.json", person))
        written.append(save_sequence(outdir / "sequence.npz", sequence_of(result)))
        result.landmarks.save(outdir / "landmarks.npz")
        written.append(outdir / "landmarks.npz")
        written.append(write_tracked_points(result, outdir / "tracked_landmarks.npz"))
        written.append(write_json(outdir / "camera.json", result.camera.to_dict(), indent=1))
        if result.larynx is not None:
            written.append(write_larynx_plot(result, outdir / "larynx.png", truth))
    except BaseException:
        if job is not None:   # an error or an interrupt: the video is abandoned
            stop.set()
            job.join()
        raise
    if job is not None:
        written.append(job.result())
        result.timings["overlay_cpu_s"] += sum(workers)
    rep = report_dict(result, truth)
    written.append(write_json(outdir / "report.json", rep, indent=1))
    return written
