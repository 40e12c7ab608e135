"""Learning the larynx term L(beta, eta, tau) (paper Sec. 3.3, 5.1; Eq. 4).

Pipeline, per sampled identity mesh x_i (metres):

1. **Larynx removal.** Inside a front-neck patch between the chin-neck angle and the
   suprasternal notch (:func:`hack_render.learn.mesh_ops.neck_front_landmarks`), the
   surface is replaced by the bi-harmonic fill of its surroundings (minimise ||L x||^2 with
   two rings of boundary vertices fixed; L the inverse-edge-length graph Laplacian). The
   fill is smooth and larynx-free. ``Gamma = (original - removed)`` projected on the template
   normals, so Gamma is a normal displacement and linear in x.
2. **UV images.** Gamma on the larynx support (front-neck vertices) is rasterised through
   the mesh's own triangles into (3, H, W) images (metres). The images' chart is the
   template's (x, y) in metres (model-file key ``larynx_vertex_uv``, format 2), not the ICT
   atlas, whose v stretches non-uniformly down the neck: there a constant v shift moved the
   larynx 9 mm up but 12 mm down for tau = +-1 cm.
3. **PCA** of the images (paper: "we conduct PCA on the obtained images").
4. **Coefficient map** c(beta) = A beta + c0 by ridge regression of the PCA weights on beta
   (the documented generalisation of Eq. 4 in :mod:`hack_render.geometry.larynx`): map 0 is
   the mean larynx image with c0 = 1, maps 1.. are the components.
5. **Larynx-removed template and shape space**: the same removal (one linear operator on the
   template's patch) applied to T_bar and to every shape component.

Data honesty: ICT-FaceKit necks carry little larynx relief, so each identity also gets a
*simulated* thyroid prominence (:func:`simulated_prominence`) at its own C4-C5 level before
removal: height 5-10 mm for identities simulated as male, 1-3 mm as female (ANATOMY.md),
sex drawn with a probability rising with the identity's neck width at C4-C5 (a simulation
assumption: neck circumference is larger in men). The file's metadata says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.learn.mesh_ops import neck_front_landmarks, ring, uniform_laplacian, vertex_normals
from hack_render.learn.pca import compactness, fit_pca, generalisation

SKIN_LAST = 11247
IMAGE_SIZE = 64


@dataclass
class LarynxResult:
    """Arrays for the model file's larynx group plus the removed template/shape space."""

    arrays: dict[str, np.ndarray]
    template: np.ndarray  # (N, 3) larynx-removed T_bar
    shape_components: np.ndarray  # (S, N, 3) larynx-removed components (same beta meaning)
    report: dict = field(default_factory=dict)


def larynx_support(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """Vertex indices carrying the larynx: front-neck skin (|x| < 4.5 cm, facing forward)
    from the chest up to 5 mm above the chin-neck angle (not the underside of the jaw, where
    a vertical chart folds)."""
    v = arrays["template_vertices"].astype(np.float64)
    n = len(v)
    lm = neck_front_landmarks(v, np.arange(SKIN_LAST + 1), int(arrays["landmark_indices"][8]))
    idx = np.arange(n)
    nrm = vertex_normals(v, arrays["faces"])
    sel = ((idx <= SKIN_LAST) & (np.abs(v[:, 0]) < 0.045) & (v[:, 1] < lm["y_angle"] + 0.005)
           & (v[:, 1] > lm["y_notch"] - 0.02) & (v[:, 2] > 0) & (nrm[:, 2] > 0.2))
    if sel.sum() < 20:
        raise HackError(f"larynx support: only {int(sel.sum())} front-neck vertices found; the "
                        "template needs a neck in the face UV chart below the chin.")
    return np.flatnonzero(sel).astype(np.int32)


class Remover:
    """Bi-harmonic larynx removal on a fixed vertex patch (one factorisation, reusable)."""

    def __init__(self, v: np.ndarray, faces: np.ndarray, interior: np.ndarray):
        n = len(v)
        self.interior = np.flatnonzero(interior)
        if len(self.interior) == 0:
            raise HackError("larynx removal: the removal patch is empty.")
        lap = uniform_laplacian(faces, n, v)
        band = ring(faces, interior, 2)
        rows = np.flatnonzero(ring(faces, interior, 1))
        lk = lap[rows][:, band.nonzero()[0]].tocsc()
        cols = np.flatnonzero(band)
        pos = {c: i for i, c in enumerate(cols)}
        fi = np.array([pos[c] for c in self.interior])
        fixed = np.setdiff1d(np.arange(len(cols)), fi)
        self.cols, self.fixed_cols = cols, cols[fixed]
        a_f, self.a_c = lk[:, fi], lk[:, fixed]
        self.lu = splu((a_f.T @ a_f).tocsc())
        self.a_f = a_f

    def fill(self, x: np.ndarray) -> np.ndarray:
        """Bi-harmonic fill of the patch. x: (N, 3) or (N, 3k) -> interior values (M, ...)."""
        rhs = -(self.a_f.T @ (self.a_c @ x[self.fixed_cols]))
        return self.lu.solve(np.asarray(rhs))

    def gamma(self, x: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Gamma = (x - removed) along ``normals`` (N, 3): zero outside the patch. x: (N, 3)."""
        out = np.zeros_like(x, dtype=np.float64)
        d = x[self.interior] - self.fill(x)
        nn = normals[self.interior]
        out[self.interior] = (d * nn).sum(1, keepdims=True) * nn
        return out


def simulated_prominence(x: np.ndarray, normals: np.ndarray, support: np.ndarray, y_c: float,
                         height: float, sigma_x: float, sigma_up: float = 0.005,
                         sigma_down: float = 0.012) -> np.ndarray:
    """A thyroid-prominence bump (N, 3), metres, along the outward normals.

    Peak ``height`` at the front midline at height ``y_c``; a sharp upper edge (sigma_up,
    the thyroid notch) and a longer taper downwards (sigma_down, the laminae); the width
    sigma_x grows by half downwards, so the bump is V-shaped like the laminae.
    """
    out = np.zeros_like(x, dtype=np.float64)
    p = x[support]
    t = p[:, 1] - y_c
    sy = np.where(t > 0, sigma_up, sigma_down)
    sx = sigma_x * (1.0 + 0.5 * np.clip(-t / sigma_down, 0, 2))
    h = height * np.exp(-0.5 * (t / sy) ** 2 - 0.5 * (p[:, 0] / sx) ** 2)
    out[support] = h[:, None] * normals[support]
    return out


def uv_raster_matrix(uv: np.ndarray, tri: np.ndarray, bounds: np.ndarray, size: int) -> sparse.csr_matrix:
    """Sparse (size*size, M) barycentric interpolation from M vertex values to image pixels.

    uv: (M, 2) texture coordinates; tri: (T, 3) triangles over 0..M-1; bounds (u0, v0, u1,
    v1); image row 0 at v1. Pixels outside every triangle get no weights (value 0).
    """
    u0, v0, u1, v1 = bounds
    rows, cols, vals = [], [], []
    taken = np.zeros(size * size, bool)
    for t in tri:
        a, b, c = uv[t]
        m = np.array([b - a, c - a]).T
        if abs(np.linalg.det(m)) < 1e-14:
            continue  # degenerate in UV
        lo = np.minimum(np.minimum(a, b), c)
        hi = np.maximum(np.maximum(a, b), c)
        j0, j1 = (np.array([lo[0], hi[0]]) - u0) / (u1 - u0) * size - 0.5
        i0, i1 = (v1 - np.array([hi[1], lo[1]])) / (v1 - v0) * size - 0.5
        jj, ii = np.meshgrid(np.arange(max(int(np.floor(j0)), 0), min(int(np.ceil(j1)), size - 1) + 1),
                             np.arange(max(int(np.floor(i0)), 0), min(int(np.ceil(i1)), size - 1) + 1))
        jj, ii = jj.ravel(), ii.ravel()
        p = np.stack([u0 + (jj + 0.5) / size * (u1 - u0), v1 - (ii + 0.5) / size * (v1 - v0)], 1)
        lam = np.linalg.solve(m, (p - a).T).T
        w = np.stack([1 - lam.sum(1), lam[:, 0], lam[:, 1]], 1)
        pix = ii * size + jj
        ok = (w >= -1e-9).all(1) & ~taken[pix]  # first triangle wins where UVs overlap
        taken[pix[ok]] = True
        rows.append(np.repeat(pix[ok], 3))
        cols.append(np.tile(t, ok.sum()))
        vals.append(w[ok].ravel())
    rows, cols, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    return sparse.csr_matrix((w, (rows, cols)), shape=(size * size, len(uv)))


def learn_larynx(arrays: dict[str, np.ndarray], num_identities: int = 300, num_maps: int = 16,
                 seed: int = 6, ridge: float = 1.0, progress: bool = True) -> LarynxResult:
    """Learn the larynx basis and the larynx-removed template/shape space (see module doc).

    Args:
        arrays: a v1 model's arrays (template, faces, vertex_uv, shape space, ...).
        num_identities: identities sampled from the shape space, beta ~ N(0, I).
        num_maps: PCA components kept (plus the mean map).
    """
    rng = np.random.default_rng(seed)
    v = arrays["template_vertices"].astype(np.float64)
    faces = arrays["faces"]
    n = len(v)
    chin = int(arrays["landmark_indices"][8])
    skin_idx = np.arange(SKIN_LAST + 1)
    shape_dirs = (arrays["shape_components"].astype(np.float64)
                  * arrays["shape_std"].astype(np.float64)[:, None, None])  # (S, N, 3)
    support = larynx_support(arrays)
    in_support = np.zeros(n, bool)
    in_support[support] = True
    nrm_t = vertex_normals(v, faces)

    # Template removal (one linear operator) -> larynx-removed template and shape space.
    lm_t = neck_front_landmarks(v, skin_idx, chin)
    patch_t = _patch(v, in_support, lm_t)
    rem_t = Remover(v, faces, patch_t)
    gamma_t = rem_t.gamma(v, nrm_t)
    comps = arrays["shape_components"].astype(np.float64)
    comps_removed = comps.copy()
    for s in range(len(comps)):
        comps_removed[s] -= rem_t.gamma(comps[s], nrm_t)

    # The maps' chart: template (x, y) in metres, so a shift in v is a vertical slide of the
    # same size everywhere (the atlas UVs stretch non-uniformly along the neck).
    sub_faces = faces[in_support[faces].all(1)]
    remap = -np.ones(n, np.int64)
    remap[support] = np.arange(len(support))
    uv = v[support, :2].copy()
    pad = 0.02 * (uv.max(0) - uv.min(0))
    bounds = np.array([*(uv.min(0) - pad), *(uv.max(0) + pad)])
    raster = uv_raster_matrix(uv, remap[sub_faces], bounds, IMAGE_SIZE)

    betas = rng.standard_normal((num_identities, len(shape_dirs)))
    images, heights, landmarks = [], [], []
    widths = []
    meshes = []
    for b in betas:
        x = v + np.tensordot(b, shape_dirs, 1)
        lm = _robust_landmarks(x, v, skin_idx, chin, lm_t, in_support)
        meshes.append(x)
        landmarks.append(lm)
        lvl = np.abs(x[support, 1] - lm["y_c45"]) < 0.006
        widths.append(np.ptp(x[support][lvl, 0]) if lvl.sum() > 1 else 0.0)
    widths = np.asarray(widths)
    z = (widths - widths.mean()) / max(widths.std(), 1e-9)
    p_male = 1.0 / (1.0 + np.exp(-2.0 * z))
    male = rng.random(num_identities) < p_male
    for i in tqdm(range(num_identities), desc="larynx removal", disable=not progress):
        x, lm = meshes[i], landmarks[i]
        h = rng.uniform(0.005, 0.010) if male[i] else rng.uniform(0.001, 0.003)
        sx = rng.uniform(0.005, 0.007) if male[i] else rng.uniform(0.008, 0.011)
        y_c = float(np.clip(lm["y_c45"], x[support, 1].min() + 0.02, x[support, 1].max() - 0.02))
        x = x + simulated_prominence(x, vertex_normals(x, faces), support, y_c, h, sx)
        patch = _patch(x, in_support, lm)
        gamma = Remover(x, faces, patch).gamma(x, nrm_t)
        images.append(np.stack([raster @ gamma[support, c] for c in range(3)]).ravel())
        heights.append(h)
    images = np.asarray(images, dtype=np.float64)  # (n, 3 H W)

    pca = fit_pca(images, num_maps)
    k = len(pca.components)
    scores = pca.project(images, k) / pca.std  # ~ unit variance
    xb = np.hstack([betas, np.ones((num_identities, 1))])
    reg = np.diag(np.r_[np.full(betas.shape[1], ridge), 0.0])
    coef = np.linalg.solve(xb.T @ xb + reg, xb.T @ scores)  # (S + 1, k)
    maps = np.concatenate([pca.mean[None], pca.components * pca.std[:, None]]).reshape(k + 1, 3, IMAGE_SIZE, IMAGE_SIZE)
    coef_matrix = np.vstack([np.zeros((1, betas.shape[1])), coef[:-1].T])
    coef_offset = np.r_[1.0, coef[-1]]
    # The chart's v is height in metres: sampling at v + tau * v_per_metre with
    # v_per_metre = -1 moves the larynx up by tau (see hack_render.geometry.larynx).
    dv_dy = 1.0

    ntest = max(num_identities // 10, 2)
    curves = {"explained_variance": compactness(pca).tolist()[:60],
              "generalisation": generalisation(images[:-ntest], images[-ntest:],
                                               [1, 2, 5, 10, 20, 30, 50], points=1),
              "pixel_rmse_note": "RMSE per image channel value (metres), over all pixels"}
    pred = (xb @ coef) * pca.std
    fit_rmse = float(np.sqrt(((pca.reconstruct(pred) - images) ** 2).mean()))
    out = {
        "larynx_maps": maps.astype(np.float32),
        "larynx_uv_bounds": bounds.astype(np.float32),
        "larynx_vertices": support,
        "larynx_coef_matrix": coef_matrix.astype(np.float32),
        "larynx_coef_offset": coef_offset.astype(np.float32),
        "larynx_v_per_metre": np.asarray(-dv_dy, np.float32),
        "larynx_vertex_uv": uv.astype(np.float32),
    }
    template = v - gamma_t
    report = {
        "identities": num_identities, "maps": k, "image_size": IMAGE_SIZE,
        "template_gamma_max_mm": float(np.abs(gamma_t).max() * 1e3),
        "shape_component_change_max": float(np.abs(comps_removed - comps).max()),
        "simulated_male_fraction": float(male.mean()),
        "simulated_height_mm": [float(np.min(heights) * 1e3), float(np.max(heights) * 1e3)],
        "beta_map_image_rmse_mm": fit_rmse * 1e3,
        "template_landmarks": lm_t, "v_per_metre": float(-dv_dy),
        "curves": curves,
    }
    return LarynxResult(arrays=out, template=template.astype(np.float32),
                        shape_components=comps_removed.astype(np.float32), report=report)


def _robust_landmarks(x, v, skin_idx, chin, lm_t, in_support) -> dict:
    """Neck landmarks of one identity; where the profile detection is implausible (angle to
    notch outside 3-10 cm, or a patch of under 10 vertices) the template's landmarks moved by
    the identity's mean vertical displacement of the support are used instead."""
    lm = neck_front_landmarks(x, skin_idx, chin)
    span = lm["y_angle"] - lm["y_notch"]
    if 0.03 <= span <= 0.10 and _patch(x, in_support, lm).sum() >= 10:
        return lm
    dy = float((x[in_support, 1] - v[in_support, 1]).mean())
    return {k: (val + dy if k.startswith("y_") else val) for k, val in lm_t.items()}


def _patch(x: np.ndarray, in_support: np.ndarray, lm: dict) -> np.ndarray:
    """Removal patch: support vertices between just above the notch and just below the angle,
    within 3.5 cm of the midline."""
    return (in_support & (x[:, 1] > lm["y_notch"] + 0.005) & (x[:, 1] < lm["y_angle"] - 0.004)
            & (np.abs(x[:, 0]) < 0.035))
