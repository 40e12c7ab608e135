"""The neck over the whole joint space (issue 21): a seeded 200-pose subset of
``bench/bench_pose_space.py`` on the shipped model, the measures it rests on, and the
skeleton's placement behind the pharynx.

Poses: half with every joint uniform within its limits, the rest whole-head rotations up to
each axis's full range (singly and combined) shared out by ``distribute_head_rotation``.
The model shipped before this change (correctives regressed onto one-axis-at-a-time
sequences) fails 01-03 by far: over the bench's 2,000 poses x 10 identities it folded skin
in 12,417 of the 20,000 and stretched skin edges by up to 3,138 %.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hack_render.geometry import load_default_model
from hack_render.geometry.deformation import (
    deformation_stats,
    fold_mask,
    model_deformation,
    sample_pose_space,
    skin_topology,
)
from hack_render.geometry.model import HackModel
from hack_render.geometry.model_file import load_model_file, save_model_file, without_correctives


@pytest.fixture(scope="module")
def measured():
    """Stretch, compression and folds per pose, shipped model and plain LBS (the same
    model without its pose correctives), for the template and two sampled identities."""
    model = load_default_model()
    arrays, meta = load_model_file(model.source_path)
    lbs = HackModel(without_correctives(arrays), meta)
    topo = skin_topology(model)
    theta = torch.cat(list(sample_pose_space(200, seed=2100).values())).float()
    g = torch.Generator().manual_seed(2101)
    betas = torch.cat([torch.zeros(1, 20), torch.randn(2, 20, generator=g)])
    out = {}
    for name, m in (("model", model), ("lbs", lbs)):
        st = [model_deformation(m, b[None], theta, topo=topo) for b in betas]
        out[name] = {k: torch.stack([getattr(s, k) for s in st]).numpy()
                     for k in ("stretch", "compression", "folded")}
    return out


def test_01_correctives_never_fold_what_lbs_does_not(measured):
    m, lbs = measured["model"]["folded"], measured["lbs"]["folded"]
    worse = np.argwhere(m > lbs)
    assert len(worse) == 0, f"{len(worse)} poses fold more triangles than LBS, e.g. {worse[:5]}"


def test_02_correctives_never_stretch_more_than_lbs(measured):
    """Within 3 points of stretch on every pose, and within 1 point on 99 % of them
    (measured: none of 600 above 1 point, the largest excess 0.000; the file shipped before
    this one: 4, the worst 2.9 points; the one before that was up to 26 times LBS's
    stretch). test_14 holds it to the issue's stricter rule."""
    m, lbs = measured["model"]["stretch"], measured["lbs"]["stretch"]
    excess = m - lbs
    assert excess.max() <= 0.03, (excess.max(), np.unravel_index(excess.argmax(), excess.shape))
    assert (excess > 0.01).sum() <= 0.01 * excess.size


def test_03_correctives_lower_the_stretch(measured):
    m, lbs = measured["model"]["stretch"], measured["lbs"]["stretch"]
    assert np.median(m) <= 0.8 * np.median(lbs), (np.median(m), np.median(lbs))
    assert np.quantile(m, 0.99) <= 0.9 * np.quantile(lbs, 0.99)
    assert measured["model"]["folded"].sum() <= 0.2 * max(measured["lbs"]["folded"].sum(), 1)


def test_04_measures_golden():
    """Rigid motion deforms nothing; a uniform 10 % scale stretches every edge by 0.1; a
    triangle turned inside out is counted once."""
    model = load_default_model()
    topo = skin_topology(model)
    rest = model.template[None]
    rot = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # 90 deg about Z
    eye = torch.eye(3).expand(1, 9, 3, 3)
    st = deformation_stats(rest, rest @ rot.T, rot.expand(1, 9, 3, 3), topo)
    assert abs(float(st.stretch[0])) < 1e-5 and int(st.folded[0]) == 0
    st = deformation_stats(rest, 1.1 * rest, eye, topo)
    assert abs(float(st.stretch[0]) - 0.1) < 1e-4 and abs(float(st.compression[0]) + 0.1) < 1e-4
    a, b, c = topo.faces[100].tolist()
    flipped = rest.clone()
    flipped[0, a] = rest[0, b] + rest[0, c] - rest[0, a]  # reflect a corner across its edge
    assert int(deformation_stats(rest, flipped, eye, topo).folded[0]) >= 1
    mask = fold_mask(rest, flipped, eye, topo)[0]  # the triangles the count counts
    assert bool(mask[100]) and int(mask.sum()) == int(deformation_stats(rest, flipped, eye,
                                                                        topo).folded[0])


def test_05_neck_region_and_skin_measures():
    """The learner's region: unique edges, adjacent pairs share an edge; its measures
    agree with the stress test's under a rigid rotation and a scale."""
    from hack_render.learn.full_model import SKIN_LAST, pose_subset
    from hack_render.learn.neck_region import neck_region, skin_measures

    model = load_default_model()
    arrays, _ = load_model_file(model.source_path)
    region = neck_region(arrays["faces"], SKIN_LAST, pose_subset(arrays))
    assert len(torch.unique(region.edges, dim=0)) == len(region.edges)
    f = region.faces
    shared = [len(set(f[i].tolist()) & set(f[j].tolist())) for i, j in region.pairs[:200].tolist()]
    assert all(s == 2 for s in shared)
    rest = model.template[region.vertices].double()[None]
    w = model.skinning_weights[region.vertices].double()[f].mean(1)
    rot = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.3, 0.2], [0.3, 0, -0.1], [-0.2, 0.1, 0]],
                                               dtype=torch.float64))
    r, cos, bend = skin_measures(region, rest, rest @ rot.T, rot.expand(1, 9, 3, 3), w)
    assert r.abs().max() < 1e-9 and (cos - 1).abs().max() < 1e-9 and bend.abs().max() < 1e-9
    r, _, _ = skin_measures(region, rest, 1.25 * rest, torch.eye(3, dtype=torch.float64).expand(1, 9, 3, 3), w)
    assert (r - 0.25).abs().max() < 1e-9


def test_06_joints_lie_behind_the_pharynx():
    """ANATOMY.md: the vertebral bodies lie behind the pharynx. The template's column is
    placed 12 mm behind the mouth socket's posterior midline wall (its throat); over 50
    identities the joints at the socket's height stay behind it (the regressor follows the
    skin, not the socket: the median margin is 12-13 mm at c2-c3 and c1-c2, the smallest
    -1 mm over 200 identities, about the 1 cm slice's own scatter). The skeleton shipped
    before sat on the wall (c2-c3 0.1 mm in front of it, c1-c2 inside)."""
    from hack_render.learn.skeleton_fit import pharynx_wall

    model = load_default_model()
    socket = torch.nonzero(model.vertex_group == model.group_names.index("mouth_socket")).flatten().numpy()
    g = torch.Generator().manual_seed(7)
    betas = torch.cat([torch.zeros(1, 20), torch.randn(49, 20, generator=g)])
    with torch.no_grad():
        out = model(beta=betas, eta=torch.zeros(50))
    margins = []
    for b in range(len(betas)):
        j = out.rest_joints[b].numpy()
        margins.append(pharynx_wall(out.rest_vertices[b].numpy(), socket, j[:, 1]) - j[:, 2])
    margins = np.asarray(margins)  # (50, 8) metres, NaN where the socket does not reach
    assert abs(margins[0, 5] - 0.012) < 1e-3 or abs(margins[0, 6] - 0.012) < 1e-3  # as placed
    for k in (5, 6):  # c2-c3, c1-c2: the socket reaches them for every identity
        assert np.isfinite(margins[:, k]).all()
        assert np.median(margins[:, k]) >= 0.010, (k, np.median(margins[:, k]))
    assert np.nanmin(margins) >= -0.002, np.nanmin(margins)


def test_07_learn_pose_writes_a_model_that_loads(tmp_path, capsys):
    """`hack-render learn pose` re-learns a model file's correctives (2 steps here): the
    output validates, carries every pose key, changes only the pose group and the neck's
    weights, and says how it was made; it says what a step trains on and, measured, how
    long a step takes (no fixed guess: a step's cost follows the settings)."""
    from hack_render.cli import main

    out = tmp_path / "m.npz"
    main(["learn", "pose", "-o", str(out), "--iterations", "2", "--identities", "1",
          "--mine-poses", "5", "--quiet"])
    err = capsys.readouterr().err
    assert "learn pose: 2 steps; each trains on 1 identities x 8 poses and 16 hard rows, " \
        "and every 10 steps 1 x 5 rows are screened" in err
    assert "s a step here (over the first 2), ~" in err
    src, _ = load_model_file(load_default_model().source_path)
    new, meta = load_model_file(out)
    # without --continue or --pose-gate the correctives are learned ungated
    assert {k for k in src if k.startswith("pose_") and not k.startswith("pose_gate")} == \
        {k for k in new if k.startswith("pose_")}
    neck = np.zeros(len(src["skinning_weights"]), bool)
    neck[new["pose_pca_vertices"]] = True
    np.testing.assert_array_equal(new["skinning_weights"][~neck], src["skinning_weights"][~neck])
    np.testing.assert_allclose(new["skinning_weights"].sum(1), 1, atol=1e-5)
    assert not np.array_equal(new["pose_basis"], src["pose_basis"])
    assert "optimised" in meta["provenance"]["pose_blendshapes"]
    assert meta["learn"]["pose"]["iterations"] == 2
    assert meta["learn"]["pose"]["mine_poses"] == 5  # the screen's poses, as asked
    HackModel(new, meta)(theta=torch.full((1, 8, 3), 0.05))  # it runs


def test_08_pose_learner_personalises():
    """A few learner steps on the shipped arrays: the loss terms are finite, and M_P's
    output differs between identities (its hidden units once all died at a large learning
    rate, leaving one constant for every identity)."""
    from hack_render.learn.full_model import SKIN_LAST, pose_subset
    from hack_render.learn.neck_region import neck_region
    from hack_render.learn.pose_energy import PoseEnergyLearner

    arrays, _ = load_model_file(load_default_model().source_path)
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    sub = pose_subset(arrays)
    learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                arrays["skinning_weights"], arrays["joint_parents"],
                                neck_region(arrays["faces"], SKIN_LAST, sub), seed=3)
    res = learner.fit(iterations=6, identities=2, poses=4, seed=3, progress=False, log_every=1)
    assert all(np.isfinite(h["loss"]) for h in res.history)
    with torch.no_grad():
        out = learner.mlp(torch.randn(16, 20, dtype=torch.float64))
    assert float(out.std(0).max()) > 1e-4


def test_09_edge_paths_match_dijkstra():
    """The bound's shortest edge paths (Bellman-Ford in torch) equal scipy's Dijkstra on a
    jittered grid, unreachable vertices included."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from hack_render.geometry.deformation import edge_path_lengths

    g = torch.Generator().manual_seed(9)
    n = 12
    ij = torch.stack(torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij"), -1).reshape(-1, 2)
    v = torch.cat([ij.double() + 0.3 * torch.rand(n * n, 2, generator=g, dtype=torch.float64),
                   torch.rand(n * n, 1, generator=g, dtype=torch.float64)], 1)
    idx = torch.arange(n * n).reshape(n, n)
    e = torch.cat([torch.stack([idx[:, :-1].flatten(), idx[:, 1:].flatten()], 1),
                   torch.stack([idx[:-1].flatten(), idx[1:].flatten()], 1),
                   torch.stack([idx[:-1, :-1].flatten(), idx[1:, 1:].flatten()], 1)])
    e = e[(e != idx[5, 5]).all(1)]  # one vertex cut off
    src = torch.tensor([0, 17, 77, idx[5, 5]])
    ours = edge_path_lengths(v, e, src).numpy()
    ln = (v[e[:, 0]] - v[e[:, 1]]).norm(dim=1).numpy()
    a, b = e[:, 0].numpy(), e[:, 1].numpy()
    graph = coo_matrix((np.r_[ln, ln], (np.r_[a, b], np.r_[b, a])), shape=(n * n, n * n)).tocsr()
    ref = dijkstra(graph, indices=src.numpy())
    np.testing.assert_array_equal(np.isinf(ours), np.isinf(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(ours[fin], ref[fin], rtol=1e-12)


def test_10_stretch_bound(measured):
    """The stretch lower bound (no deformer that keeps the face rigid with the skull and the
    chest rim with the thorax can stretch skin less): never above what plain LBS or the
    shipped model measure on the subset's 600 pose-identity pairs; at most 0 at zero pose
    (a straight line is no longer than a path); at the full-range extension (-70.5 deg shared
    out) 0.73 on the template, bound by the front of the neck between the chin-neck angle
    and the chest rim (measured: 11.9 cm of skin path whose ends move 20.6 cm apart)."""
    from hack_render.geometry.deformation import (
        anchor_paths,
        model_stretch_bound,
        rigid_anchors,
        stretch_lower_bound,
    )
    from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
    from hack_render.geometry.skeleton import distribute_head_rotation

    model = load_default_model()
    topo = skin_topology(model)
    anchors = rigid_anchors(model, topo)
    assert set(anchors.node.tolist()) == {0, 8}  # the chest rim and the skull
    theta = torch.cat(list(sample_pose_space(200, seed=2100).values())).float()
    g = torch.Generator().manual_seed(2101)
    betas = torch.cat([torch.zeros(1, 20), torch.randn(2, 20, generator=g)])
    bound = np.stack([model_stretch_bound(model, b[None], theta, topo=topo, anchors=anchors).numpy()
                      for b in betas])
    for name in ("lbs", "model"):
        gap = measured[name]["stretch"] - bound
        assert gap.min() >= 0, (name, gap.min(), np.unravel_index(gap.argmin(), gap.shape))
    assert bound.max() > 0.6  # the subset holds poses where the 60 % target cannot be met

    person = model.personalize(torch.zeros(1, 20))
    rest = person().vertices[0].double()
    j = person.joints.double().reshape(1, -1, 3)
    ext = distribute_head_rotation(torch.tensor([[np.deg2rad(-70.5), 0.0, 0.0]], dtype=torch.float64))
    th = torch.cat([torch.zeros_like(ext), ext])
    _, rel = rigid_transforms(local_rotations(th, th.new_zeros(2, 3)),
                              torch.cat([j[:, :1], j], 1).expand(2, -1, -1), chain_parents(model.parents))
    paths = anchor_paths(rest, anchors)
    b = stretch_lower_bound(rest, rel, anchors, paths)
    assert float(b[0]) <= 1e-12
    assert abs(float(b[1]) - 0.73) < 0.02, float(b[1])
    m = rel[1][anchors.node]
    p = torch.einsum("sij,sj->si", m[:, :3, :3], rest[anchors.vertices]) + m[:, :3, 3]
    ratio = torch.cdist(p, p) / paths.clamp(min=1e-12) * (anchors.node[:, None] != anchors.node[None])
    s, t = np.unravel_index(int(ratio.argmax()), ratio.shape)
    ends = rest[anchors.vertices[[s, t]]]
    assert (ends[:, 0].abs() < 0.01).all() and (ends[:, 2] > 0.03).all()  # front midline


def _dead_mp(arrays: dict) -> dict:
    """The model arrays with M_P's last layer zeroed: its output is the constant b2."""
    out = dict(arrays)
    out["pose_mlp_w2"] = np.zeros_like(arrays["pose_mlp_w2"])
    return out


def test_11_restart_personalisation_keeps_the_mean_corrective():
    """Continuing a learner from a model file whose M_P is dead (the shipped file's M_P with
    its last layer zeroed: one constant output for every identity, as an M_P whose hidden
    units died returns): its constant output is folded into P (the mean corrective is
    unchanged) and M_P starts again, small and identity-dependent."""
    from hack_render.learn.full_model import SKIN_LAST, pose_subset
    from hack_render.learn.neck_region import neck_region
    from hack_render.learn.pose_energy import PoseEnergyLearner

    arrays = _dead_mp(load_model_file(load_default_model().source_path)[0])
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                arrays["skinning_weights"], arrays["joint_parents"],
                                neck_region(arrays["faces"], SKIN_LAST, pose_subset(arrays)), seed=4)
    learner.start_from(arrays)
    beta = torch.randn(64, 20, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    with torch.no_grad():
        before = learner.blendshapes(beta)
    spread = learner.restart_personalisation(seed=4)
    assert spread < 1e-6  # one constant
    with torch.no_grad():
        after = learner.blendshapes(beta)
        out = learner.mlp(beta)
    scale = float(before.abs().max())
    assert float((after.mean(0) - before.mean(0)).abs().max()) < 0.02 * scale
    assert float(out.std(0).max()) > 1e-5 and float(out.abs().max()) < 0.5


def test_12_learn_pose_continue(tmp_path):
    """`learn pose --continue` starts from the file's correctives (one tiny step here: P stays
    within a few per cent of the file's) with the file's gate and chain weight, keeps a live
    M_P and restarts a dead one (its mean folded into P), and says so in the file."""
    from hack_render.cli import main

    src, src_meta = load_model_file(load_default_model().source_path)
    dead = tmp_path / "dead.npz"
    save_model_file(dead, _dead_mp(src), src_meta)
    for model, restarted in ((None, False), (dead, True)):
        out = tmp_path / f"m{int(restarted)}.npz"
        main(["learn", "pose", "--continue", "-o", str(out), "--iterations", "1",
              "--identities", "1", "--lr", "1e-6", "--hard-examples", "0", "--quiet"]
             + (["--model", str(model)] if model else []))
        new, meta = load_model_file(out)
        p0, p1 = np.asarray(src["pose_basis"]), np.asarray(new["pose_basis"])
        assert np.abs(p1 - p0).max() < 0.05 * np.abs(p0).max()
        assert meta["learn"]["pose"]["continued"]["mp_restarted"] == restarted
        assert "continued from the input model" in meta["provenance"]["pose_blendshapes"]
        for k in ("pose_gate_deg", "pose_gate_chain"):
            assert float(new[k]) == float(src[k])
        if not restarted:  # the live M_P goes on: its weights moved by one tiny step only
            np.testing.assert_allclose(new["pose_mlp_w2"], src["pose_mlp_w2"], atol=1e-3)


def test_13_learner_rest_is_the_models_and_screen_finds_folds():
    """The learner on the model's own rest meshes (larynx, personalised expressions, an
    expression held) poses the neck exactly as the model does (less the flexion block of a
    format-5 file, which the learner does not carry: `learn pose` leaves it out); its
    hard-example screen flags every row where plain LBS folds skin (with P at zero the
    learner is plain LBS)."""
    from hack_render.geometry.deformation import sample_head_poses
    from hack_render.learn.full_model import SKIN_LAST, model_rest_fn, pose_subset
    from hack_render.learn.neck_region import neck_region
    from hack_render.learn.pose_energy import PoseBatch, PoseEnergyLearner

    model = load_default_model().double()
    arrays, meta = load_model_file(model.source_path)
    plain = without_correctives(arrays)
    region = neck_region(arrays["faces"], SKIN_LAST, pose_subset(plain))
    std = np.asarray(arrays["shape_std"], np.float64)
    dirs = np.asarray(arrays["shape_components"], np.float64)[:20] * std[:20, None, None]
    learner = PoseEnergyLearner(arrays["template_vertices"], dirs, arrays["joint_regressor"],
                                arrays["skinning_weights"], arrays["joint_parents"], region,
                                rest_fn=model_rest_fn(plain, region.vertices), seed=13,
                                gate_deg=float(arrays["pose_gate_deg"]),
                                gate_chain=float(arrays["pose_gate_chain"]))
    learner.start_from(arrays)
    g = torch.Generator().manual_seed(13)
    theta = sample_head_poses(48, g, "xyz")
    beta = torch.randn(1, 20, generator=g, dtype=torch.float64).expand(48, -1)
    psi = model.expression_vector("jawOpen=0.5, mouthSmile_L=0.8, mouthSmile_R=0.8").expand(48, -1)
    rest, joints = learner.rest(beta, psi)
    batch = PoseBatch(beta, theta, psi, rest, joints)
    with torch.no_grad():
        posed, _ = learner.pose(batch)
        no_block = HackModel({k: v for k, v in arrays.items() if not k.startswith("flex_")},
                             meta).double()
        ref = no_block(beta=beta, psi=psi, theta=theta).vertices[:, region.vertices]
    assert float((posed - ref).abs().max()) < 1e-6  # 1 micrometre: float32-stored arrays

    lbs = HackModel(plain, meta).double()
    folded = model_deformation(lbs, beta[:1], theta, psi[:1]).folded
    assert int((folded > 0).sum()) >= 2  # full-range combined rotations: LBS folds some
    with torch.no_grad():
        learner.p_cm.zero_()
        learner.c_cm.zero_()
    flagged = learner.screen(batch)
    assert bool(flagged[folded > 0].all()), (folded.tolist(), flagged.tolist())
    assert not bool(flagged.all())


#: the expression the bench holds over its poses (bench/bench_pose_space.py EXPRESSION)
BENCH_EXPRESSION = "mouthSmile_L=0.8, mouthSmile_R=0.8, jawOpen=0.5, browDown_L=0.4, browDown_R=0.4"


@pytest.fixture(scope="module")
def expression_measured():
    """As ``measured`` (the same 200 poses, template and two sampled identities), with the
    bench's expression held: stretch and folds, shipped model and its plain LBS."""
    model = load_default_model()
    arrays, meta = load_model_file(model.source_path)
    lbs = HackModel(without_correctives(arrays), meta)
    topo = skin_topology(model)
    theta = torch.cat(list(sample_pose_space(200, seed=2100).values())).float()
    g = torch.Generator().manual_seed(2101)
    betas = torch.cat([torch.zeros(1, 20), torch.randn(2, 20, generator=g)])
    psi = model.expression_vector(BENCH_EXPRESSION)
    out = {}
    for name, m in (("model", model), ("lbs", lbs)):
        st = [model_deformation(m, b[None], theta, psi, topo=topo) for b in betas]
        out[name] = {k: torch.stack([getattr(s, k) for s in st]).numpy() for k in ("stretch", "folded")}
    return out


def _issue60_rules(res) -> None:
    """Issue 60's rules on 600 pose-identity pairs: no folded skin triangle at all, every
    pair's largest stretch at most 3 points above the same identity's plain LBS, and at
    most 0.5 % of pairs (3) more than 1 point above it."""
    stretch, folded = res["model"]["stretch"], res["model"]["folded"]
    what = f"{int((folded > 0).sum())} pairs fold {int(folded.sum())} triangles"
    assert folded.sum() == 0, (what, np.argwhere(folded > 0)[:5])
    excess = stretch - res["lbs"]["stretch"]
    assert excess.max() <= 0.03, (excess.max(), np.unravel_index(excess.argmax(), excess.shape))
    assert (excess > 0.01).sum() <= 0.005 * excess.size, int((excess > 0.01).sum())


def test_14_no_folds_and_never_meaningfully_worse_than_lbs(measured):
    """Issue 60's rules (:func:`_issue60_rules`) on the subset's 600 neutral pairs
    (measured with model versions 3, 4 and 5: no fold, none above LBS by more than a point,
    the largest excess 0.000; version 2 folded in 6 pairs, 57 triangles, and was above by
    more than a point in 4)."""
    _issue60_rules(measured)


def test_14_with_the_expression(expression_measured):
    """The same rules with the bench's expression held (measured with model version 5: no
    fold, none above LBS by more than a point, the largest excess 0.000; version 4 folded
    in 1 of these pairs, 2 triangles, version 3 in 2, version 2 in 11). In the default suite
    since version 5 (about 90 s; an opt-in expected failure before)."""
    _issue60_rules(expression_measured)


def test_15_arap_reference_holds_the_rigid_sets_and_the_bound():
    """The stretch bench's reference deformer (`learn.pose_data.arap_deformation`: DQS, then
    ARAP of the skin with the vertices skinned to one node held rigid, the bound's rigid
    sets) never stretches below the bound, and spreads the stretch: on 8 combined
    full-range head rotations of the template, below plain LBS's in the median."""
    from hack_render.geometry.deformation import model_stretch_bound, sample_head_poses
    from hack_render.learn.pose_data import arap_deformation

    model = load_default_model()
    lbs = HackModel({k: v for k, v in load_model_file(model.source_path)[0].items()
                     if not k.startswith("pose_")}, model.meta)
    theta = sample_head_poses(8, torch.Generator().manual_seed(15), "xyz")
    beta = torch.zeros(1, 20)
    topo = skin_topology(model)
    arap = arap_deformation(model, beta, theta, topo=topo, iterations=20)
    bound = model_stretch_bound(model, beta, theta.float(), topo=topo).double()
    plain = model_deformation(lbs, beta, theta.float(), topo=topo)
    assert (arap.stretch >= bound - 1e-9).all(), (arap.stretch - bound).min()
    assert float(arap.stretch.median()) < float(plain.stretch.median()) - 0.1, (
        arap.stretch, plain.stretch)
