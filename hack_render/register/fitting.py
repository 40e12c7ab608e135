"""The registration's optimisation: the model's parameters, then free-form offsets.

Stages (each :func:`hack_render.fit.stages.run_stage`, Adam, best iterate kept):

1. ``rigid``: global rotation and translation (the similarity from the landmarks is the
   start), by landmarks and the two-way surface distance.
2. ``model``: beta (the first ``num_shape`` components), psi, theta over all 8 joints,
   eta, tau and the global pose, by the same terms plus priors and the rotation limits.
3. ``free``: per-vertex offsets on the skin, with a Laplacian (smoothness) regulariser:
   the detailed registration in the model's topology.

The data terms (:class:`TwoWayDistance`): scan-to-model (each scan sample to the
model's nearest skin or eye vertex, point-to-plane along that vertex's normal) and
model-to-scan (each skin vertex to the scan's nearest surface sample, point-to-plane
along the scan's normal), both robust (Huber in millimetres) and trimmed: pairs farther
than ``max_distance``, model vertices whose nearest scan point lies on a scan boundary
(holes, a neck cut higher than the model's) or faces the other way, and the worst
``trim`` fraction are left out. Correspondences are found anew every iteration with
KD-trees (scipy's ``cKDTree``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.fit.stages import run_stage
from hack_render.geometry.larynx import ETA_DEFAULT, clamp_larynx, larynx_limit_penalty
from hack_render.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from hack_render.geometry.skeleton import rotation_limit_penalty
from hack_render.register.scan import SurfaceIndex, vertex_normals

#: vertex groups of the model's outer skin (the part a scan sees)
SKIN_GROUPS = ("face", "head_and_neck")
#: also candidates for scan points (a scan sees the eyes)
EYE_GROUPS = ("eyeball_left", "eyeball_right")


@dataclass
class RegisterConfig:
    """Weights and schedule. Distances are in millimetres inside the losses.

    Presets: ``default`` (this module's terms) and ``paper`` (the weights of the paper's protocol, flame-fitting's scan fitting:
    scan-to-mesh 2, landmarks 0.01, shape 5e-5 on the first 100 components, on sums of
    squared distances in metres; no model-to-scan term).
    """

    preset: str = "default"
    num_shape: int = 100
    joints: bool = True  # False: the linear model (identity + expression, rigid head)
    expression: bool = True
    larynx: bool = True
    free_form: bool = True
    rigid_iterations: int = 50
    model_iterations: int = 220
    free_iterations: int = 150
    lr_pose: float = 0.01
    lr_shape: float = 0.05
    lr_free: float = 2e-4  # metres per step
    w_s2m: float = 1.0
    w_m2s: float = 1.0
    w_lmk: float = 0.05
    w_jaw: float = 0.2  # jaw-line landmarks relative to the inner ones
    w_shape: float = 2e-3
    w_expr: float = 2e-3
    w_theta: float = 1e-2
    w_limits: float = 10.0
    w_laplacian: float = 20.0
    w_offset: float = 1e-3
    huber_mm: float = 2.0
    trim: float = 0.05
    max_distance: float = 0.02  # metres
    scan_points: int = 20_000  # scan samples in the scan-to-model term
    sum_metres: bool = False  # the paper's forms: sums of squares in metres
    seed: int = 0

    @classmethod
    def preset_named(cls, name: str, **overrides) -> RegisterConfig:
        if name == "default":
            return replace(cls(), **overrides)
        if name == "paper":
            base = cls(preset="paper", w_s2m=2.0, w_m2s=0.0, w_lmk=0.01, w_shape=5e-5,
                       num_shape=100, sum_metres=True, trim=0.0)
            return replace(base, **overrides)
        raise HackError(f"--preset: expected default or paper, found {name!r}.")


@dataclass
class Correspondence:
    """The data terms' state and the model vertex subsets."""

    skin: torch.Tensor  # (S,) model vertex ids of the skin
    candidates: torch.Tensor  # (C,) model vertex ids scan points may match (skin + eyes)
    skin_faces: np.ndarray  # (F, 3) faces in model ids, all corners in the skin
    cand_faces: np.ndarray  # (F', 3) faces whose corners are all candidates
    scan_points: np.ndarray  # (M, 3) the scan samples of the scan-to-model term
    index: SurfaceIndex


def model_subsets(model) -> tuple[np.ndarray, np.ndarray]:
    """(skin ids, candidate ids) of a model: outer skin, and skin + eyeballs."""
    groups = model.vertex_group.numpy()
    names = model.group_names
    skin = np.flatnonzero(np.isin(groups, [names.index(g) for g in SKIN_GROUPS]))
    eyes = np.flatnonzero(np.isin(groups, [names.index(g) for g in EYE_GROUPS if g in names]))
    return skin, np.union1d(skin, eyes)


def faces_within(faces: np.ndarray, ids: np.ndarray) -> np.ndarray:
    keep = np.zeros(int(faces.max()) + 1, bool)
    keep[ids] = True
    return faces[keep[faces].all(1)]


def make_correspondence(model, index: SurfaceIndex, cfg: RegisterConfig) -> Correspondence:
    skin, cand = model_subsets(model)
    faces = model.faces.numpy()
    rng = np.random.default_rng(cfg.seed)
    pts = index.points
    take = rng.choice(len(pts), size=min(cfg.scan_points, len(pts)), replace=False)
    return Correspondence(torch.as_tensor(skin), torch.as_tensor(cand), faces_within(faces, skin),
                          faces_within(faces, cand), pts[np.sort(take)], index)


def huber(r_mm: torch.Tensor, delta: float) -> torch.Tensor:
    a = r_mm.abs()
    return torch.where(a <= delta, 0.5 * a ** 2, delta * (a - 0.5 * delta))


def _trimmed(d: np.ndarray, ok: np.ndarray, trim: float) -> np.ndarray:
    """ok with the worst ``trim`` fraction of the ok distances removed."""
    if trim <= 0 or ok.sum() < 10:
        return ok
    cut = np.quantile(d[ok], 1.0 - trim)
    return ok & (d <= cut)


class TwoWayDistance:
    """The robust, trimmed two-way point-to-plane distance between model and scan."""

    def __init__(self, corr: Correspondence, cfg: RegisterConfig):
        self.c, self.cfg = corr, cfg

    def _loss(self, r_mm: torch.Tensor, diff_mm: torch.Tensor, verts: torch.Tensor) -> torch.Tensor:
        """Point-to-plane residuals r (mm) and the full differences (mm) -> the term: mean
        Huber plus 1 % of the mean squared point-to-point distance (against sliding), or
        for the paper's protocol the plain sum of squared distances in metres."""
        if not len(r_mm):
            return verts.sum() * 0
        if self.cfg.sum_metres:
            return ((diff_mm / 1000.0) ** 2).sum()
        return huber(r_mm, self.cfg.huber_mm).mean() + 0.01 * (diff_mm ** 2).sum(1).mean()

    def __call__(self, verts: torch.Tensor) -> dict[str, torch.Tensor]:
        """verts: (N, 3) posed model vertices, metres -> {"m2s", "s2m"} losses (mm^2 scale)."""
        from scipy.spatial import cKDTree

        c, cfg = self.c, self.cfg
        v_np = verts.detach().double().numpy()
        normals = vertex_normals(v_np, c.cand_faces)  # skin faces are among them
        out = {}
        if cfg.w_m2s > 0:
            skin = c.skin.numpy()
            vs = v_np[skin]
            n_model = normals[skin]
            d, idx = c.index.nearest(vs, cfg.max_distance)
            ok = np.isfinite(d)
            idx_ok = np.where(ok, idx, 0)
            ok &= ~c.index.near_boundary[idx_ok]
            ok &= (n_model * c.index.normals[idx_ok]).sum(1) > 0.3
            ok = _trimmed(d, ok, cfg.trim)
            sel = torch.as_tensor(np.flatnonzero(ok))
            target = torch.as_tensor(c.index.points[idx_ok[ok]], dtype=verts.dtype)
            normal = torch.as_tensor(c.index.normals[idx_ok[ok]], dtype=verts.dtype)
            diff = verts.index_select(0, c.skin[sel]) - target
            r = 1000.0 * (diff * normal).sum(1)
            tangential = 1000.0 * diff
            out["m2s"] = self._loss(r, tangential, verts)
            self.m2s_used = int(ok.sum())
        if cfg.w_s2m > 0:
            cand = c.candidates.numpy()
            vc = v_np[cand]
            n_model = normals[cand]
            d, j = cKDTree(vc).query(c.scan_points, k=1, distance_upper_bound=cfg.max_distance)
            ok = _trimmed(d, np.isfinite(d), cfg.trim)
            j = np.where(ok, j, 0)
            sel = np.flatnonzero(ok)
            p = torch.as_tensor(c.scan_points[sel], dtype=verts.dtype)
            n = torch.as_tensor(n_model[j[sel]], dtype=verts.dtype)
            diff = p - verts.index_select(0, c.candidates[torch.as_tensor(j[sel])])
            r = 1000.0 * (diff * n).sum(1)
            out["s2m"] = self._loss(r, 1000.0 * diff, verts)
            self.s2m_used = int(ok.sum())
        return out


def uniform_laplacian(faces: np.ndarray, ids: np.ndarray, n: int) -> torch.Tensor:
    """Sparse (S, S) uniform graph Laplacian L = I - D^-1 A over the vertices ``ids``
    (model ids) using the edges of ``faces`` (model ids, all corners in ``ids``)."""
    local = np.full(n, -1, np.int64)
    local[ids] = np.arange(len(ids))
    f = local[faces]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, 1), axis=0)
    i = np.concatenate([e[:, 0], e[:, 1]])
    j = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(i, minlength=len(ids)).astype(np.float64)
    w = -1.0 / np.maximum(deg[i], 1)
    rows = np.concatenate([i, np.arange(len(ids))])
    cols = np.concatenate([j, np.arange(len(ids))])
    vals = np.concatenate([w, np.where(deg > 0, 1.0, 0.0)])
    return torch.sparse_coo_tensor(np.stack([rows, cols]), vals, (len(ids), len(ids)),
                                   check_invariants=True).coalesce()


@dataclass
class RegisterState:
    """What is optimised. All tensors float32 leaves (B = 1)."""

    beta: torch.Tensor
    psi: torch.Tensor
    theta: torch.Tensor
    global_orient: torch.Tensor
    transl: torch.Tensor
    eta: torch.Tensor
    tau: torch.Tensor
    offsets: torch.Tensor  # (S, 3) metres, on the skin vertices
    reports: list = field(default_factory=list)
    head_orient: torch.Tensor | None = None  # optimised instead of global_orient: see
    # global_from_head

    def params(self) -> dict:
        """The model's parameters as a parameter-file dict (lists)."""
        return {"beta": self.beta[0].tolist(), "psi": self.psi[0].tolist(),
                "theta": self.theta[0].tolist(), "global_orient": self.global_orient[0].tolist(),
                "transl": self.transl[0].tolist(), "eta": float(self.eta[0]),
                "tau": float(self.tau[0])}


def initial_state(model, num_shape: int, R: np.ndarray) -> RegisterState:
    """Zeros, eta at its default, the global rotation from the alignment (model -> scan)."""
    z = lambda *s: torch.zeros(*s, dtype=torch.float32)
    go = matrix_to_axis_angle(torch.as_tensor(R, dtype=torch.float32)[None])
    skin, _ = model_subsets(model)
    return RegisterState(z(1, num_shape), z(1, model.num_expressions), z(1, 8, 3), go.clone(),
                         z(1, 3), torch.full((1,), ETA_DEFAULT), z(1), z(len(skin), 3))


def global_from_head(head_orient: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """The root rotation (B, 3) that leaves the skull turned by ``head_orient`` (B, 3) in
    the world whatever the joints ``theta`` (B, 8, 3): R_root = R_head (R_1 ... R_8)^T.

    Optimising the head's orientation and the joints, rather than the root's and the
    joints, makes "the neck turned, the head where it is" one coordinate instead of a
    narrow valley between two (a scan is aligned by its face, so a turned neck starts as
    a turned torso)."""
    chain = axis_angle_to_matrix(theta)  # (B, 8, 3, 3), c7-t1 ... o-c1
    total = chain[:, 0]
    for k in range(1, chain.shape[1]):
        total = total @ chain[:, k]
    return matrix_to_axis_angle(axis_angle_to_matrix(head_orient) @ total.transpose(1, 2))


def posed_vertices(model, st: RegisterState, skin: torch.Tensor, free: bool) -> tuple:
    if st.head_orient is not None:
        st.global_orient = global_from_head(st.head_orient, st.theta)
    out = model(beta=st.beta, psi=st.psi, theta=st.theta, global_orient=st.global_orient,
                transl=st.transl, eta=st.eta, tau=st.tau)
    v = out.vertices[0]
    if free:
        v = v.index_add(0, skin, st.offsets)
    return v, out.landmarks[0]


def run_registration(model, index: SurfaceIndex, landmarks: np.ndarray | None,
                     landmark_ids: tuple[int, ...], st: RegisterState, cfg: RegisterConfig,
                     progress: bool = True) -> RegisterState:
    """Fit ``st`` to the scan (in the model's frame: the scan already moved there)."""
    corr = make_correspondence(model, index, cfg)
    dist = TwoWayDistance(corr, cfg)
    lmk = None if landmarks is None else torch.as_tensor(landmarks, dtype=torch.float32)
    lmk_w = torch.ones(len(landmark_ids))
    lmk_w[torch.as_tensor(landmark_ids) < 17] = cfg.w_jaw
    lids = torch.as_tensor(landmark_ids)

    def data_terms(v, lm) -> dict:
        terms = dist(v)
        out = {}
        if "s2m" in terms:
            out["E_s2m"] = cfg.w_s2m * terms["s2m"]
        if "m2s" in terms:
            out["E_m2s"] = cfg.w_m2s * terms["m2s"]
        if lmk is not None and cfg.w_lmk > 0:
            if cfg.sum_metres:
                out["E_lmk"] = cfg.w_lmk * ((lm[lids] - lmk) ** 2).sum()
            else:
                e = ((1000.0 * (lm[lids] - lmk)) ** 2).sum(1)
                out["E_lmk"] = cfg.w_lmk * (lmk_w * e).sum() / lmk_w.sum()
        return out

    def priors() -> dict:
        out = {"E_shape": cfg.w_shape * (st.beta ** 2).sum()}
        if cfg.expression:
            out["E_expr"] = cfg.w_expr * (st.psi ** 2).sum()
        if cfg.joints:
            out["E_theta"] = cfg.w_theta * (st.theta ** 2).sum()
            out["E_limits"] = cfg.w_limits * rotation_limit_penalty(st.theta).sum()
        if cfg.larynx:
            out["E_larynx"] = cfg.w_limits * larynx_limit_penalty(st.eta, st.tau).sum()
        return out

    base = {}

    def model_loss(free: bool, with_priors: bool, rigid_only: bool = False):
        def fn(it):
            if free:  # the model's parameters are fixed: pose it once
                if "v" not in base:
                    with torch.no_grad():
                        base["v"] = posed_vertices(model, st, corr.skin, False)[0]
                v = base["v"].index_add(0, corr.skin, st.offsets)
                lm = v[model.landmark_indices]
            elif rigid_only:  # the shape is fixed: pose it once, then move it rigidly
                if "rest" not in base:
                    with torch.no_grad():
                        zero = torch.zeros_like(st.global_orient)
                        out = model(beta=st.beta, psi=st.psi, theta=st.theta,
                                    global_orient=zero, transl=zero, eta=st.eta, tau=st.tau)
                        base["rest"] = out.vertices[0]
                        base["root"] = out.joints[0, :1]  # global rotation is about c7-t1
                rot = axis_angle_to_matrix(st.global_orient)[0]
                v = (base["rest"] - base["root"]) @ rot.T + base["root"] + st.transl
                lm = v[model.landmark_indices]
            else:
                v, lm = posed_vertices(model, st, corr.skin, False)
            terms = data_terms(v, lm)
            if with_priors:
                terms.update(priors())
            if free:
                lap = torch.sparse.mm(laplacian, st.offsets.double()).float()
                terms["E_lap"] = cfg.w_laplacian * ((1000.0 * lap) ** 2).sum(1).mean()
                terms["E_offset"] = cfg.w_offset * ((1000.0 * st.offsets) ** 2).sum(1).mean()
            total = sum(terms.values())
            return total, {k: float(x.detach()) for k, x in terms.items()}
        return fn

    def project():
        with torch.no_grad():
            st.psi.clamp_(0.0, 1.0)
            e, t = clamp_larynx(st.eta, st.tau)
            st.eta.copy_(e)
            st.tau.copy_(t)

    for p in (st.global_orient, st.transl):
        p.requires_grad_(True)
    t0 = time.perf_counter()
    rep = run_stage("rigid", [{"params": [st.global_orient], "lr": cfg.lr_pose},
                              {"params": [st.transl], "lr": 2e-3}],
                    model_loss(False, False, rigid_only=True), cfg.rigid_iterations, progress)
    st.reports.append(rep)
    if cfg.joints:  # the head keeps its orientation while the joints move
        st.global_orient.requires_grad_(False)
        st.head_orient = global_from_head(st.global_orient.detach(), st.theta.detach()
                                          ).detach().requires_grad_(True)
        orient = st.head_orient
    else:
        orient = st.global_orient
    groups = [{"params": [orient], "lr": cfg.lr_pose * 0.5},
              {"params": [st.transl], "lr": 1e-3},
              {"params": [st.beta], "lr": cfg.lr_shape}]
    st.beta.requires_grad_(True)
    if cfg.expression:
        st.psi.requires_grad_(True)
        groups.append({"params": [st.psi], "lr": 0.02})
    if cfg.joints:
        st.theta.requires_grad_(True)
        groups.append({"params": [st.theta], "lr": cfg.lr_pose})
    if cfg.larynx and model.has_larynx:
        st.eta.requires_grad_(True)
        st.tau.requires_grad_(True)
        groups += [{"params": [st.eta], "lr": 0.02}, {"params": [st.tau], "lr": 5e-4}]
    rep = run_stage("model", groups, model_loss(False, True), cfg.model_iterations, progress,
                    after_step=project)
    st.reports.append(rep)
    if st.head_orient is not None:
        with torch.no_grad():
            st.global_orient = global_from_head(st.head_orient, st.theta).detach()
        st.head_orient = None
    if cfg.free_form and cfg.free_iterations > 0:
        for p in (st.beta, st.psi, st.theta, st.eta, st.tau, st.global_orient, st.transl):
            p.requires_grad_(False)
        laplacian = uniform_laplacian(corr.skin_faces, corr.skin.numpy(), model.num_vertices)
        st.offsets.requires_grad_(True)
        rep = run_stage("free", [{"params": [st.offsets], "lr": cfg.lr_free}],
                        model_loss(True, False), cfg.free_iterations, progress)
        st.reports.append(rep)
        st.offsets.requires_grad_(False)
    for p in (st.beta, st.psi, st.theta, st.eta, st.tau, st.global_orient, st.transl):
        p.requires_grad_(False)
    st.seconds = time.perf_counter() - t0
    return st
