"""The pose learner's own machinery (issue 60): its stretch bound is the model's, its hard-
example screen keeps the rows above their bound, its sampler's single-axis head rotations
(moved here from ``test_pose_space.py``, 16 and 17) and corner poses, and the anchor term."""

from __future__ import annotations

import re

import numpy as np
import torch

from hack_render.geometry import load_default_model
from hack_render.geometry.deformation import model_stretch_bound, sample_pose_space
from hack_render.geometry.model_file import load_model_file
from hack_render.learn.full_model import SKIN_LAST, model_rest_fn, pose_subset
from hack_render.learn.neck_region import neck_region, skin_measures
from hack_render.learn.pose_energy import PoseBatch, PoseEnergyLearner


def test_01_learner_bound_is_the_models():
    """The learner's stretch bound (its region's anchors and paths, :mod:`learn.neck_region`)
    equals the model-level bound (:func:`model_stretch_bound`) of the same identity and
    expression over poses of every family; with the ``bound`` loss on, the term is finite
    and positive on full-range rotations, and the screen's ``near_bound`` keeps exactly the
    rows whose largest stretch exceeds their bound by more than it."""
    model = load_default_model().double()
    arrays, _ = load_model_file(model.source_path)
    sub = pose_subset(arrays)
    region = neck_region(arrays["faces"], SKIN_LAST, sub)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                arrays["skinning_weights"], arrays["joint_parents"], region,
                                rest_fn=model_rest_fn(arrays, region.vertices), seed=16,
                                loss={"bound": 1.0, "near_bound": 0.17},
                                gate_deg=float(arrays["pose_gate_deg"]),
                                gate_chain=float(arrays["pose_gate_chain"]))
    learner.start_from(arrays)
    theta = torch.cat(list(sample_pose_space(6, seed=16).values())).double()
    beta = torch.randn(1, 20, generator=torch.Generator().manual_seed(16), dtype=torch.float64)
    psi = model.expression_vector("jawOpen=0.5, mouthSmile_L=0.8, mouthSmile_R=0.8")[None]
    rest, joints = learner.rest(beta, psi)
    ours = learner._bounds(rest, joints, theta, len(theta))
    ref = model_stretch_bound(model, beta, theta, psi=psi)
    assert (ours - ref).abs().max() < 1e-9, (ours - ref).abs().max()
    assert ref.max() > 0.3  # the full-range rotations are in

    n = len(theta)
    batch = PoseBatch(beta.expand(n, -1), theta, psi.expand(n, -1), rest.expand(n, -1, -1),
                      joints.expand(n, -1, -1), bound=ours)
    term = learner.terms(batch)["bound"]
    assert torch.isfinite(term) and float(term) > 0
    with torch.no_grad():
        posed, rot = learner.pose(batch)
        r, _, _ = skin_measures(region, batch.rest, posed, rot, learner.weights()[region.faces].mean(1))
    learner.lam.update(near_fold=-2.0, near_worse=-10.0)  # the other criteria off
    # measured excess over the bound of these 6 rows: 0.12-0.24
    above = r.amax(1) > ours + 0.17
    assert above.any() and not above.all()
    assert torch.equal(learner.screen(batch), above)
    assert len(PoseBatch.cat([batch.rows(above), batch]).bound) == int(above.sum()) + n


def test_02_learner_samples_single_axis_head_rotations():
    """``single_axis``: a quarter of a sampled batch are whole-head rotations about one
    axis alone (a third each of x, y, z: each joint's axis-angle on that axis only);
    without it, none are."""
    arrays, _ = load_model_file(load_default_model().source_path)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    region = neck_region(arrays["faces"], SKIN_LAST, pose_subset(arrays))
    for single in (False, True):
        learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                    arrays["skinning_weights"], arrays["joint_parents"], region,
                                    seed=17, single_axis=single)
        theta = learner.sample(torch.Generator().manual_seed(17), 3, 8).theta
        on = (theta.abs() > 1e-12).any(1)  # (B, 3): the axes any joint turns about
        counts = [int((on.sum(1) == 1)[on[:, a]].sum()) for a in range(3)]
        assert counts == ([2, 2, 2] if single else [0, 0, 0]), counts


def test_03_mining_screens_its_own_identities():
    """``fit(mine_identities=k)`` screens k identities x ``mine_poses`` rows, however many
    identities a training step draws; without it, the step's own count. ``report`` gets
    one line, after the first mining round, with the measured time a step takes."""
    arrays, _ = load_model_file(load_default_model().source_path)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    region = neck_region(arrays["faces"], SKIN_LAST, pose_subset(arrays))
    learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                arrays["skinning_weights"], arrays["joint_parents"], region,
                                rest_fn=model_rest_fn(arrays, region.vertices), seed=18)
    screened = []
    screen = learner.screen
    learner.screen = lambda batch: screened.append(batch) or screen(batch)
    for k, want in ((5, 5), (None, 2)):
        screened.clear()
        lines = []
        learner.fit(iterations=1, identities=2, poses=4, hard=2, mine_poses=4,
                    mine_identities=k, progress=False, learn_weights=False, report=lines.append)
        (line,) = lines
        step = float(re.match(r"about ([0-9.]+) s a step here \(over the first 1\), ~", line)[1])
        assert 0 < step < 120 and line.endswith(" in all")
        (batch,) = screened
        assert len(batch.theta) == 4 * want
        assert len(torch.unique(batch.beta, dim=0)) == want


def test_04_corner_poses_and_the_anchor_term():
    """``corner``: that share of the full-range whole-head poses lies near the box's corners
    (every axis's whole-neck angle in the outer quarter of its range); ``corner=0`` draws
    what the sampler drew before the option (the same generator calls). The ``anchor`` term
    is zero where ``start_from`` left P and C, and the squared change (cm^2) after a step."""
    from hack_render.geometry.anatomy import whole_neck_angles_deg
    from hack_render.geometry.deformation import (
        head_rotation_range_deg,
        sample_corner_head_poses,
        sample_head_poses,
        sample_joint_poses,
    )

    rng = head_rotation_range_deg().numpy()
    span = rng[:, 1] - rng[:, 0]
    ang = whole_neck_angles_deg(sample_corner_head_poses(64, torch.Generator().manual_seed(3)))
    u = (ang - rng[:, 0]) / span
    assert ((u < 0.25 + 1e-6) | (u > 0.75 - 1e-6)).all()
    assert (u < 0.25).any() and (u > 0.75).any()

    arrays, _ = load_model_file(load_default_model().source_path)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    region = neck_region(arrays["faces"], SKIN_LAST, pose_subset(arrays))
    make = lambda corner: PoseEnergyLearner(
        arrays["template_vertices"], dirs, arrays["joint_regressor"], arrays["skinning_weights"],
        arrays["joint_parents"], region, seed=19, corner=corner, loss={"anchor": 1.0})
    # corner 0: the old sampler's draws, in its order
    g = torch.Generator().manual_seed(19)
    last = 0.6 * sample_head_poses(6, g, "xyz")
    th = torch.cat([sample_joint_poses(12, g), sample_head_poses(6, g, "xyz"), last])
    th = th[torch.randperm(len(th), generator=g)]
    assert torch.equal(make(0.0).sample(torch.Generator().manual_seed(19), 3, 8).theta, th)
    # corner 1: every full-range whole-head pose at a corner (of this batch's 24 poses,
    # exactly those 6: the per-joint and the 60 % ones fall short of the outer quarters)
    theta = make(1.0).sample(torch.Generator().manual_seed(19), 3, 8).theta
    u = (whole_neck_angles_deg(theta) - rng[:, 0]) / span
    assert int(((u < 0.25) | (u > 0.75)).all(1).sum()) == 6

    learner = make(0.0)
    learner.start_from(arrays)
    batch = learner.sample(torch.Generator().manual_seed(20), 1, 4)
    assert float(learner.terms(batch)["anchor"].detach()) == 0.0
    with torch.no_grad():
        learner.p_cm[3, 5, 1] += 0.2
        learner.c_cm[0, 3, 5, 1] -= 0.1
    assert abs(float(learner.terms(batch)["anchor"].detach()) - 0.05) < 1e-12
