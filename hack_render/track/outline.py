"""The neck's placement per frame from the person's outline (the tracker's outline stage).

Landmarks pin the face, not the neck below it: a head turn that the tracker splits
between the neck's twist and a sideways slide of the body, or a head pitch traded for a
move up or down, leaves the face where it is and moves the neck by several pixels (7 px
on average on the benchmark's clip 10, where a 1 mm slide of the larynx moves its bump
1.4 px). The person's outline pins it: the neck's sides must lie on the border of the
person mask in every frame.

Per frame with a face:

1. The person mask: the frame's plain background keyed out
   (:func:`~hack_render.fit.silhouette.segment_plain_background`), else MediaPipe's person
   segmentation (:func:`~hack_render.vision.segment.person_mask`) when it installs; its
   signed distance map (:class:`~hack_render.fit.silhouette.PhotoSilhouette`). Frames
   with no mask are left to the landmarks.
2. The model's side is the fitter's silhouette term
   (:class:`~hack_render.fit.silhouette.ModelSilhouette`): the outer occluding contour of
   the face and neck skin (the bust's cut and the scalp left out) lies on the mask's
   border; the skin projects inside the mask (one-sided: hair and clothes cost nothing).
   The contour is selected on the full mesh at the frame's current pose; during the solve
   its points move with the pose by linear blend skinning of the frame's corrected rest
   mesh (exact for the pose the mesh was built at; the pose correctives are refreshed at
   every round).
3. One joint solve over the clip, as the tracker's smoothing solve (landmarks, priors,
   velocity and acceleration) plus this term, in the landmark term's units (residuals
   over the outer-eye distance, the same robust knee), for ``rounds`` rounds of contour
   selection.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from hack_render.fit.camera import R0
from hack_render.fit.silhouette import (
    ModelSilhouette,
    PhotoSilhouette,
    mask_problem,
    segment_plain_background,
)
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms, skin
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.render.bridge import vertex_normals_torch
from hack_render.track.solve import solve_clip
from hack_render.vision.detect import mesh_landmarks
from hack_render.vision.segment import person_mask, ring, skin_colour_mask

#: frames whose contour is selected together (one batched forward of the model)
_CHUNK = 32


@dataclass
class OutlineConfig:
    """Weights of the outline stage, relative to the 68 landmarks' term: ``contour`` for
    the model's contour points off the mask's border, ``inside`` for skin outside the
    mask; ``rounds`` of contour selection; ``iterations`` of L-BFGS per round."""

    contour: float = 1.0
    inside: float = 1.0
    rounds: int = 2
    iterations: int = 60


@dataclass
class FrameMasks:
    """Per-frame person masks as signed distance maps, stacked: ``sdf`` (T, 1, h, w) at
    ``scale`` working px per frame px (> 0 outside), ``has`` (T,) frames with a mask,
    ``source`` (T,) how each was made ("" where none)."""

    sdf: torch.Tensor
    scale: float
    has: np.ndarray
    source: list
    #: (T,) per frame, the lowest image row (working px) where the mask's border is the
    #: person's outline (the head-and-neck mask: the neck's skin seen down to there; +inf:
    #: the whole border); the model's contour below it is left out
    limit_y: np.ndarray | None = None
    #: "head_neck" (:func:`head_neck_mask`: the face's and neck's own outline, no hair, the
    #: term reads only the face's and neck's skin) or "person" (the person mask)
    kind: str = "person"

    @classmethod
    def from_masks(cls, masks, source: list | None = None,
                   max_side: int = 320) -> FrameMasks:
        """From (H, W) bool masks, one per frame (None: no mask for that frame); each is
        turned into its distance map as it comes (stored as float16 at ``max_side``: a
        long clip's masks are not kept)."""
        sdfs, has, kinds, scale = [], [], [], 1.0
        for i, m in enumerate(masks):
            if m is not None and mask_problem(m) is not None:
                m = None  # all person or none (a tight crop): no outline in this frame
            kind = (source[i] if source is not None else "given") if m is not None else ""
            if m is None:
                sdfs.append(None)
            else:
                sil = PhotoSilhouette.from_mask(m, kind, max_side)
                sdfs.append(sil.sdf[0].half())
                scale = sil.scale
            has.append(m is not None)
            kinds.append(kind)
        has = np.array(has, bool)
        T = len(sdfs)
        if not has.any():
            return cls(torch.zeros(T, 1, 1, 1, dtype=torch.float16), 1.0, has, kinds)
        zero = torch.zeros_like(next(x for x in sdfs if x is not None))
        return cls(torch.stack([x if x is not None else zero for x in sdfs]), scale, has,
                   kinds)

    def distance(self, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance (frame px) at frame pixels uv (T, P, 2), bilinear and
        differentiable, and (T, P) inside the frame."""
        h, w = self.sdf.shape[-2:]
        x, y = uv[..., 0] * self.scale, uv[..., 1] * self.scale
        grid = torch.stack([2.0 * x / w - 1.0, 2.0 * y / h - 1.0], -1)
        d = torch.nn.functional.grid_sample(self.sdf.to(grid.dtype), grid[:, None], mode="bilinear",
                                            padding_mode="border", align_corners=False)
        valid = (x >= 0) & (x <= w) & (y >= 0) & (y <= h)
        return d[:, 0, 0] / self.scale, valid.detach()


def frame_masks(frames, points: np.ndarray, found: np.ndarray, segment: bool = True,
                max_side: int = 320, max_spread: float = 0.06, chroma: bool = True,
                mode: str = "head_neck", every: int = 1) -> FrameMasks:
    """The mask of every ``every``-th frame with a face (:class:`FrameMasks`; the frames
    between get none and follow the landmarks and the temporal priors).

    Args:
        frames: iterable of (H, W, 3) uint8 sRGB frames at the tracker's working size.
        points: (T, 68, 2) landmarks; found: (T,) frames with a face.
        segment: use MediaPipe's person segmentation where the background is not plain
            (it is skipped, with frames left without a mask, where mediapipe is missing).
        max_side: the distance maps' size (long side, px).
        max_spread, chroma: the plain-background key's (``fit.silhouette``).
        mode: "head_neck" (the default, :func:`head_neck_mask`: the face mesh's oval and
            the neck's skin below it, no hair) or "person" (the person mask: a plain
            background keyed out, else the person segmentation; hair included, which
            pulls the face's outline out to the hair's on a face that fills the frame).
        every: mask every n-th frame (1: all).
    """
    T = len(found)
    source = [""] * T
    limits = np.full(T, np.inf)

    def masks():
        n = 0
        for i, img in enumerate(frames):
            if i >= T:
                break
            n += 1
            m = None
            if found[i] and i % max(1, every) == 0:
                if mode == "head_neck":
                    m, limits[i] = head_neck_mask(img, points[i])
                    source[i] = "head and neck"
                else:
                    m = segment_plain_background(img.astype(np.float32) / 255.0, points[i],
                                                 max_spread=max_spread, chroma=chroma)[0]
                    source[i] = "plain background"
                    if m is None and segment:
                        m, source[i] = _segmented(img, points[i]), "segmentation"
            yield m
        yield from [None] * (T - n)  # a clip shorter than its landmarks

    fm = FrameMasks.from_masks(masks(), source, max_side)
    return dataclasses.replace(fm, limit_y=limits, kind=mode)


#: the neck's skin counts where at least this many pixels of it, per outer-eye distance
#: squared, join the face oval's lower half (a collar, a beard's shadow or the frame's
#: edge leave less: the neck is then left out of the term for that frame)
MIN_NECK_AREA = 0.15


def head_neck_mask(img: np.ndarray, points: np.ndarray) -> tuple[np.ndarray | None, float]:
    """The head-and-neck mask of a frame: the face mesh's face oval (MediaPipe, run in the
    landmarks' box) joined to the neck's skin below it (pixels of the face's own skin
    chromaticity, ``vision.segment.skin_colour_mask``, below the mouth, within the oval's
    width widened by a fifth, the part that touches the oval's lower half). Hair is not in
    it: on a face that fills the frame the person mask's border is the hair's, 40-60 px
    outside the jaw (issue 63). Returns (mask (H, W) bool, the lowest row where the
    border is the neck's own; -inf: no neck seen, the face oval alone) or (None, inf)
    where the mesh finds no face. About 60 ms a 512 px frame (no person segmentation)."""
    from scipy import ndimage
    from skimage.draw import polygon

    p = points[np.isfinite(points).all(1)]
    if len(p) < 20:
        return None, np.inf
    box = (*p.min(0), *p.max(0))
    try:
        dense, presence = mesh_landmarks(img, box, passes=1)
    except Exception:  # noqa: BLE001 - no mesh face: no mask (an interruption is not lost:
        return None, np.inf  # the command's handler recorded the signal, see interrupts)
    if presence < 0.5:
        return None, np.inf
    h, w = img.shape[:2]
    oval_pts = dense[ring("FACEMESH_FACE_OVAL"), :2]
    oval = np.zeros((h, w), bool)
    rr, cc = polygon(oval_pts[:, 1] - 0.5, oval_pts[:, 0] - 0.5, (h, w))
    oval[rr, cc] = True
    if oval.sum() < 50:
        return None, np.inf
    iod = float(np.linalg.norm(p[36] - p[45])) if len(p) == 68 else \
        float(np.ptp(oval_pts[:, 0])) / 2.2
    mouth_y = float(np.mean(points[48:68, 1]))
    x0, x1 = oval_pts[:, 0].min(), oval_pts[:, 0].max()
    pad = 0.2 * (x1 - x0)
    within = np.zeros((h, w), bool)
    within[int(max(0, mouth_y)):, int(max(0, x0 - pad)):int(min(w, x1 + pad + 1))] = True
    within &= ~oval
    neck = ndimage.binary_opening(skin_colour_mask(img, dense, within), iterations=1)
    lab, n = ndimage.label(neck)
    rows = np.arange(h)[:, None]
    touch = ndimage.binary_dilation(oval & (rows > mouth_y), iterations=3)
    keep = np.zeros(n + 1, bool)
    keep[np.unique(lab[touch & (lab > 0)])] = True
    keep[0] = False
    neck = keep[lab]
    if neck.sum() >= MIN_NECK_AREA * iod * iod:
        ys = np.flatnonzero(neck.any(1))
        # the neck's border is its own down to where its skin ends (a collar, the
        # frame's edge), less a margin
        return ndimage.binary_fill_holes(oval | neck), float(ys.max()) - 0.1 * iod
    return oval, -np.inf


def _segmented(img: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    try:  # mediapipe missing (ImportError) or a segmentation that fails: the frame is left
        m, _ = person_mask(img, points)  # to the landmarks
    except Exception:  # noqa: BLE001
        return None
    return m


class OutlineTerm:
    """The outline cost of a window of frames, differentiable in the per-frame parameters
    (h, g, t): see the module docstring.

    Args:
        model: the HackModel; person: its :class:`~hack_render.geometry.model.
            PersonalizedHack` at the clip's identity; eta, tau: the larynx (tau (T,)).
        camera: the clip's :class:`~hack_render.track.solve.ClipCamera`.
        masks: :class:`FrameMasks`; scale: (T,) each frame's outer-eye distance (px).
    """

    def __init__(self, model, person, eta: float, tau: np.ndarray, camera, masks: FrameMasks,
                 scale: np.ndarray, cfg: OutlineConfig, robust_knee: float):
        self.model, self.person, self.camera, self.masks = model, person, camera, masks
        self.eta, self.tau = float(eta), np.asarray(tau, np.float64)
        self.cfg, self.knee = cfg, float(robust_knee)
        self.sil = ModelSilhouette(model)
        self.scale = torch.as_tensor(np.asarray(scale, np.float64))
        self.parents = chain_parents(model.parents)
        self.faces = model.faces
        # every 3rd of the silhouette term's inside set (every 9th skin vertex, ~1,200):
        # the one-sided test needs coverage, not density
        self.inside = self.sil.inside.numpy()[::3]
        self.contour_ok = self.neck_v = None
        if masks.kind == "head_neck":
            # the head-and-neck mask's border is the face's and the neck's own outline:
            # only their skin below the brows is read (the scalp, the ears and the chest
            # may lie anywhere: hair or clothes cover them, or the frame's edge)
            regions = model.vertex_region.numpy()
            names = list(model.region_names)
            t = model.template.numpy()
            brow = t[model.landmark_indices.numpy()[17:27], 1].min()
            face_v = (regions == names.index("face")) & (t[:, 1] < brow)
            self.neck_v = regions == names.index("neck")
            self.contour_ok = face_v | self.neck_v
            self.inside = np.flatnonzero(face_v)[::9]
        self.weights_all = model.skinning_weights.double()
        joints = person.joints.double()[None]
        self.nodes = torch.cat([joints[:, :1], joints], 1)

        self.centre = -(R0.double().T @ torch.as_tensor(camera.cam_t, dtype=torch.float64)).numpy()
        self.rest = self.pairs = self.S = None
        self._cache = None   # (window, frames with a mask, their float64 maps)

    def select(self, params) -> None:
        """Re-select every frame's contour and rest mesh at ``params``
        (:class:`~hack_render.track.solve.FrameParams`)."""
        T = params.frames
        rest_all, pairs, ts = [None] * T, [np.zeros((0, 2), np.int64)] * T, [np.zeros(0)] * T
        h, w = self.camera.height, self.camera.width
        for s in range(0, T, _CHUNK):
            e = min(T, s + _CHUNK)
            sl = slice(s, e)
            if not self.masks.has[sl].any():
                continue
            with torch.no_grad():
                out = self.person(
                    psi=torch.as_tensor(params.psi[sl]).float(),
                    theta=distribute_head_rotation(torch.as_tensor(params.h[sl]),
                                                   clamp=False).float(),
                    global_orient=torch.as_tensor(params.g[sl]).float(),
                    transl=torch.as_tensor(params.t[sl]).float(),
                    eta=torch.full((e - s,), self.eta),
                    tau=torch.as_tensor(self.tau[sl]).float())
            for k in range(e - s):
                i = s + k
                if not self.masks.has[i]:
                    continue
                rest_all[i] = out.rest_vertices[k]
                V = out.vertices[k].double()
                n = vertex_normals_torch(V, self.faces).numpy().astype(np.float64)
                px = max(float(self.scale[i]) / 25.0, 1.0)
                pairs[i], ts[i] = self.sil.select_contour(
                    V.numpy(), n, self.centre,
                    lambda X: self.camera.project(torch.as_tensor(X)).numpy(), (h, w), px)
                if self.contour_ok is not None:
                    pairs[i], ts[i] = self._head_neck_contour(V, pairs[i], ts[i], i)
        # the vertices the term reads this round: the contours' and the inside set
        self.S = np.unique(np.concatenate([self.inside] + [p.ravel() for p in pairs]))
        local = np.full(self.model.num_vertices, -1, np.int64)
        local[self.S] = np.arange(len(self.S))
        S = torch.as_tensor(self.S)
        self.weights = self.weights_all[S]
        self.inside_local = torch.as_tensor(local[self.inside])
        self.rest = torch.zeros(T, len(self.S), 3, dtype=torch.float64)
        for i in range(T):
            if rest_all[i] is not None:
                self.rest[i] = rest_all[i][S].double()
        P = max(1, max(len(t) for t in ts))
        self.pairs = torch.zeros(T, P, 2, dtype=torch.long)
        self.t = torch.zeros(T, P, dtype=torch.float64)
        self.valid = torch.zeros(T, P, dtype=torch.float64)
        for i in range(T):
            n = len(ts[i])
            if n:
                self.pairs[i, :n] = torch.as_tensor(local[pairs[i]])
                self.t[i, :n] = torch.as_tensor(ts[i])
                self.valid[i, :n] = 1.0

    def _head_neck_contour(self, V: torch.Tensor, pairs: np.ndarray, t: np.ndarray,
                           i: int) -> tuple[np.ndarray, np.ndarray]:
        """The contour points the head-and-neck mask speaks for: on the face below the
        brows and on the neck, the neck's only where the frame's neck was seen, and none
        below the row where the neck's skin ends (``FrameMasks.limit_y``)."""
        a, b = pairs[:, 0], pairs[:, 1]
        keep = self.contour_ok[a] & self.contour_ok[b]
        limit = float(self.masks.limit_y[i]) if self.masks.limit_y is not None else np.inf
        if limit == -np.inf:   # no neck seen: the face's outline only
            keep &= ~self.neck_v[a] & ~self.neck_v[b]
        elif np.isfinite(limit):
            Vn = V.numpy()
            X = Vn[a] + t[:, None] * (Vn[b] - Vn[a])
            uv = self.camera.project(torch.as_tensor(X)).numpy()
            keep &= uv[:, 1] <= limit
        return pairs[keep], t[keep]

    def points(self, x: torch.Tensor, frames) -> torch.Tensor:
        """(T', |S|, 3) the term's vertices posed by LBS at parameters x (T', D) of
        ``frames`` (a slice or index tensor into the clip)."""
        h, g, t = x[:, :3], x[:, 3:6], x[:, 6:9]
        rot = local_rotations(distribute_head_rotation(h, clamp=False), g)
        _, rel = rigid_transforms(rot, self.nodes.expand(len(x), -1, -1), self.parents)
        return skin(self.rest[frames], self.weights, rel) + t[:, None]

    def _contour(self, P: torch.Tensor, frames) -> torch.Tensor:
        """(T', C, 3) the contour points of ``frames`` (a slice or index tensor) on their
        edges of the posed term vertices P (T', |S|, 3) (padding rows: ``valid`` 0)."""
        pairs, t = self.pairs[frames], self.t[frames]
        a = torch.gather(P, 1, pairs[..., 0:1].expand(-1, -1, 3))
        b = torch.gather(P, 1, pairs[..., 1:2].expand(-1, -1, 3))
        return a + t[..., None] * (b - a)

    def _window_masks(self, sl: slice) -> tuple[torch.Tensor, FrameMasks]:
        """The frames of window ``sl`` with a mask (indices into the clip) and their
        distance maps in float64, converted once per window (the solve evaluates the
        term a hundred times a window; converting the window's whole float16 stack on
        each call took half the stage's time)."""
        key = (sl.start, sl.stop)
        if self._cache is None or self._cache[0] != key:
            idx = torch.as_tensor(np.flatnonzero(self.masks.has[sl]) + (sl.start or 0))
            sdf = self.masks.sdf[idx].to(torch.float64)
            self._cache = key, idx, FrameMasks(sdf, self.masks.scale,
                                               np.ones(len(idx), bool), [])
        return self._cache[1], self._cache[2]

    def frame_costs(self, x: torch.Tensor, sl: slice) -> torch.Tensor:
        """(T',) the outline cost of frames ``sl`` at parameters x (T', D) (0 where a
        frame has no mask: only the frames with one are evaluated)."""
        idx, masks = self._window_masks(sl)
        out = x.new_zeros(len(x))
        if len(idx) == 0:
            return out
        local = idx - (sl.start or 0)
        P = self.points(x[local], idx)
        k = self.knee
        scale = self.scale[idx][:, None]

        def rho(r):
            return k * k * (torch.sqrt(1 + (r / k) ** 2) - 1)

        d, ok = masks.distance(self.camera.project(self._contour(P, idx)))
        w = self.valid[idx] * ok
        contour = (rho(d / scale) * w).sum(1) / w.sum(1).clamp_min(1.0)
        d, ok = masks.distance(self.camera.project(P[:, self.inside_local]))
        inside = (rho(torch.relu(d) / scale) * ok).sum(1) / ok.sum(1).clamp_min(1)
        cost = 68.0 * (self.cfg.contour * contour + self.cfg.inside * inside)
        return out.index_add(0, local, cost)

    def distances(self, params) -> np.ndarray:
        """(T,) each frame's mean absolute distance (px) of its contour points from the
        mask's border at ``params`` (NaN where no mask)."""
        with torch.no_grad():
            x = torch.as_tensor(params.vector(), dtype=torch.float64)
            P = self.points(x, slice(None))
            d, ok = self.masks.distance(self.camera.project(self._contour(P, slice(None))))
            w = self.valid * ok
            out = ((d.abs() * w).sum(1) / w.sum(1).clamp_min(1.0)).numpy()
        return np.where(self.masks.has & (w.sum(1).numpy() > 0), out, np.nan)


@dataclass
class OutlineResult:
    """What the outline stage did: per-frame contour distance (px, mean absolute) before
    and after, and the frames' mask sources."""

    before: np.ndarray
    after: np.ndarray
    source: list

    def report(self) -> dict:
        has = np.isfinite(self.after)
        kinds = sorted({s for s in self.source if s})
        return {"frames_with_mask": int(has.sum()), "mask_sources": kinds,
                "contour_px_before": _med(self.before), "contour_px_after": _med(self.after)}


def _med(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return round(float(np.median(x)), 3) if len(x) else None


def refine_outline(rig, camera, obs, found, weights, params, g_ref, tcfg, model, beta,
                   eta: float, tau: np.ndarray, masks: FrameMasks,
                   cfg: OutlineConfig | None = None, progress: bool = True):
    """The tracked parameters with the neck placed on the person's outline: the joint
    solve (:func:`~hack_render.track.solve.solve_clip`) with :class:`OutlineTerm` added,
    ``cfg.rounds`` times. Returns (FrameParams, :class:`OutlineResult`)."""

    cfg = cfg or OutlineConfig()
    if not masks.has.any():
        nan = np.full(params.frames, np.nan)
        return params, OutlineResult(nan, nan, masks.source)
    person = model.personalize(beta.detach().float())
    iod = np.linalg.norm(obs[:, 36] - obs[:, 45], axis=1)
    iod = np.where(found & np.isfinite(iod), iod, np.nanmedian(iod[found]))
    term = OutlineTerm(model, person, eta, tau, camera, masks, iod, cfg, tcfg.robust_knee)
    joint = dataclasses.replace(tcfg, joint_iterations=cfg.iterations)
    before = None
    # many small tensor ops: one thread is faster than two here (and far faster on a
    # loaded machine, where two spin against each other)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for _ in range(max(1, cfg.rounds)):
            term.select(params)
            if before is None:
                before = term.distances(params)
            params = solve_clip(rig, camera, obs, found, weights, params, g_ref, joint,
                                progress, extra=lambda x, sl: term.frame_costs(x, sl).sum())
        term.select(params)
    finally:
        torch.set_num_threads(threads)
    return params, OutlineResult(before, term.distances(params), masks.source)
