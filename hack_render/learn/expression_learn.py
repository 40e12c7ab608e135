"""Personalised expression blendshapes E_beta and M_E (paper Sec. 3.2, 5.1; Eq. 7; Fig. 12).

For each identity beta_i ~ N(0, I) of the (larynx-removed) shape space, the 53 generic
shapes are deformation-transferred (:mod:`hack_render.motion.deformation_transfer`) from
the template onto the identity's neutral mesh: E_beta_i = DT(E) - x_i. The personal part
E_beta - E_generic is kept on the M skin vertices where it varies most (the model file's
vertex subset, to fit the size budget), PCA'd, and M_E maps beta to the first 50 weights.

The subset holds 59 % of the personal part's energy: outside it the personal part is cut
to zero, and across the subset's edge with the rest of the skin that cut was a step (up to
2 mm across one 3.5 mm edge, shrinking submental edges to a quarter of their length under
a smile with the jaw open, where the pose correctives then stretched or folded the skin).
:func:`taper_personal` ramps the personal part down over the subset's outer rings instead
(:data:`TAPER_RINGS`), the same for every identity and expression.

Data honesty: the per-identity expressions are *derived* by deformation transfer of
ICT-FaceKit's generic shapes, not captured per person; the personalisation they encode is the
geometric adaptation of each shape to the identity's face (sizes, proportions, curvature).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from hack_render.learn.mesh_ops import ring
from hack_render.learn.pca import compactness, generalisation
from hack_render.learn.personal import (
    PersonalSpace,
    learn_personal_space,
    mlp_forward,
    personal_arrays,
)
from hack_render.motion.deformation_transfer import TargetSolver, source_gradients

SKIN_LAST = 11247
#: Rings of the personal subset, counted from the skin outside it, over which M_E's output
#: ramps from 0 to its full value (ring r of k: r / (k + 1)).
TAPER_RINGS = 3


@dataclass
class ExpressionResult:
    arrays: dict[str, np.ndarray]
    space: PersonalSpace
    report: dict = field(default_factory=dict)


class ExpressionTransfer:
    """Deformation transfer of a model's generic expressions onto identity meshes."""

    def __init__(self, template: np.ndarray, faces: np.ndarray, expressions: np.ndarray):
        self.template = template.astype(np.float64)
        n = len(template)
        skin = np.arange(n) <= SKIN_LAST
        moving = np.zeros(n, bool)
        moving[: SKIN_LAST + 1] = np.abs(expressions[:, : SKIN_LAST + 1]).max(axis=(0, 2)) > 1e-7
        self.moving = moving
        self.free = ring(faces, moving, 2) & skin
        self.faces = faces[(faces <= SKIN_LAST).all(1) & self.free[faces].any(1)]
        self.expressions = expressions.astype(np.float64)
        self.gradients = np.stack([source_gradients(self.template, self.template + e, self.faces)
                                   for e in self.expressions])

    def transfer(self, identity: np.ndarray) -> np.ndarray:
        """Personal expression deltas (E, N, 3) of one identity mesh (N, 3); non-skin
        vertices keep the generic deltas (they move rigidly or belong to other parts)."""
        out = TargetSolver(identity, self.faces, self.free).transfer(self.gradients) - identity
        non_skin = np.arange(len(identity)) > SKIN_LAST
        out[:, non_skin] = self.expressions[:, non_skin]
        return out


def seam_taper(faces: np.ndarray, subset: np.ndarray, num_vertices: int,
               rings: int = TAPER_RINGS) -> np.ndarray:
    """(len(subset),) factors in (0, 1]: ``r / (rings + 1)`` on the subset's r-th ring from
    the skin outside it (graph rings over the skin's faces), 1 from ring ``rings + 1`` on
    and where no outside skin vertex is reachable."""
    subset = np.asarray(subset, np.int64)
    f = np.asarray(faces, np.int64)
    f = f[(f <= SKIN_LAST).all(1)]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    dist = np.full(num_vertices, np.inf)
    front = np.zeros(num_vertices, bool)
    front[np.unique(f)] = True
    front[subset] = False
    dist[front] = 0
    r = 0
    while front.any() and r <= rings:
        r += 1
        nb = np.zeros(num_vertices, bool)
        nb[e[front[e[:, 0]], 1]] = True
        nb &= ~np.isfinite(dist)
        dist[nb] = r
        front = nb
    return np.clip(dist[subset] / (rings + 1), 0.0, 1.0)


def taper_personal(arrays: dict[str, np.ndarray], faces: np.ndarray, num_vertices: int,
                   rings: int = TAPER_RINGS, prefix: str = "expr") -> dict[str, np.ndarray]:
    """``arrays`` with the personal group's mean and components scaled per vertex by
    :func:`seam_taper` (M_E's output is linear in both: the output itself tapered)."""
    t = seam_taper(faces, arrays[f"{prefix}_pca_vertices"], num_vertices, rings)
    out = dict(arrays)
    out[f"{prefix}_pca_mean"] = (arrays[f"{prefix}_pca_mean"] * t[None, :, None]).astype(np.float32)
    out[f"{prefix}_pca_components"] = (
        arrays[f"{prefix}_pca_components"] * t[None, None, :, None]).astype(np.float32)
    return out


def learn_expressions(arrays: dict[str, np.ndarray], template: np.ndarray, shape_components: np.ndarray,
                      num_identities: int = 300, num_vertices: int = 1500, num_components: int = 50,
                      epochs: int = 3000, seed: int = 60, progress: bool = True,
                      taper_rings: int = TAPER_RINGS) -> ExpressionResult:
    """DT onto ``num_identities`` identities, PCA of {E_beta}, M_E, and the Fig. 12 ablation.

    The last 10 % of identities are held out of PCA and M_E; on them the ablation compares the
    DT ground truth with (a) the generic shapes and (b) the generic shapes plus M_E's
    personalisation, as mean per-vertex error in mm over all moving skin vertices.
    ``taper_rings``: :func:`taper_personal` (0: the subset's edge a step, as before model
    version 6).
    """
    rng = np.random.default_rng(seed)
    faces = arrays["faces"]
    expr = arrays["expression_basis"].astype(np.float64)
    dirs = shape_components.astype(np.float64) * arrays["shape_std"].astype(np.float64)[:, None, None]
    dt = ExpressionTransfer(template, faces, expr)
    betas = rng.standard_normal((num_identities, len(dirs)))
    ntest = max(int(round(num_identities * 0.1)), 1)
    # Pilot: choose the vertex subset where the personal part is largest (second moment).
    pilot = min(20, num_identities - ntest)
    energy = np.zeros(len(template))
    bar = tqdm(total=num_identities, desc="deformation transfer", disable=not progress)
    personal_full = []
    for i in range(pilot):
        d = dt.transfer(template + np.tensordot(betas[i], dirs, 1)) - expr
        energy += (d**2).sum(axis=(0, 2))
        personal_full.append(d)
        bar.update()
    subset = np.sort(np.argsort(energy)[::-1][:num_vertices]).astype(np.int32)
    e = len(expr)
    deltas = np.zeros((num_identities, e, len(subset), 3), np.float32)
    test_full = []
    for i in range(num_identities):
        if i < pilot:
            d = personal_full[i]
        else:
            d = dt.transfer(template + np.tensordot(betas[i], dirs, 1)) - expr
            bar.update()
        deltas[i] = d[:, subset]
        if i >= num_identities - ntest:
            test_full.append(d[:, dt.moving].astype(np.float32))
    bar.close()
    captured = float(energy[subset].sum() / max(energy.sum(), 1e-30))

    space = learn_personal_space(betas, deltas, num_components, val_fraction=ntest / num_identities,
                                 epochs=epochs, seed=seed, progress=progress, desc="M_E")
    # Ablation (Fig. 12) on the held-out identities.
    pred = space.pca.reconstruct(mlp_forward(space.mlp, betas[-ntest:])).reshape(ntest, e, len(subset), 3)
    taper = seam_taper(faces, subset, len(template), taper_rings) if taper_rings else 1.0
    pred = pred * np.reshape(taper, (1, 1, -1, 1))
    moving_idx = np.flatnonzero(dt.moving)
    pos = np.searchsorted(moving_idx, subset)
    generic_err, personal_err = [], []
    for j, truth in enumerate(test_full):  # truth: personal part, (E, Mv, 3) metres
        generic_err.append(np.linalg.norm(truth, axis=2).mean())
        res = truth.copy()
        res[:, pos] -= pred[j]
        personal_err.append(np.linalg.norm(res, axis=2).mean())
    sub_g = np.mean([np.linalg.norm(t[:, pos], axis=2).mean() for t in test_full])
    sub_p = np.mean([np.linalg.norm(t[:, pos] - pred[j], axis=2).mean() for j, t in enumerate(test_full)])
    flat = deltas.reshape(num_identities, -1)
    report = {
        "identities": num_identities, "held_out": ntest, "subset_vertices": int(len(subset)),
        "subset_energy_fraction": captured, "components": int(len(space.pca.components)),
        "taper_rings": int(taper_rings),
        "mlp_train_mse_mm2": space.train_loss * 1e6, "mlp_val_mse_mm2": (space.val_loss or 0) * 1e6,
        "ablation_mm": {
            "generic_all_moving_vertices": float(np.mean(generic_err) * 1e3),
            "personalised_all_moving_vertices": float(np.mean(personal_err) * 1e3),
            "generic_subset": float(sub_g * 1e3), "personalised_subset": float(sub_p * 1e3),
            "moving_vertices": int(len(moving_idx)),
        },
        "curves": {"explained_variance": compactness(space.pca).tolist()[:60]
                   if len(space.pca.variance_ratio) else [],
                   "generalisation": generalisation(flat[:-ntest], flat[-ntest:],
                                                    [1, 2, 5, 10, 20, 30, 50, 100, 200])},
    }
    out = personal_arrays("expr", space, subset, (e, len(subset)))
    if taper_rings:
        out = taper_personal(out, faces, len(template), taper_rings)
    return ExpressionResult(arrays=out, space=space, report=report)
