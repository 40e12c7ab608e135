"""`hack-render track`: a clip to per-frame HACK parameters.

1. Landmarks on every frame (``detect.py``): dlib searched around the last face, the
   fit's refiner; lost frames marked.
2. One identity for the clip: the photo fit (``hack_render.fit``) on keyframes spread over
   the clip, all views at once, one expression per view; it gives beta, eta, the skin
   (alpha, when the photometric stage runs), the focal length and each keyframe's pose.
3. Per frame (``solve.py``): head rotation (over the 8 neck joints), torso rotation,
   translation and expression, warm-started from the previous frame, then one joint solve
   with velocity and acceleration priors; lost frames are carried by the priors.
4. The larynx's slide tau per frame from the neck's shading (``larynx.py``).
5. Outputs (``outputs.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.track.detect import FrameLandmarks
from hack_render.track.solve import ClipCamera, FrameParams, TrackConfig
from hack_render.track.video import Clip


@dataclass
class TrackResult:
    clip: Clip
    landmarks: FrameLandmarks
    keyframes: list[int]
    fit: object                    # the keyframe FitResult
    rig: object
    camera: ClipCamera
    params: FrameParams
    tau: np.ndarray
    timings: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    fitter: object = None          # the keyframe fit's Fitter (its outputs are written)


def pick_keyframes(found: np.ndarray, count: int, points: np.ndarray) -> list[int]:
    """``count`` frames with a face, spread over the clip: the first found frame, then in
    each of ``count - 1`` equal spans the frame whose face turns furthest from the ones
    picked (the nose tip's offset from the eye corners' midpoint, a yaw and pitch proxy),
    so the identity sees the face from several sides."""
    idx = np.flatnonzero(found)
    if len(idx) == 0:
        raise HackError("track: no face found in any frame. Use a clip with a visible face of "
                        "at least 48 px, frontal to three-quarter.")
    count = max(1, min(count, len(idx)))
    mid = (points[:, 36] + points[:, 45]) / 2
    iod = np.linalg.norm(points[:, 36] - points[:, 45], axis=1)
    turn = (points[:, 30] - mid) / np.maximum(iod, 1e-6)[:, None]
    picked = [int(idx[0])]
    for span in np.array_split(idx[1:], count - 1) if count > 1 else []:
        if len(span) == 0:
            continue
        d = np.min([np.linalg.norm(turn[span] - turn[p], axis=1) for p in picked], axis=0)
        picked.append(int(span[int(np.argmax(d))]))
    return sorted(set(picked))


def fit_identity(clip: Clip, lm: FrameLandmarks, keyframes: list[int], config,
                 progress: bool = True):
    """The photo fit on the keyframes (one expression per view): (FitResult, fitter)."""
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.landmarks import Detection
    from hack_render.fit.photo import from_array

    want = set(keyframes)
    photos, dets = [], []
    for i, img in enumerate(clip.read(0, max(keyframes) + 1)):
        if i in want:
            ph = from_array(img.astype(np.float32) / 255.0, f"frame {i}")
            photos.append(ph)
            box = tuple(float(x) for x in lm.boxes[i])
            weights = lm.weights if lm.raw is not None else None
            dets.append(Detection(lm.points[i].copy(), box, 1, "dlib",
                                  raw=lm.raw[i].copy(), weights=weights))
    fitter = Fitter(photos, dets, config, progress=progress)
    result = fitter.run()
    return result, fitter


def track_clip(clip: Clip, config=None, track_config: TrackConfig | None = None,
               keyframes: int = 5, progress: bool = True, model=None,
               landmarks: FrameLandmarks | None = None, estimate_tau: bool = True
               ) -> TrackResult:
    """Track a clip (no files written). ``config``: the keyframe fit's
    :class:`~hack_render.fit.config.FitConfig` (per-view expressions are switched on);
    ``landmarks``: reuse landmarks found before (a resumed run)."""
    import dataclasses

    from hack_render.fit.camera import R0
    from hack_render.fit.config import FitConfig
    from hack_render.track.detect import FrameDetector, detect_frames
    from hack_render.track.rig import LandmarkRig
    from hack_render.track.solve import solve_clip, solve_frames

    tcfg = track_config or TrackConfig()
    cfg = dataclasses.replace(config or FitConfig(), per_view_expression=True)
    timings, notes = {}, list(clip.notes)
    t0 = time.perf_counter()
    if landmarks is None:
        landmarks = detect_frames(clip.read(), FrameDetector(refiner=cfg.landmarks.refiner),
                                  progress, clip.frames)
        timings["landmarks_s"] = time.perf_counter() - t0
    if landmarks.found.sum() < 2:
        raise HackError(f"track: a face was found in {int(landmarks.found.sum())} of "
                        f"{len(landmarks.found)} frames; expected at least 2. Use a clip with "
                        "a visible face of at least 48 px, frontal to three-quarter.")
    keys = pick_keyframes(landmarks.found, keyframes, landmarks.points)
    t1 = time.perf_counter()
    fit, fitter = fit_identity(clip, landmarks, keys, cfg, progress)
    timings["identity_fit_s"] = time.perf_counter() - t1
    state = fitter.state
    rig = LandmarkRig.build(state.model, fit.beta.detach(), state.embedding)
    views = fit.views
    focal = float(np.median([float(v.focal.detach()) for v in views]))
    cam_t = views[0].transl.detach().double().numpy()
    camera = ClipCamera(focal, clip.work[0], clip.work[1], cam_t)
    R = R0.double().numpy()
    g_ref = np.median(np.stack([v.global_orient.detach().double().numpy() for v in views]), 0)
    v0 = views[0]
    psi0 = (v0.psi if v0.psi is not None else fit.psi).detach().double().numpy()
    init = FrameParams(v0.head_angles.detach().double().numpy()[None],
                       v0.global_orient.detach().double().numpy()[None],
                       (R.T @ (v0.transl.detach().double().numpy() - cam_t))[None], psi0)
    t2 = time.perf_counter()
    first = keys[0]
    obs, found = landmarks.points, landmarks.found.copy()
    # the warm-started pass runs forward from the first keyframe and backward to frame 0
    fwd = solve_frames(rig, camera, obs[first:], found[first:], landmarks.weights, init, tcfg,
                       progress)
    parts = [fwd]
    if first > 0:
        back = solve_frames(rig, camera, np.ascontiguousarray(obs[:first + 1][::-1]),
                            np.ascontiguousarray(found[:first + 1][::-1]),
                            landmarks.weights, init, tcfg, progress=False)
        parts.insert(0, FrameParams(*(a[::-1][:-1] for a in (back.h, back.g, back.t, back.psi))))
    seq = FrameParams(*(np.concatenate([getattr(p, k) for p in parts]) for k in
                        ("h", "g", "t", "psi")))
    timings["per_frame_s"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    params = solve_clip(rig, camera, obs, found, landmarks.weights, seq, g_ref, tcfg, progress)
    timings["smoothing_s"] = time.perf_counter() - t3
    tau = np.zeros(clip.frames)
    if estimate_tau:
        from hack_render.track.larynx import track_tau

        t4 = time.perf_counter()
        tau, note = track_tau(clip, state.model, fit, rig, camera, params, found, progress)
        timings["tau_s"] = time.perf_counter() - t4
        if note:
            notes.append(note)
    return TrackResult(clip, landmarks, keys, fit, rig, camera, params, tau, timings, notes,
                       fitter)


def sequence_of(result: TrackResult):
    """The per-frame parameters as a :class:`~hack_render.geometry.params.ParamSequence`."""
    from hack_render.geometry.params import ParamSequence
    from hack_render.geometry.skeleton import distribute_head_rotation

    p = result.params
    theta = distribute_head_rotation(torch.as_tensor(p.h), clamp=False).numpy()
    return ParamSequence(fps=result.clip.fps, theta=theta, psi=p.psi, tau=result.tau,
                         global_orient=p.g, transl=p.t)
