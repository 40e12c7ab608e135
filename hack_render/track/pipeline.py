"""`hack-render track`: a clip to per-frame HACK parameters.

1. Landmarks on every frame (``detect.py``): dlib searched around the last face, the
   fit's refiner; lost frames marked.
2. One identity for the clip: the photo fit (``hack_render.fit``) on keyframes spread over
   the clip, all views at once, one expression per view; it gives beta, eta, the skin
   (alpha, when the photometric stage runs), the focal length and each keyframe's pose.
3. Per frame (``solve.py``): head rotation (over the 8 neck joints), torso rotation,
   translation and expression, warm-started from the previous frame, then one joint solve
   with velocity and acceleration priors; lost frames are carried by the priors.
4. The outline stage (``outline.py``, ``outline=True``, the default): the person mask of
   every frame (a plain background keyed out, else MediaPipe's person segmentation) and
   one more joint solve with the model's face and neck contour held on its border, so
   the neck below the face sits where the image shows it.
5. With ``larynx=True`` (the default), the larynx's slide tau per frame (``larynx.py``):
   the neck's shading fitted at a grid of slides with the light refitted per frame, then
   the least-cost smooth path over the clip; with ``larynx=False`` the keyframe fit's tau
   throughout.
6. Outputs (``outputs.py``).
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.fit.camera import R0
from hack_render.fit.config import FitConfig
from hack_render.fit.fitter import Fitter
from hack_render.fit.photo import from_array
from hack_render.geometry.params import ParamSequence
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.track.detect import FrameDetector, FrameLandmarks, detect_frames
from hack_render.track.larynx import track_tau
from hack_render.track.outline import frame_masks, refine_outline
from hack_render.track.rig import LandmarkRig
from hack_render.track.solve import (
    ClipCamera,
    FrameParams,
    TrackConfig,
    landmark_error,
    solve_clip,
    solve_frames,
)
from hack_render.track.video import Clip
from hack_render.vision.detection import Detection


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
    larynx: object = None          # the photometric tau's LarynxTrack (None: not tracked)
    outline: object = None         # the outline stage's OutlineResult (None: not run)
    warnings: list[str] = field(default_factory=list)  # :func:`quality_warnings`'s
    # what ``track_clip``'s ``on_identity`` returned (a :class:`Background` writing the
    # keyframe fit's files while the clip is tracked), None: not started
    identity_job: object = None


#: the tracked model's points farther than this from the detected ones (median over the
#: frames with a face, in units of the outer-eye distance) are reported as a poor track
#: (stderr, the report's ``status``): the tracker reaches 2-4 % on real clips where it
#: works (docs/motion.md), the photo fitter 3.9 % on held-out portraits; 6 % is a face
#: fitted a size too wide or the landmarks of another face
FAR_NME = 0.06
#: a clip where fewer than this share of the frames with a face show the neck's larynx
#: region (its photometric confidence 0: not scored) keeps the keyframe fit's tau, with
#: zero confidence, instead of a path through frames that were never seen
MIN_NECK_SHARE = 0.25


class timed:
    """Adds ``<name>_s`` (wall) and ``<name>_cpu_s`` (this process's CPU time, all
    threads) to ``timings`` for the block."""

    def __init__(self, timings: dict, name: str):
        self.timings, self.name = timings, name

    def __enter__(self):
        self.t, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.timings[f"{self.name}_s"] = time.perf_counter() - self.t
        self.timings[f"{self.name}_cpu_s"] = time.process_time() - self.c
        return False


class Background(threading.Thread):
    """``fn(*args, **kw)`` in a daemon thread (an interrupt of the command abandons it: it
    writes nothing); :meth:`result` waits and returns it, or raises its error. Adds
    ``<name>_s`` (its wall seconds) and ``<name>_cpu_s`` (its thread's CPU) to
    ``timings``."""

    def __init__(self, timings: dict, name: str, fn, *args, **kw):
        super().__init__(name=name, daemon=True)
        self.timings, self.label, self.call = timings, name, (fn, args, kw)
        self.value = self.error = None
        self.start()

    def run(self) -> None:
        t, c = time.perf_counter(), time.thread_time()
        fn, args, kw = self.call
        try:
            self.value = fn(*args, **kw)
        except BaseException as err:  # noqa: BLE001 - re-raised by result()
            self.error = err
        self.timings[f"{self.label}_s"] = time.perf_counter() - t
        self.timings[f"{self.label}_cpu_s"] = time.thread_time() - c

    def result(self):
        self.join()
        if self.error is not None:
            raise self.error
        return self.value


class MaskFeed:
    """The landmarks stage's frames and points handed, as each frame's landmarks are
    final, to a thread that makes the outline stage's masks (:func:`~hack_render.track.
    outline.frame_masks` reads frame i's points and found flag only): the masks' face mesh
    and NumPy then run beside dlib's one-core detection instead of beside the keyframe
    fit. :attr:`points` and :attr:`found` are filled as frames come; :meth:`frames` is
    the masks' frame iterable; :meth:`close` ends it (a clip with more or fewer frames
    than announced: :attr:`complete` is False and the caller makes the masks afresh).
    At most :data:`MASK_FEED_FRAMES` frames wait; ``consumer``: the masks' thread, once
    started (a thread that has died no longer holds the detection up)."""

    def __init__(self, frames: int):
        self.points = np.full((frames, 68, 2), np.nan)
        self.found = np.zeros(frames, bool)
        self.seen = 0
        self.queue: queue.Queue = queue.Queue(maxsize=MASK_FEED_FRAMES)
        self.consumer: threading.Thread | None = None

    def _put(self, item) -> None:
        while self.consumer is None or self.consumer.is_alive():
            try:
                self.queue.put(item, timeout=0.2)
                return
            except queue.Full:
                continue

    def put(self, i: int, img: np.ndarray, points: np.ndarray, found: bool) -> None:
        self.seen = i + 1
        if i < len(self.found):
            self.points[i], self.found[i] = points, found
            self._put(img)

    def close(self) -> None:
        self._put(None)

    @property
    def complete(self) -> bool:
        return self.seen == len(self.found)

    def frames(self):
        while (img := self.queue.get()) is not None:
            yield img


#: frames waiting for the outline masks' thread at most (:class:`MaskFeed`: 512 px frames,
#: 0.8 MB each; the masks' thread takes every third frame, faster than dlib's detection)
MASK_FEED_FRAMES = 32


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


def warm_started(rig, camera, obs, found, weights, init: FrameParams, first: int,
                 tcfg: TrackConfig, progress: bool) -> FrameParams:
    """The warm-started pass from frame ``first`` (where ``init`` holds): forward to the
    clip's end, and backward to frame 0."""
    w = np.asarray(weights)
    parts = [solve_frames(rig, camera, obs[first:], found[first:],
                          w[first:] if w.ndim == 2 else w, init, tcfg, progress, init.g[0])]
    if first > 0:
        back = solve_frames(rig, camera, np.ascontiguousarray(obs[:first + 1][::-1]),
                            np.ascontiguousarray(found[:first + 1][::-1]),
                            np.ascontiguousarray(w[:first + 1][::-1]) if w.ndim == 2 else w,
                            init, tcfg, False, init.g[0])
        parts.insert(0, FrameParams(*(a[::-1][:-1] for a in (back.h, back.g, back.t, back.psi))))
    return FrameParams(*(np.concatenate([getattr(p, k) for p in parts]) for k in
                         ("h", "g", "t", "psi")))


#: the keyframe fit's silhouette term: "off" (the default since issue 63: the fit's
#: silhouette reads the person mask, whose border on a face that fills the frame is the
#: hair's, and fitted the identity a size too wide) or "person" (the fit's own term)
IDENTITY_SILHOUETTE = "off"
#: the outline stage's mask (:func:`~hack_render.track.outline.frame_masks`' ``mode``)
#: and the share of frames it is made for (every n-th frame; the priors carry the rest)
OUTLINE_MASK = "head_neck"
OUTLINE_EVERY = 3
#: the keyframe fit's camera and shape stages' iterations where the config leaves the
#: photo fit's defaults (150 each): on WDA_BobMenendez_000 the camera stage's loss at 100
#: was within 1 % of its value at 150 and the shape stage's within 0.3 %, and the per-frame
#: and joint solves refine the pose after it; a third of the fit's time
IDENTITY_ITERATIONS = {"camera": 100, "shape": 100}


def identity_config(config) -> FitConfig:
    """The keyframe fit's config: per-view expressions, the camera and shape stages'
    iterations of :data:`IDENTITY_ITERATIONS` where the config has the photo fit's
    defaults, and the silhouette term off unless :data:`IDENTITY_SILHOUETTE` asks for it
    (the outline stage places the face's and neck's outline on the head-and-neck mask
    afterwards)."""
    cfg = dataclasses.replace(config or FitConfig(), per_view_expression=True)
    default = FitConfig()
    for stage, n in IDENTITY_ITERATIONS.items():
        if getattr(cfg, stage).iterations == getattr(default, stage).iterations:
            cfg = dataclasses.replace(cfg, **{stage: dataclasses.replace(
                getattr(cfg, stage), iterations=n)})
    if IDENTITY_SILHOUETTE == "off" and cfg.silhouette.mode != "off":
        cfg = dataclasses.replace(cfg, silhouette=dataclasses.replace(cfg.silhouette,
                                                                      mode="off"))
    return cfg


def track_clip(clip: Clip, config=None, track_config: TrackConfig | None = None,
               keyframes: int = 5, progress: bool = True, model=None,
               landmarks: FrameLandmarks | None = None, larynx: bool = True,
               outline: bool = True, outline_mask: str | None = None,
               on_identity=None) -> TrackResult:
    """Track a clip (no files written). ``config``: the keyframe fit's
    :class:`~hack_render.fit.config.FitConfig` (per-view expressions are switched on, its
    silhouette off: :func:`identity_config`); ``landmarks``: reuse landmarks found before
    (a resumed run); ``larynx``: track the larynx's slide per frame from the neck's
    shading (else the keyframe fit's tau); ``outline``: place the face's and neck's
    outline on the head-and-neck mask (``outline.py``; ``outline_mask`` "person": the
    person mask, as before issue 63); ``on_identity``: called with the keyframe
    FitResult and the timings as soon as the keyframe fit ends (``outputs.py`` starts
    writing its files there, in a thread beside the per-frame stages, which use one
    core); what it returns is the result's ``identity_job``."""

    tcfg = track_config or TrackConfig()
    outline_on = outline and (config is None or config.silhouette.mode != "off")
    cfg = identity_config(config)
    timings, notes = {}, list(clip.notes)
    # the outline stage's masks need only the frames and their landmarks: made in a
    # thread from each frame as its landmarks are final (beside dlib's one core), or, for
    # landmarks given, beside the keyframe fit (its torch work and the masks' face mesh and
    # NumPy then share the two cores)
    sc = (config or FitConfig()).silhouette
    mode = outline_mask or OUTLINE_MASK

    def masks_from(frames, points, found) -> Background:
        return Background(timings, "outline_masks", frame_masks, frames, points, found,
                          segment=sc.segment, chroma=sc.chroma, mode=mode,
                          every=OUTLINE_EVERY if mode == "head_neck" else 1)

    masking = feed = None
    if landmarks is None:
        if outline_on:
            feed = MaskFeed(clip.frames)
            masking = feed.consumer = masks_from(feed.frames(), feed.points, feed.found)
        try:
            with timed(timings, "landmarks"):
                landmarks = detect_frames(clip.read(), FrameDetector(
                    refiner=cfg.landmarks.refiner), progress, clip.frames,
                    on_frame=feed.put if feed is not None else None)
        finally:
            if feed is not None:
                feed.close()
        if feed is not None and not feed.complete:  # the clip's frame count was wrong
            masking.result()
            masking = None
    if landmarks.found.sum() < 2:
        raise HackError(f"track: a face was found in {int(landmarks.found.sum())} of "
                        f"{len(landmarks.found)} frames; expected at least 2. Use a clip with "
                        "a visible face of at least 48 px, frontal to three-quarter.")
    # keyframes from dlib's frames: the fit reads their jawline as dlib's outline
    by_dlib = landmarks.found & np.array([src == "dlib" for src in landmarks.source])
    keys = pick_keyframes(by_dlib if by_dlib.any() else landmarks.found, keyframes,
                          landmarks.points)
    if outline_on and masking is None:
        masking = masks_from(clip.read(), landmarks.points, landmarks.found.copy())
    with timed(timings, "identity_fit"):
        fit, fitter = fit_identity(clip, landmarks, keys, cfg, progress)
    identity_job = on_identity(fit, timings) if on_identity is not None else None
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
    # the torso the clip keeps is the keyframes' median; the first frame's head starts
    # with the first keyframe's whole rotation (torso and head) given to the head
    g0 = v0.global_orient.detach().double().numpy()
    init = FrameParams((v0.head_angles.detach().double().numpy() + g0 - g_ref)[None],
                       g_ref[None],
                       (R.T @ (v0.transl.detach().double().numpy() - cam_t))[None], psi0)
    obs, found = landmarks.points, landmarks.found.copy()
    point_w = landmarks.weights[None] * landmarks.mask  # (T, 68): the mesh's jaw left out
    with timed(timings, "per_frame"):
        seq = warm_started(rig, camera, obs, found, point_w, init, keys[0], tcfg,
                           progress)
    with timed(timings, "smoothing"):
        params = solve_clip(rig, camera, obs, found, point_w, seq, g_ref, tcfg,
                            progress)
    tau = np.full(clip.frames, float(fit.tau.detach().reshape(-1)[0]))
    eta = float(fit.eta.detach().reshape(-1)[0])
    placed = None  # the outline stage's OutlineResult
    if masking is not None:
        with timed(timings, "outline"):
            masks = masking.result()
            params, placed = refine_outline(rig, camera, obs, found, point_w, params, g_ref,
                                            tcfg, state.model, fit.beta.detach(), eta, tau,
                                            masks, progress=progress)
        if not masks.has.any():
            notes.append("outline: no frame gave a mask (head and neck: no face mesh; person: "
                         "neither a plain background nor the person segmentation); the neck "
                         "follows the landmarks alone")
    track = None
    if larynx:
        with timed(timings, "larynx"):
            track = track_tau(clip.read, state.model, fit.beta.detach(), eta, params, camera,
                              found, clip.fps, progress=progress)
        tau, note = larynx_or_fixed(track, tau, found)
        if note:
            notes.append(note)
    result = TrackResult(clip, landmarks, keys, fit, rig, camera, params, tau, timings,
                         notes, fitter, track, placed, identity_job=identity_job)
    result.warnings = quality_warnings(result)
    return result


def larynx_or_fixed(track, fixed: np.ndarray, found: np.ndarray) -> tuple[np.ndarray, str]:
    """The photometric tau where the neck was seen, else the keyframe fit's: (tau, note).
    A clip where under :data:`MIN_NECK_SHARE` of the frames with a face were scored (the
    larynx region off the frame, under the chin or too small: confidence 0) keeps
    ``fixed`` throughout and the track's confidence is set to 0 on every frame."""
    seen = track.confidence > 0
    n = max(int(np.sum(found)), 1)
    if seen.sum() >= MIN_NECK_SHARE * n:
        return track.tau, ""
    track.confidence[:] = 0.0
    track.tau = np.array(fixed, np.float64)
    track.fallback = True
    return track.tau, (f"larynx: the neck's larynx region was seen in {int(seen.sum())} of "
                       f"{n} frames with a face (needs {MIN_NECK_SHARE:.0%}); tau kept at the "
                       f"keyframe fit's {1e3 * float(fixed[0]):.1f} mm on every frame, "
                       "confidence 0")


def quality_warnings(result: TrackResult) -> list[str]:
    """What a user must know about the track: the tracked model's points far from the
    detected ones (median NME over the frames with a face above :data:`FAR_NME`)."""
    lm = result.landmarks
    _, nme, _ = landmark_error(result.rig, result.camera, result.params, lm.points, lm.found)
    out = []
    v = nme[lm.found & np.isfinite(nme)]
    if len(v):
        med, far = float(np.median(v)), float(np.mean(v > FAR_NME))
        if med > FAR_NME:
            out.append(f"the tracked model's landmarks lie {100 * med:.1f} % of the outer-eye "
                       f"distance from the detected ones (median over {len(v)} frames; "
                       f"{100 * far:.0f} % of the frames above {100 * FAR_NME:.0f} %): a poor "
                       "track (the face fitted the wrong size, or the wrong face); check "
                       "overlay.mp4")
    return out


def sequence_of(result: TrackResult):
    """The per-frame parameters as a :class:`~hack_render.geometry.params.ParamSequence`."""
    p = result.params
    theta = distribute_head_rotation(torch.as_tensor(p.h), clamp=False).numpy()
    return ParamSequence(fps=result.clip.fps, theta=theta, psi=p.psi, tau=result.tau,
                         global_orient=p.g, transl=p.t)
