"""The larynx's slide tau per frame from plain video, by analysis by synthesis of the neck's
shading (the photometric tau of issue 24; the paper's Eq. 13 kernel needs normal maps,
:func:`hack_render.motion.larynx_motion.track_larynx`).

Per frame, with the tracked identity, pose and expression:

1. The mesh is built at a grid of slides over ``TAU_RANGE_M`` (one batched forward) and
   ray cast once (at the grid's middle) in a window around the larynx region: each pixel
   keeps its triangle and barycentric weights, so each slide's surface normals under the
   pixels come from that slide's vertex normals (the bump moves the surface by a few
   millimetres at most: the parallax is far below a pixel at video distances).
2. The frame's luminance over the pixels that see the larynx region is fitted, for each
   slide, by a linear shading model of the surface normal ``n`` and the mirrored view
   direction ``r``: order-2 spherical harmonics of ``n`` (diffuse light from any distant
   surround, 9 terms) and of ``r`` (a broad specular lobe, 8 more), by iteratively
   reweighted least squares (Tukey's biweight) so that cast shadows and highlights the
   model cannot hold do not count. The light is fitted anew for every slide and frame,
   so a light that changes over the clip costs nothing, and the albedo is taken as
   uniform over the region (its slow variation goes into the light). What is left, the
   truncated squared residual, is the frame's cost of that slide: a bump shaded where the
   image shows none, or none where it shows one, costs.
3. Over the clip, a dynamic programme on a fine grid picks the path of least summed
   relative cost plus a velocity penalty: the whole clip is seen at once, so the estimate
   does not lag, and frames whose cost curve is flat (a light from the camera leaves the
   bump unshaded; lost faces) follow their neighbours.

Everything here needs only the tracked parameters and the frames; the renderer's ray caster
(:class:`~hack_render.render.mesh_views.MeshViews`) finds the triangles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from hack_render.fit.camera import R0
from hack_render.geometry.larynx import TAU_RANGE_M
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.render.mesh_views import MeshViews
from scenes.cameras import Camera


@dataclass
class LarynxTrackConfig:
    """Settings of the photometric tau.

    Attributes:
        step: spacing of the slides each frame is scored at (metres).
        fine_step: spacing of the clip-wide dynamic programme's grid (metres).
        margin: pixels around the larynx region's projected box.
        min_pixels: frames whose larynx region covers fewer pixels are scored as lost.
        max_pixels: at most this many pixels are scored (an even spread of them).
        cache_frames: clips up to this long keep their scored pixels for the second pass
            (about 0.6 MB a frame); longer ones are read and ray cast again.
        speed: the larynx speed (m/s) whose velocity penalty equals ``smoothness``
            relative cost per frame (a swallow lifts it ~2 cm in ~0.3 s: ~0.07 m/s).
        smoothness: weight of the velocity penalty.
        irls: reweighting rounds of the robust shading fit.
    """

    step: float = 0.0025
    fine_step: float = 0.0005
    margin: int = 6
    min_pixels: int = 150
    max_pixels: int = 4000
    cache_frames: int = 600
    speed: float = 0.05
    smoothness: float = 0.02
    irls: int = 4


@dataclass
class LarynxTrack:
    """The photometric tau of a clip.

    Attributes:
        tau: (T,) the slide per frame, metres (the programme's path).
        grid: (C,) the slides each frame was scored at.
        cost: (T, C) each frame's relative cost curve (cost / its minimum - 1; NaN rows
            where the frame was not scored).
        confidence: (T,) the curve's mean rise 5 mm either side of its minimum (0 where
            not scored): how sharply the frame alone tells the slide.
        pixels: (T,) pixels of the larynx region scored per frame.
        fallback: the neck was seen in too few frames: ``tau`` is the keyframe fit's
            (``pipeline.larynx_or_fixed``), ``confidence`` 0 throughout.
    """

    tau: np.ndarray
    grid: np.ndarray
    cost: np.ndarray
    confidence: np.ndarray
    pixels: np.ndarray
    fallback: bool = False


def _sh9(d: np.ndarray) -> np.ndarray:
    """Real spherical harmonics to order 2 (unnormalised) of unit vectors (P, 3) -> (P, 9)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, y * z, x * z, x * x - y * y,
                     3 * z * z - 1], 1)


def shading_basis(normals: np.ndarray, view: np.ndarray) -> np.ndarray:
    """(P, 17) the shading model's columns: SH to order 2 of the unit normals (P, 3) and,
    without the constant, of the view direction (P, 3, unit, toward the camera) mirrored
    about them."""
    r = 2 * (normals * view).sum(1, keepdims=True) * normals - view
    return np.concatenate([_sh9(normals), _sh9(r)[:, 1:]], 1)


def robust_shading_fit(A: np.ndarray, b: np.ndarray, rounds: int = 4):
    """Tukey-biweight IRLS of b (P,) on the columns of A (P, K): (residual (P,), robust
    scale). Each round solves the weighted normal equations (K is small; an SVD per round
    costs 50x more)."""
    w = np.ones(len(b))
    r, s = b, 1.0
    ridge = 1e-9 * np.eye(A.shape[1])
    for _ in range(max(1, rounds)):
        Aw = A * w[:, None]
        G = Aw.T @ A
        c = np.linalg.solve(G + ridge * max(float(np.trace(G)), 1e-12), Aw.T @ b)
        r = b - A @ c
        s = 1.4826 * float(np.median(np.abs(r))) + 1e-9
        w = np.clip(1 - (r / (4.685 * s)) ** 2, 0, None)
    return r, s


def srgb_luminance(frame: np.ndarray) -> np.ndarray:
    """(H, W) linear luminance (Rec. 709) of an 8-bit sRGB frame (H, W, 3)."""
    x = frame[..., :3].astype(np.float64) / 255.0
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


class _Region:
    """The larynx region's pixels and the vertices and faces its normals need."""

    def __init__(self, model):
        faces = model.faces.numpy().astype(np.int64)
        n = model.template.shape[0]
        inside = np.zeros(n, bool)
        inside[model.larynx_vertices.numpy()] = True
        self.faces = faces
        self.face_in = inside[faces].all(1)                     # faces scored
        touch = inside[faces].any(1)                            # faces whose normals count
        self.sub_faces = faces[touch]
        self.verts = np.unique(self.sub_faces)                  # vertices normals are taken at
        self.local = np.full(n, -1, np.int64)
        self.local[self.verts] = np.arange(len(self.verts))
        self.larynx_vertices = np.flatnonzero(inside)
        # the larynx chart (metres) at every region vertex (others unused: zeros)
        self.chart = np.zeros((n, 2))
        self.chart[model.larynx_vertices.numpy()] = model.larynx_uv.double().numpy()

    def vertex_normals(self, V: torch.Tensor) -> torch.Tensor:
        """(C, n_sub, 3) unit normals at ``verts`` of the posed meshes V (C, N, 3); exact
        for the region's vertices (every face around them is counted)."""
        f = torch.as_tensor(self.sub_faces)
        v = V[:, f]  # (C, F, 3, 3)
        fn = torch.cross(v[:, :, 1] - v[:, :, 0], v[:, :, 2] - v[:, :, 0], dim=-1)
        out = V.new_zeros(V.shape[0], len(self.verts), 3)
        idx = torch.as_tensor(self.local[self.sub_faces.ravel()])
        out.index_add_(1, idx, fn.repeat_interleave(3, dim=1))
        return out / out.norm(dim=-1, keepdim=True).clamp_min(1e-12)


@dataclass
class _Sample:
    """One frame's scored pixels: chart position (P, 2, metres), luminance (P,), unit view
    direction (P, 3) and the unit normal under each pixel at every slide (C, P, 3)."""

    chart: np.ndarray
    lum: np.ndarray
    view: np.ndarray
    normals: np.ndarray


def frame_sample(views, camera, V: torch.Tensor, luminance: np.ndarray, region: _Region,
                 cfg: LarynxTrackConfig) -> tuple[_Sample | None, int]:
    """One frame's scored pixels (None below ``cfg.min_pixels``) and their count.

    ``views``: a :class:`~hack_render.render.mesh_views.MeshViews` of the model's faces at
    the frame's size; ``camera``: the frame's :class:`~scenes.cameras.Camera`; ``V``
    (C, N, 3) the posed meshes, one per slide."""
    C = V.shape[0]
    mid = V[C // 2].double().numpy()
    box = np.concatenate([camera.project(V[k, region.larynx_vertices].double().numpy())
                          for k in (0, C - 1)])
    box = box[np.isfinite(box).all(1)]
    W, H = views.width, views.height
    if len(box) == 0:
        return None, 0
    x0 = int(np.clip(np.floor(box[:, 0].min()) - cfg.margin, 0, W - 1))
    y0 = int(np.clip(np.floor(box[:, 1].min()) - cfg.margin, 0, H - 1))
    x1 = int(np.clip(np.ceil(box[:, 0].max()) + cfg.margin, x0 + 1, W))
    y1 = int(np.clip(np.ceil(box[:, 1].max()) + cfg.margin, y0 + 1, H))
    views.set_vertices(mid, region.faces)
    tri, bary, hit = views.trace_triangles(camera, (x0, y0, x1, y1))
    use = hit & region.face_in[tri]
    npix = int(use.sum())
    if npix < cfg.min_pixels:
        return None, npix
    keep = np.flatnonzero(use.ravel())
    keep = keep[np.linspace(0, len(keep) - 1, min(len(keep), cfg.max_pixels)).astype(int)]
    t, b = tri.ravel()[keep], bary.reshape(-1, 3)[keep]
    corners = region.local[region.faces[t]]                      # (P, 3) local ids
    pos = np.einsum("pk,pkc->pc", b, mid[region.faces[t]])
    view = camera.center - pos
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    normals = region.vertex_normals(V.double()).numpy()          # (C, n_sub, 3)
    n = np.einsum("pk,cpkd->cpd", b, normals[:, corners])
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    chart = np.einsum("pk,pkc->pc", b, region.chart[region.faces[t]])
    return _Sample(chart, luminance[y0:y1, x0:x1].ravel()[keep], view.astype(np.float32),
                   n.astype(np.float32)), npix


def _fit(sample: _Sample, albedo: np.ndarray, k: int, rounds: int):
    """The robust shading fit of the frame's luminance at slide ``k``: (residual, scale)."""
    A = shading_basis(sample.normals[k].astype(np.float64), sample.view.astype(np.float64))
    return robust_shading_fit(A * albedo[:, None], sample.lum, rounds)


def sample_costs(sample: _Sample, albedo: np.ndarray | None,
                 cfg: LarynxTrackConfig) -> np.ndarray:
    """(C,) the frame's cost of each slide: the truncated squared residual of the robust
    fit of its luminance by ``albedo`` (P,; None: uniform) times the shading model, one
    truncation for all slides."""
    a = np.ones(len(sample.lum)) if albedo is None else albedo
    fits = [_fit(sample, a, k, cfg.irls) for k in range(sample.normals.shape[0])]
    cap = (2.5 * float(np.median([s for _, s in fits]))) ** 2
    return np.array([np.mean(np.minimum(r * r, cap)) for r, _ in fits])


def fitted_shading(sample: _Sample, k: int, cfg: LarynxTrackConfig):
    """The shading fitted to the frame at slide ``k`` with a uniform skin (P,), and the
    robust fit's weights (P,): what :class:`SkinAlbedo` divides the luminance by."""
    r, s = _fit(sample, np.ones(len(sample.lum)), k, cfg.irls)
    return sample.lum - r, np.clip(1 - (r / (4.685 * s)) ** 2, 0, None)


class SkinAlbedo:
    """The skin's relative albedo over the larynx chart (``model.larynx_uv``, metres), on
    a grid of ``cell`` metres: the robust mean over frames of luminance over fitted
    shading (moles and freckles ride on the skin; the bump's shading slides over it)."""

    def __init__(self, region: _Region, cell: float = 0.001):
        lo = region.chart[region.larynx_vertices].min(0)
        hi = region.chart[region.larynx_vertices].max(0)
        self.lo, self.cell = lo, cell
        self.shape = tuple(int(x) for x in np.ceil((hi - lo) / cell) + 1)
        self.sum = np.zeros(self.shape[0] * self.shape[1])
        self.weight = np.zeros_like(self.sum)

    def _cells(self, chart: np.ndarray) -> np.ndarray:
        ij = np.clip(np.floor((chart - self.lo) / self.cell).astype(np.int64), 0,
                     np.array(self.shape) - 1)
        return ij[:, 0] * self.shape[1] + ij[:, 1]

    def add(self, chart: np.ndarray, ratio: np.ndarray, weight: np.ndarray) -> None:
        c = self._cells(chart)
        ok = np.isfinite(ratio) & (weight > 0)
        self.sum += np.bincount(c[ok], weight[ok] * np.clip(ratio[ok], 0.5, 2.0),
                                minlength=len(self.sum))
        self.weight += np.bincount(c[ok], weight[ok], minlength=len(self.sum))

    def __call__(self, chart: np.ndarray) -> np.ndarray:
        """(P,) relative albedo at chart points (1 where no frame saw the cell)."""
        c = self._cells(chart)
        w = self.weight[c]
        a = np.where(w > 0, self.sum[c] / np.maximum(w, 1e-12), 1.0)
        seen = self.weight > 0
        mean = self.sum[seen].sum() / max(self.weight[seen].sum(), 1e-12) if seen.any() else 1.0
        return a / mean


def smooth_path(cost: np.ndarray, grid: np.ndarray, fps: float,
                cfg: LarynxTrackConfig) -> np.ndarray:
    """The clip's tau (T,): the least-cost path through the relative cost curves (T, C)
    on ``grid`` (C,), resampled to ``cfg.fine_step``, plus ``cfg.smoothness`` times the
    squared velocity in units of ``cfg.speed``. NaN rows cost nothing (carried by the
    penalty). Exact (a Viterbi pass)."""
    from scipy.interpolate import CubicSpline

    fine = np.arange(grid[0], grid[-1] + cfg.fine_step / 2, cfg.fine_step)
    T = len(cost)
    data = np.zeros((T, len(fine)))
    for t in range(T):
        if np.isfinite(cost[t]).all():
            data[t] = np.maximum(CubicSpline(grid, cost[t])(fine), 0.0)
    step = (fine[:, None] - fine[None]) * fps / cfg.speed
    trans = cfg.smoothness * step ** 2                           # (to, from)
    acc = data[0].copy()
    back = np.zeros((T, len(fine)), np.int64)
    for t in range(1, T):
        tot = acc[None] + trans
        back[t] = tot.argmin(1)
        acc = tot[np.arange(len(fine)), back[t]] + data[t]
    path = np.zeros(T, np.int64)
    path[-1] = int(acc.argmin())
    for t in range(T - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return fine[path]


def slid_meshes(model, person, params, theta: torch.Tensor, i: int, eta: float,
                taus: torch.Tensor, d_tau: torch.Tensor) -> torch.Tensor:
    """(C, N, 3) frame ``i``'s posed meshes at the slides ``taus`` (C,): one forward at the
    first slide, and the others' larynx displacements ``d_tau`` (C, M, 3, rest space) posed
    by the blend of the joints' rotations (LBS is linear in the rest mesh, and the pose
    correctives do not depend on tau); equal to C full forwards (tests)."""
    with torch.no_grad():
        g = torch.as_tensor(params.g[i]).float()[None]
        out = person(psi=torch.as_tensor(params.psi[i]).float()[None], theta=theta[i][None],
                     global_orient=g, transl=torch.as_tensor(params.t[i]).float()[None],
                     eta=torch.tensor([eta]), tau=taus[:1])
        rot = local_rotations(theta[i][None], g)
        j = person.joints[None]
        _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(model.parents))
        lv = model.larynx_vertices
        blend = torch.einsum("vk,kij->vij", model.skinning_weights[lv].float(),
                             rel[0, :, :3, :3])
        V = out.vertices.expand(len(taus), -1, -1).clone()
        V[:, lv] += torch.einsum("vij,cvj->cvi", blend, d_tau - d_tau[:1])
    return V


def _relative(raw: np.ndarray) -> np.ndarray:
    rel = np.full_like(raw, np.nan)
    ok = np.isfinite(raw).all(1)
    rel[ok] = raw[ok] / raw[ok].min(1, keepdims=True) - 1
    return rel


def track_tau(frames, model, beta: torch.Tensor, eta: float, params, camera, found,
              fps: float, cfg: LarynxTrackConfig | None = None,
              progress: bool = True) -> LarynxTrack:
    """The photometric tau of a tracked clip: a first pass with a uniform skin, the skin's
    albedo over the larynx chart from it (:class:`SkinAlbedo`), then a second pass with
    that albedo.

    Args:
        frames: a callable returning an iterator of (H, W, 3) uint8 sRGB frames at the
            tracker's working size (``Clip.read``); called again for the second pass
            when the clip is longer than ``cfg.cache_frames``.
        model: the :class:`~hack_render.geometry.model.HackModel`; beta (1, S); eta.
        params: the tracker's :class:`~hack_render.track.solve.FrameParams`.
        camera: the clip's :class:`~hack_render.track.solve.ClipCamera`.
        found: (T,) frames with a face (others are not scored).
        fps: the clip's frame rate (the velocity penalty is per second).
    """

    cfg = cfg or LarynxTrackConfig()
    lo, hi = TAU_RANGE_M
    grid = np.linspace(lo, hi, round((hi - lo) / cfg.step) + 1)
    C, T = len(grid), params.frames
    region = _Region(model)
    K = np.array([[camera.focal, 0, camera.width / 2], [0, camera.focal, camera.height / 2],
                  [0, 0, 1.0]])
    cam = Camera(K, R0.double().numpy(), np.asarray(camera.cam_t, np.float64),
                 camera.width, camera.height, "clip")
    person = model.personalize(beta.detach().float())
    theta = distribute_head_rotation(torch.as_tensor(params.h), clamp=False).float()
    taus = torch.as_tensor(grid, dtype=torch.float32)
    with torch.no_grad():
        d_tau = model.larynx_displacement(beta.detach().float().expand(C, -1),
                                          torch.full((C,), float(eta)),
                                          taus)  # (C, M, 3) rest-space
    views = None
    cache = T <= cfg.cache_frames
    samples: dict[int, _Sample] = {}
    pixels = np.zeros(T, np.int64)

    def scan(desc: str):
        nonlocal views
        for i, frame in enumerate(tqdm(frames(), total=T, desc=desc, unit="frame",
                                       disable=not progress, leave=False)):
            if i >= T:
                break
            if not found[i]:
                continue
            V = slid_meshes(model, person, params, theta, i, float(eta), taus, d_tau)
            if views is None:
                views = MeshViews(V[C // 2].double().numpy(), region.faces,
                                  width=camera.width, height=camera.height)
            smp, pixels[i] = frame_sample(views, cam, V, srgb_luminance(frame), region, cfg)
            if smp is not None:
                yield i, smp

    # pass 1: a uniform skin
    raw = np.full((T, C), np.nan)
    for i, smp in scan("larynx (1/2)"):
        raw[i] = sample_costs(smp, None, cfg)
        if cache:
            samples[i] = smp
    tau = smooth_path(_relative(raw), grid, fps, cfg)
    # the skin's albedo over the chart: luminance over the shading fitted at the path
    albedo = SkinAlbedo(region)
    todo = samples.items() if cache else scan("larynx albedo")
    for i, smp in todo:
        k = int(np.argmin(np.abs(grid - tau[i])))
        shade, w = fitted_shading(smp, k, cfg)
        albedo.add(smp.chart, smp.lum / np.maximum(shade, 1e-6), w)
    # pass 2: with the albedo
    raw = np.full((T, C), np.nan)
    for i, smp in (samples.items() if cache else scan("larynx (2/2)")):
        raw[i] = sample_costs(smp, albedo(smp.chart), cfg)
    rel = _relative(raw)
    conf = np.zeros(T)
    for i in np.flatnonzero(np.isfinite(rel).all(1)):
        k = int(np.argmin(rel[i]))
        side = [rel[i, j] for j in (k - round(0.005 / cfg.step),
                                    k + round(0.005 / cfg.step)) if 0 <= j < C]
        conf[i] = float(np.mean(side)) if side else 0.0
    tau = smooth_path(rel, grid, fps, cfg)
    return LarynxTrack(tau=tau, grid=grid, cost=rel, confidence=conf, pixels=pixels)
