"""bench/mesh68_hand.py: the face mesh's 468 points read as the 68 by index pairs chosen on
hand-placed points (the real-clip bench's reference), and the shipped choice."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def hand():
    sys.path.insert(0, str(ROOT / "bench"))
    spec = importlib.util.spec_from_file_location("mesh68_hand", ROOT / "bench" / "mesh68_hand.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def triangles():
    from hack_render.vision.dense68 import load_map

    return load_map().triangles


@pytest.fixture(scope="module")
def layout():
    """The face mesh's 468 points on a real face (the astronaut, scikit-image's)."""
    import skimage.data

    from hack_render.vision.detect import detect_faces

    return np.asarray(detect_faces(skimage.data.astronaut(), "mesh")[0].dense)[:, :2]


def _faces(rng, base, n, pairs, noise):
    """n faces: the mesh's layout turned, scaled, moved and jittered by 1 px, and truths
    at the given pairs' midpoints plus noise (pixels)."""
    out = []
    for _ in range(n):
        a, s = rng.uniform(-0.3, 0.3), rng.uniform(0.7, 1.4)
        R = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        moved = base @ R.T + rng.uniform(-50, 50, 2) + rng.normal(0, 1.0, base.shape)
        dense = np.c_[moved, np.zeros(468)]
        truth = 0.5 * (dense[pairs[:, 0], :2] + dense[pairs[:, 1], :2])
        out.append((dense, truth + rng.normal(0, noise, truth.shape)))
    return out


def test_01_choose_recovers_known_edge_midpoints_and_single_points(hand, triangles, layout):
    rng = np.random.default_rng(0)
    edges = sorted(hand.edges(triangles))
    pick = rng.choice(len(edges), 68, replace=False)
    pairs = np.array([edges[i] for i in pick])
    pairs[::3, 1] = pairs[::3, 0]            # a third are single points
    samples = _faces(rng, layout, 12, pairs, noise=0.0)
    got = hand.choose(samples, hand.edges(triangles))
    np.testing.assert_array_equal(np.sort(got, 1), np.sort(pairs, 1))
    # and what it chose reads the truth back exactly
    for dense, truth in samples:
        np.testing.assert_allclose(hand.to68(got, dense), truth, atol=1e-9)


def test_02_never_a_pair_across_a_gap(hand, triangles, layout):
    """A truth halfway between two points that share no edge (an upper and a lower lip
    point across the mouth) is read by a point or an edge, never by that pair."""
    rng = np.random.default_rng(1)
    edge_set = hand.edges(triangles)
    nbr = {i: set() for i in range(468)}
    for a, b in edge_set:
        nbr[a].add(b)
        nbr[b].add(a)
    pairs = []
    for a in rng.choice(468, 68, replace=False):   # a point two edges away, no edge between
        second = sorted(set().union(*(nbr[n] for n in nbr[a])) - nbr[a] - {a})
        pairs.append((a, second[rng.integers(len(second))]))
    pairs = np.array(pairs)
    samples = _faces(rng, layout, 8, pairs, noise=0.0)
    got = hand.choose(samples, edge_set)
    for p, q in got:
        assert p == q or (min(p, q), max(p, q)) in edge_set


def test_03_leave_one_out_scores_a_photo_by_pairs_chosen_without_it(hand, triangles, layout):
    """check(): on noiseless faces the held-out score is zero; a photo whose hand-placed
    points are all moved scores its own error (its choice did not see it), the others
    still nearly zero."""
    rng = np.random.default_rng(2)
    edges = sorted(hand.edges(triangles))
    pairs = np.array([edges[i] for i in rng.choice(len(edges), 68, replace=False)])
    samples = _faces(rng, layout, 6, pairs, noise=0.0)
    found = {f"p{i}": {"dense": d, "attention": d[:, :2], "truth": t, "mesh": None,
                       "dlib": None} for i, (d, t) in enumerate(samples)}
    res = hand.check(found, triangles)
    assert res["mean"]["hand_loo"]["nme_mean"] < 0.002   # (a long edge may fall outside the 12)
    assert res["mean"]["hand_loo_plain"] == res["mean"]["hand_loo"]   # the same mesh twice
    # a photo where one mesh found no face is scored by neither (both on the same photos)
    gone = dict(found, p5=dict(found["p5"], attention=None))
    res_gone = hand.check(gone, triangles)
    assert "hand_loo" not in res_gone["photos"]["p5"]
    assert "hand_loo_plain" not in res_gone["photos"]["p5"]
    moved = dict(found)
    t = samples[0][1].copy()
    iod = np.linalg.norm(t[36] - t[45])
    t[:, 1] += 0.05 * iod                    # 5 % of the outer-eye distance, downwards
    moved["p0"] = dict(found["p0"], truth=t)
    res = hand.check(moved, triangles)
    assert res["photos"]["p0"]["hand_loo"]["nme"] == pytest.approx(0.05, rel=0.02)
    assert res["photos"]["p0"]["hand_loo"]["offset"]["brows"][1] == pytest.approx(-0.05, rel=0.02)
    assert max(res["photos"][f"p{i}"]["hand_loo"]["nme"] for i in range(1, 6)) < 0.01


def test_04_shipped_pairs_are_mesh_points_or_edges_and_beat_the_model_map(hand, triangles,
                                                                          tmp_path):
    """The pairs the bench reads (bench/results/mesh68_hand.json): 68 of them on the
    attention mesh, each a point or an edge of the tessellation; scored leave-one-photo-out
    they lie nearer the hands' points than the shipped map and than the plain mesh's own
    pairs on the same photos (mean and median: why the attention mesh is the reference),
    and carry no part's offset over 1 % but the chin's (the mesh ends above the jaw's
    edge)."""
    pairs = hand.load_pairs()
    edge_set = hand.edges(triangles)
    assert pairs.shape == (68, 2) and pairs.min() >= 0 and pairs.max() < 468
    assert all(p == q or (min(p, q), max(p, q)) in edge_set for p, q in pairs.tolist())
    res = json.loads(hand.DEFAULT_OUT.read_text())
    assert res["mesh"] == "attention"
    loo, plain, model = (res["mean"][k] for k in ("hand_loo", "hand_loo_plain", "mesh"))
    assert loo["photos"] >= 20 and loo["nme_mean"] < model["nme_mean"]
    assert loo["photos"] == plain["photos"]
    assert loo["nme_mean"] < plain["nme_mean"] and loo["nme_median"] < plain["nme_median"]
    old = tmp_path / "plain.json"            # a file of pairs on the plain mesh is refused
    old.write_text(json.dumps({"pairs": res["pairs_plain"]}))
    with pytest.raises(SystemExit, match="plain mesh"):
        hand.load_pairs(old)
    assert all(abs(v) < 0.01 for g, off in loo["offset_mean"].items() if g != "chin"
               for v in off)


def test_05_clip_bench_scores_both_readings_of_the_same_mesh(hand, layout):
    """bench_track_real: the hand reading reads the attention mesh and the fitter's map the
    plain one (NaN frames stay unscored); a tracked track equal to one reading scores 0 against it
    and, against the other, what the two readings differ by; the summary of the other
    reading is built from its own per-frame figures."""
    spec = importlib.util.spec_from_file_location("bench_track_real",
                                                  ROOT / "bench" / "bench_track_real.py")
    btr = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(btr)
    from hack_render.vision.dense68 import load_map

    rng = np.random.default_rng(3)
    dense = np.stack([np.c_[layout + rng.normal(0, 1.0, layout.shape), np.zeros(468)]
                      for _ in range(6)])
    dense[2] = np.nan                                    # no face in frame 2
    pairs = hand.load_pairs()
    attention = dense[..., :2] + rng.normal(0, 0.5, dense[..., :2].shape)
    refs = btr.references(dense, attention, pairs)
    np.testing.assert_allclose(refs["hand"][0], hand.to68(pairs, attention[0]))
    np.testing.assert_allclose(refs["model_map"][0], load_map().to68(dense[0]))
    own = btr.score(refs["hand"], refs["hand"])
    other = btr.score(refs["hand"], refs["model_map"])
    assert own["frames_scored"] == other["frames_scored"] == 5
    assert own["nme_median"] == 0.0 and own["per_frame_nme"][2] is None
    iod = np.linalg.norm(refs["model_map"][0, 36] - refs["model_map"][0, 45])
    gap = np.linalg.norm(refs["hand"][0] - refs["model_map"][0], axis=1)[hand.IDX].mean() / iod
    assert other["per_frame_nme"][0] == pytest.approx(gap, abs=1e-5) and gap > 0.01
    rows = [{"nme_median": 0.01, "per_frame_nme": [0.01], "vs_model_map": other},
            {"nme_median": 0.02, "per_frame_nme": [0.02], "vs_model_map": own}]
    s = btr.summary(rows, "vs_model_map")
    assert s["clips"] == 2 and s["worst_clip_median"] == pytest.approx(other["nme_median"])
    assert s["clips_over_4pc"] == int(other["nme_median"] > 0.04)
