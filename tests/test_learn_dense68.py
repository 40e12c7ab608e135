"""hack_render.learn.dense68: the face-mesh-to-68 map's fit recovers known affine weights,
and its trim keeps samples the mesh model got wrong (an occluder) from pulling them."""

from __future__ import annotations

import numpy as np

from hack_render.learn.dense68 import fit_map


def _samples(rng, n: int, outliers: float):
    """Dense points scattered over a face of size ~1 (jittered per sample), each true
    landmark a known affine combination of three neighbouring points plus noise; the given
    share of the samples has every landmark thrown 0.3 face sizes off."""
    base = rng.uniform(0, 1, (468, 2))
    # each landmark on three neighbouring points (the mesh's points about it)
    centres = rng.uniform(0.1, 0.9, (68, 2))
    ids = np.argsort(np.linalg.norm(base[None] - centres[:, None], axis=-1), 1)[:, :3]
    w = rng.uniform(0.2, 0.6, (68, 3))
    w /= w.sum(1, keepdims=True)
    sizes = rng.uniform(80, 160, n)
    dense = np.zeros((n, 468, 3))
    truth = np.zeros((n, 68, 2))
    bad = rng.random(n) < outliers
    for s in range(n):
        d = base + rng.normal(0, 0.02, base.shape)
        t = np.einsum("lk,lkc->lc", w, d[ids]) + rng.normal(0, 0.002, (68, 2))
        if bad[s]:
            t += rng.choice([-1, 1], (68, 2)) * 0.3
        dense[s, :, :2] = d * sizes[s] + 7.0
        truth[s] = t * sizes[s] + 7.0
    return dense, truth, sizes, ids, w


def _error(index, weight, ids, w, dense, truth, sizes):
    """Median distance in face sizes between the fitted and the true combinations."""
    fit = np.einsum("lk,slkc->slc", weight, dense[:, index, :2])
    true = np.einsum("lk,slkc->slc", w, dense[:, ids, :2])
    return float(np.median(np.linalg.norm(fit - true, axis=-1) / sizes[:, None]))


def test_fit_map_recovers_known_weights():
    rng = np.random.default_rng(3)
    dense, truth, sizes, ids, w = _samples(rng, 120, 0.0)
    index, weight, resid = fit_map(dense, truth, sizes, k=6)
    assert np.allclose(weight.sum(1), 1.0)
    # where a landmark's three true points are among its six nearest (most: a random
    # point may lie nearer), they get the true weights and the others next to none
    held = [lm for lm in range(68) if set(ids[lm]) <= set(index[lm])]
    assert len(held) >= 50
    for lm in held:
        got = dict(zip(index[lm], weight[lm]))
        assert max(abs(got.pop(i) - wt) for i, wt in zip(ids[lm], w[lm])) < 0.05
        assert max(abs(v) for v in got.values()) < 0.05
    assert _error(index, weight, ids, w, dense, truth, sizes) < 0.003
    assert np.median(resid) < 0.005


def test_fit_map_trim_keeps_outliers_out():
    rng = np.random.default_rng(4)
    dense, truth, sizes, ids, w = _samples(rng, 200, 0.08)
    plain = _error(*fit_map(dense, truth, sizes, k=6)[:2], ids, w, dense, truth, sizes)
    trimmed = _error(*fit_map(dense, truth, sizes, k=6, trim=0.15)[:2], ids, w, dense,
                     truth, sizes)
    assert trimmed < 0.004
    assert trimmed < 0.5 * plain
