"""The v2 default model: the v1 ICT-FaceKit model plus every learned HACK component.

``build_full_model(ict)`` calls :func:`hack_render.learn.ict_default.build_default_model`
and adds, in order: the larynx basis with the larynx-removed template and shape space
(:mod:`larynx_learn`), personalised expressions and M_E (:mod:`expression_learn`), and pose
blendshapes, skinning weights and M_P learned from simulated sequences (:mod:`pose_data`,
:mod:`pose_learn`). Each component's provenance is written into the metadata with an honest
label: "captured", "derived" (computed from captured data) or "simulated".
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import without_correctives
from hack_render.learn.expression_learn import learn_expressions
from hack_render.learn.ict_default import build_default_model
from hack_render.learn.larynx_learn import learn_larynx
from hack_render.learn.mesh_ops import ring
from hack_render.learn.neck_region import neck_region
from hack_render.learn.pca import compactness, generalisation
from hack_render.learn.personal import learn_personal_space, mlp_forward, personal_arrays
from hack_render.learn.pose_data import (
    ArapNeck,
    action_thetas,
    pose_sequence,
    single_joint_sweeps,
    twist_area_ratio,
)
from hack_render.learn.pose_energy import PoseEnergyLearner
from hack_render.learn.pose_learn import PoseTrainer, Sequence

SKIN_LAST = 11247


def shape_curves(arrays: dict, num_train: int = 500, num_test: int = 50, seed: int = 11) -> dict:
    """Compactness of the shape space and held-out RMSE (mm per skin vertex) of sampled
    identities against the number of components."""
    rng = np.random.default_rng(seed)
    std = arrays["shape_std"].astype(np.float64)
    sub = np.arange(0, SKIN_LAST + 1, 3)
    dirs = arrays["shape_components"][:, sub].reshape(len(std), -1).astype(np.float64) * std[:, None]
    x = rng.standard_normal((num_train + num_test, len(std))) @ dirs
    gen = generalisation(x[:num_train], x[num_train:], [1, 2, 5, 10, 20, 30, 50, 70, 100])
    return {"explained_variance": (np.cumsum(std**2) / (std**2).sum()).tolist(),
            "generalisation": gen, "note": "identities sampled from ICT-FaceKit's 100 modes; "
            "RMSE over every third skin vertex"}


def pose_subset(arrays: dict) -> np.ndarray:
    """Skin vertices the neck joints move (neither fully root nor fully o-c1), plus one ring."""
    w = arrays["skinning_weights"]
    n = len(w)
    moving = (np.arange(n) <= SKIN_LAST) & (w[:, 0] < 0.999) & (w[:, -1] < 0.999)
    return np.flatnonzero(ring(arrays["faces"], moving, 1) & (np.arange(n) <= SKIN_LAST)).astype(np.int32)


def learn_pose(arrays: dict, num_identities: int = 12, iterations: int = 30, lr: float = 1e-3,
               seed: int = 12, learn_weights: bool = False, progress: bool = True,
               deformer: str = "arap") -> dict:
    """Simulate sequences for ``num_identities`` identities (the Sec. 4.2 actions plus every
    joint alone to its limits; ``deformer`` "arap" = DQS then ARAP of the neck skin with the
    face, head and chest rigid, see :mod:`pose_data`), fit P_beta (and W if
    ``learn_weights``) with :class:`PoseTrainer` (closed-form unposed least squares, then
    ``iterations`` of Adam on Eq. 12 at ``lr`` centimetres: small, because Adam's first
    steps move every coordinate by about ``lr`` and would undo the closed-form start), then
    PCA + M_P. Identity 0 is the template (beta = 0), and M_P's output bias is shifted so
    that it reproduces that identity exactly: the default model's pose correctives are the
    ones learned for its own mesh. Returns model arrays and a report.

    W is not learned by default: on the simulated data, learned weights lean on the pose
    correctives (jointly they are not identifiable to first order) and stretched the skin
    more than the procedural weights at single-joint extremes (c1-c2 twist alone: 2.0 vs
    0.53 edge stretch without correctives).
    """
    rng = np.random.default_rng(seed)
    model = HackModel(arrays).double()
    sub = pose_subset(arrays)
    m = len(sub)
    remap = -np.ones(len(arrays["template_vertices"]), np.int64)
    remap[sub] = np.arange(m)
    faces = remap[arrays["faces"][(remap[arrays["faces"]] >= 0).all(1)]]
    betas = rng.standard_normal((num_identities, model.num_shape))
    betas[0] = 0.0  # the template itself (see the docstring)
    w0 = torch.as_tensor(arrays["skinning_weights"], dtype=torch.float64)
    rests, joints, seqs = [], [], []
    acts = action_thetas() + single_joint_sweeps()
    faces_all = np.asarray(arrays["faces"])
    skin_faces = faces_all[(faces_all <= SKIN_LAST).all(1)]
    n_all = len(arrays["template_vertices"])
    moving = np.zeros(n_all, bool)
    moving[sub] = True
    moving &= (w0[:, 0] < 0.999).numpy() & (w0[:, -1] < 0.999).numpy()
    t0 = time.time()
    with torch.no_grad():
        for i, b in enumerate(tqdm(betas, desc=f"simulating {deformer.upper()} sequences", disable=not progress)):
            out = model(beta=torch.as_tensor(b[None]))
            rest, j = out.rest_vertices[0], out.rest_joints[0]
            rests.append(rest[sub].numpy())
            joints.append(j.numpy())
            arap = ArapNeck(rest.numpy(), skin_faces, ~moving) if deformer == "arap" else None
            # The eased actions go out and back, so about half their frames repeat: pose each
            # distinct theta once (in chunks), then cut the result back into sequences.
            every = torch.cat([th for _, th in acts])
            uniq, inverse = np.unique(np.round(every.numpy().reshape(len(every), -1), 12), axis=0,
                                      return_inverse=True)
            uniq = torch.as_tensor(uniq).view(-1, 8, 3)
            posed = torch.cat([pose_sequence(rest, j, w0, model.parents, uniq[k:k + 96], deformer, arap)[:, sub]
                               for k in range(0, len(uniq), 96)])[torch.as_tensor(inverse.ravel())]
            start = 0
            for _, th in acts:
                seqs.append(Sequence(i, posed[start:start + len(th)].numpy(), th.numpy()))
                start += len(th)
    simulate_s = time.time() - t0
    trainer = PoseTrainer(np.stack(rests), np.stack(joints), faces, arrays["skinning_weights"][sub],
                          model.parents)
    t0 = time.time()
    init = trainer.unposed_least_squares(seqs)
    fit = trainer.fit(seqs, iterations=iterations, lr=lr, learn_weights=learn_weights, progress=progress,
                      pose_init=init)
    train_s = time.time() - t0
    # LBS without pose blendshapes vs the learned model, per vertex (mm), on the training data.
    with torch.no_grad():
        errs = {"lbs_initial_weights": [], "learned": []}
        wl = torch.as_tensor(fit.weights)
        for s in seqs:
            th = torch.as_tensor(s.theta)
            zero = torch.zeros(72, m, 3, dtype=torch.float64)
            for key, p, w in (("lbs_initial_weights", zero, trainer.w_init),
                              ("learned", torch.as_tensor(fit.pose_blendshapes[s.identity]), wl)):
                v, _ = trainer.predict(s.identity, th, p, w)
                errs[key].append(np.linalg.norm(v.numpy() - s.targets, axis=-1).mean())
    space = learn_personal_space(betas, fit.pose_blendshapes.astype(np.float32),
                                 num_components=num_identities - 1, val_fraction=0.0,
                                 epochs=3000, seed=seed, progress=progress, desc="M_P")
    n = len(arrays["template_vertices"])
    generic = np.zeros((72, n, 3), np.float32)
    generic[:, sub] = space.pca.mean.reshape(72, m, 3)
    # Anchor M_P at the template (identity 0, beta = 0): shift its output bias so it
    # predicts that identity's PCA weights exactly.
    w_template = space.pca.project(fit.pose_blendshapes[:1].reshape(1, -1).astype(np.float64))[0]
    space.mlp["b2"] = (space.mlp["b2"] + w_template - mlp_forward(space.mlp, betas[:1])[0]).astype(np.float32)
    space.pca.mean = np.zeros_like(space.pca.mean)  # the mean lives in the generic pose_basis
    out = personal_arrays("pose", space, sub, (72, m))
    out["pose_basis"] = generic
    weights = arrays["skinning_weights"].astype(np.float64).copy()
    weights[sub] = fit.weights
    weights /= weights.sum(1, keepdims=True)
    if learn_weights:
        out["skinning_weights"] = weights.astype(np.float32)
    flat = fit.pose_blendshapes.reshape(num_identities, -1)
    ring_idx = sub[np.abs(rests[0][:, 1] - joints[0][3, 1]) < 0.004]
    report = {
        "identities": num_identities, "frames": int(sum(len(s.theta) for s in seqs)),
        "subset_vertices": int(m), "iterations": iterations, "train_seconds": train_s,
        "simulate_seconds": simulate_s, "deformer": deformer,
        "learned_weights": learn_weights,
        "fit_error_mm": {k: float(np.mean(v) * 1e3) for k, v in errs.items()},
        "final_terms": fit.history[-1],
        "twist_area_ratio_c4c5_75deg": twist_area_ratio(torch.as_tensor(np.asarray(model.template.double())
                                                                           ), model.rest_joints(torch.zeros(1, 1, dtype=torch.float64))[0],
                                                          w0, model.parents, ring_idx),
        "curves": {"explained_variance": compactness(space.pca).tolist(),
                   "reconstruction": generalisation(flat, flat, list(range(1, num_identities)))},
    }
    return {"arrays": out, "report": report}


def clean_weights(w: np.ndarray, w0: np.ndarray, floor: float = 1e-3, most: int = 8) -> np.ndarray:
    """Learned skinning weights (N, K+1) made sparse and safe: rows that were rigid in the
    initial weights ``w0`` (one node at 1: the skull-rigid face, the root-rigid chest) stay
    exactly as they were; elsewhere weights below ``floor`` are dropped, at most ``most``
    nodes are kept (a glTF vertex carries 8), and rows sum to one."""
    w0 = np.asarray(w0, np.float64)
    out = np.where(w >= floor, w, 0.0)
    drop = np.argsort(out, axis=1)[:, : max(out.shape[1] - most, 0)]
    np.put_along_axis(out, drop, 0.0, axis=1)
    out /= out.sum(1, keepdims=True)
    rigid = w0.max(1) >= 1.0 - 1e-6
    out[rigid] = w0[rigid]
    return out


def model_rest_fn(arrays: dict, vertices) -> callable:
    """``(beta (U, S), psi (U, E) or None) -> (rest (U, V, 3), joints (U, K, 3))``: the rest
    mesh of the model the arrays make without pose correctives (template, shape, larynx at
    eta = 1, generic and personalised expressions), on ``vertices``, in float64."""
    model = HackModel(without_correctives(arrays)).double()
    idx = torch.as_tensor(np.asarray(vertices), dtype=torch.long)

    def rest(beta, psi):
        with torch.no_grad():
            out = model(beta=beta.double(), psi=psi.double() if psi is not None else None)
        return out.rest_vertices[:, idx], out.rest_joints

    return rest


#: an M_P whose output's largest standard deviation over sampled identities is below this
#: has died (one constant for every identity): ``learn pose --continue`` restarts it
MP_DEAD = 1e-4


def energy_learner(arrays: dict, num_components: int = 8, seed: int = 12,
                   expressions: bool = True, loss: dict | None = None,
                   gate_deg: float | None = None, single_axis: bool = False,
                   gate_chain: float = 0.0, corner: float = 0.0) -> PoseEnergyLearner:
    """The :class:`~hack_render.learn.pose_energy.PoseEnergyLearner` of a model's arrays: its
    neck region, the model's rest meshes (``expressions``: with sampled expressions) and
    mirrored expression pairs; :func:`learn_pose_energy` trains it, and
    ``bench/bench_mp_heldout.py`` scores a learned file's M_P with it."""
    sub = pose_subset(arrays)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64) * std[:, None, None]
    region = neck_region(arrays["faces"], SKIN_LAST, sub)
    rest = model_rest_fn(arrays, region.vertices) if expressions else None
    names = [str(x) for x in arrays["expression_names"]]
    return PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                             arrays["skinning_weights"], arrays["joint_parents"], region,
                             num_components=num_components, seed=seed, rest_fn=rest, loss=loss,
                             num_expressions=len(names) if expressions else 0,
                             jaw_open=names.index("jawOpen") if "jawOpen" in names else None,
                             symmetric=[(i, names.index(n[:-2] + "_R")) for i, n in enumerate(names)
                                        if n.endswith("_L") and n[:-2] + "_R" in names],
                             gate_deg=gate_deg, single_axis=single_axis, gate_chain=gate_chain,
                             corner=corner)


def learn_pose_energy(arrays: dict, iterations: int = 600, lr: float = 0.01,
                      num_components: int = 8, identities: int = 4, poses: int = 8,
                      learn_weights: bool = True, seed: int = 12, progress: bool = True,
                      start: dict | None = None, mlp_lr: float = 1e-4, hard: int = 16,
                      mine_poses: int = 48, expressions: bool = True, loss: dict | None = None,
                      gate_deg: float | None = None, single_axis: bool = False,
                      gate_chain: float = 0.0, mine_identities: int | None = None,
                      corner: float = 0.0, report=None) -> dict:
    """Pose correctives P, the personalised components and M_P, and the neck's skinning
    weights, learned by :class:`~hack_render.learn.pose_energy.PoseEnergyLearner` over the
    whole joint space (see that module for why this replaced :func:`learn_pose`). Returns
    model arrays and a report.

    ``start``: model arrays whose correctives and weights (``pose_*``,
    ``skinning_weights``) the learner continues from; an M_P that had died (its output's
    spread over identities under :data:`MP_DEAD`) is restarted
    (:meth:`~hack_render.learn.pose_energy.PoseEnergyLearner.restart_personalisation`), a
    live one continues; without ``start`` P and the components start at zero.

    ``expressions``: train on the model's own rest meshes (larynx, personalised expressions)
    with sampled expressions, as the stress test measures (:func:`model_rest_fn`); otherwise
    on T_bar + B_S(beta). ``hard``: hard-example rows per step (0: none); ``mine_poses``:
    the poses per identity screened for them every 10 steps, over ``mine_identities``
    identities (default: ``identities``). ``gate_deg``: the
    correctives' gate (model format 3, written as ``pose_gate_deg``), or None for plain
    ``R - I`` features; ``gate_chain``: its chain weight (format 4, ``pose_gate_chain``; 0:
    none). ``single_axis``: a quarter of the poses whole-head rotations about
    one axis alone; ``corner``: that share of the full-range whole-head poses near the
    box's corners (:class:`~hack_render.learn.pose_energy.PoseEnergyLearner`); ``report``:
    called with the measured time a step takes (``PoseEnergyLearner.fit``)."""
    sub = pose_subset(arrays)
    n, m = len(arrays["template_vertices"]), len(sub)
    learner = energy_learner(arrays, num_components=num_components, seed=seed,
                             expressions=expressions, loss=loss, gate_deg=gate_deg,
                             single_axis=single_axis, gate_chain=gate_chain, corner=corner)
    old_spread = None
    if start is not None:
        learner.start_from(start)
        old_spread = learner.personalisation_spread(seed)
        restarted = old_spread < MP_DEAD
        if restarted:
            learner.restart_personalisation(seed)
    res = learner.fit(iterations=iterations, lr=lr, identities=identities, poses=poses,
                      learn_weights=learn_weights, seed=seed, progress=progress, mlp_lr=mlp_lr,
                      hard=hard, mine_poses=mine_poses, mine_identities=mine_identities,
                      report=report)
    generic = np.zeros((72, n, 3), np.float32)
    generic[:, sub] = res.pose_basis
    out = {"pose_basis": generic, "pose_pca_vertices": sub.astype(np.int32),
           "pose_pca_mean": np.zeros((72, m, 3), np.float32),
           "pose_pca_components": res.components}
    out.update({f"pose_mlp_{k}": v for k, v in res.mlp.items()})
    if gate_deg:
        out["pose_gate_deg"] = np.asarray(gate_deg, np.float32)
        if gate_chain:
            out["pose_gate_chain"] = np.asarray(gate_chain, np.float32)
    if learn_weights:
        w = np.asarray(arrays["skinning_weights"], np.float64).copy()
        w[sub] = res.weights
        out["skinning_weights"] = clean_weights(w, arrays["skinning_weights"]).astype(np.float32)
    report = {"method": "energy (hack_render.learn.pose_energy)", "iterations": iterations,
              "lr_cm": lr, "mlp_lr": mlp_lr, "identities_per_step": identities, "poses_per_identity": poses,
              "components": num_components, "subset_vertices": int(m),
              "region_triangles": len(learner.region.faces), "learned_weights": learn_weights,
              "loss_weights": learner.lam, "seconds": res.seconds, "history": res.history,
              "seed": seed, "hard_examples_per_step": hard,
              "mine_poses": mine_poses, "mine_identities": mine_identities or identities,
              "gate_deg": gate_deg or None,
              "gate_chain": gate_chain if gate_deg else 0.0,
              "single_axis_head_poses": single_axis, "corner_poses": corner,
              "rest": ("the model's rest mesh (larynx, personalised expressions), half the "
                       "identities with a sampled expression" if expressions
                       else "T_bar + B_S(beta), neutral")}
    if start is not None:
        report["continued"] = {"from": "the input model's correctives and neck weights",
                               "mp_restarted": restarted, "old_mp_output_std_max": old_spread}
    return {"arrays": out, "report": report}


def pose_curves(out: dict, num_identities: int = 200, seed: int = 5) -> dict:
    """Compactness of the personalised pose blendshapes: explained variance of the deltas
    m(beta) C over sampled identities (beta ~ N(0, I)), against the number of components."""
    rng = np.random.default_rng(seed)
    w = mlp_forward({k[9:]: v for k, v in out.items() if k.startswith("pose_mlp_")},
                    rng.standard_normal((num_identities, out["pose_mlp_w0"].shape[1])))
    comps = np.asarray(out["pose_pca_components"], np.float64).reshape(len(out["pose_pca_components"]), -1)
    # the deltas w C have rank <= C: their spectrum is that of (w - mean) scaled by C's Gram
    wc = w - w.mean(0)
    g = comps @ comps.T
    u, s, _ = np.linalg.svd(g)
    half = (u * np.sqrt(s.clip(min=0))) @ u.T  # G^(1/2): same spectrum, symmetric
    sv = np.linalg.eigvalsh(half @ (wc.T @ wc) @ half)[::-1].clip(min=0)
    ev = np.cumsum(sv) / max(sv.sum(), 1e-30)
    ref = np.abs(np.asarray(out["pose_basis"], np.float64)).max()
    return {"explained_variance": ev.tolist(),
            "personal_to_generic": float(np.abs(w @ comps).max() / max(ref, 1e-30)),
            "note": f"personal deltas m(beta) C of {num_identities} sampled identities; "
                    "personal_to_generic = their largest entry over the generic P's"}


def pose_provenance(report: dict) -> dict:
    """Model-file provenance of the pose correctives and the neck's skinning weights."""
    out = {"pose_blendshapes": (
        "optimised (not captured): generic P, personalised components and the M_P MLP "
        "minimise the neck skin's deformation energy (strain, stretch and compression tails, "
        "folds, bending, never worse than plain LBS) under LBS over poses sampled from the "
        f"whole joint space ({report['iterations']} Adam steps x {report['identities_per_step']} "
        f"identities beta ~ N(0, I) x {report['poses_per_identity']} poses: each joint uniform "
        "within its limits, whole-head rotations up to each axis's full range, singly and "
        "combined); hack_render.learn.pose_energy")}
    if report.get("continued"):
        out["pose_blendshapes"] += (f"; these {report['iterations']} steps continued from the "
                                    "input model's correctives and neck weights, with M_P "
                                    "restarted (its mean output folded into P)")
    if report.get("learned_weights"):
        out["skinning_weights_neck"] = ("optimised with the pose correctives (same energy), "
                                        "from the procedural weights, on the neck's "
                                        f"{report['subset_vertices']} vertices")
    return out


def build_full_model(ict_path: str | Path, num_expression_identities: int = 300,
                     num_pose_identities: int = 4, pose_iterations: int = 700,
                     expression_epochs: int = 3000, learn_weights: bool = True,
                     progress: bool = True, report=None) -> tuple[dict, dict]:
    """Arrays and metadata of the v2 default model (see module docstring).
    ``num_pose_identities``: identities per step of the pose learner (new ones each step);
    ``report``: called with the pose stage's measured time a step (:func:`learn_pose_energy`)."""
    torch.set_num_threads(1)
    timings = {}
    t = time.time()
    arrays, meta = build_default_model(ict_path)
    timings["v1"] = time.time() - t
    curves = {"shape": shape_curves(arrays)}
    t = time.time()
    lar = learn_larynx(arrays, progress=progress)
    arrays.update(lar.arrays)
    arrays["template_vertices"] = lar.template
    arrays["shape_components"] = lar.shape_components
    timings["larynx"] = time.time() - t
    t = time.time()
    ex = learn_expressions(arrays, lar.template, lar.shape_components,
                           num_identities=num_expression_identities, epochs=expression_epochs,
                           progress=progress)
    arrays.update(ex.arrays)
    timings["expressions"] = time.time() - t
    t = time.time()
    po = learn_pose_energy(arrays, iterations=pose_iterations, identities=num_pose_identities,
                           learn_weights=learn_weights, progress=progress, report=report)
    arrays.update(po["arrays"])
    timings["pose"] = time.time() - t
    curves["larynx"] = lar.report.pop("curves")
    curves["expression"] = ex.report.pop("curves")
    curves["pose"] = pose_curves(po["arrays"])
    prov = meta["provenance"]
    prov.update({
        "template": prov["template"] + "; larynx removed (derived: bi-harmonic fill of the "
                    "front neck between the chin-neck angle and the notch)",
        "shape_space": prov["shape_space"] + "; larynx removed by the same linear operator "
                       f"(components orthonormal to {lar.report['shape_component_change_max']:.3f})",
        "larynx": "simulated + derived: Gamma = ICT identity (+ a simulated thyroid prominence at "
                  "C4-C5, 5-10 mm male / 1-3 mm female, sex drawn from neck width) - its "
                  "larynx-removed neck; UV-space PCA; c(beta) by ridge regression",
        "personalised_expressions": f"derived: deformation transfer (Sumner & Popovic 2004) of the "
                                    f"53 ICT shapes onto {num_expression_identities} sampled "
                                    "identities; PCA (50) + M_E MLP",
    })
    prov.update(pose_provenance(po["report"]))
    meta["model_version"] = 2
    meta["learn"] = {"larynx": lar.report, "expressions": ex.report, "pose": po["report"],
                     "timings_s": timings, "curves": curves}
    return arrays, meta
