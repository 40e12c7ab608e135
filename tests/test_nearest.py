"""hack_render.geometry.nearest: the hair's k-d tree answers as scipy's cKDTree does."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from hack_render.geometry.nearest import PointTree


def _cloud(seed: int, n: int) -> np.ndarray:
    # a head-sized shell with noise: the skin's vertices are a surface, not a volume
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    return 0.1 * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(0, 0.003, (n, 3))


@pytest.mark.parametrize("bound", [np.inf, 0.08, 0.01])
def test_01_nearest_is_scipys_within_a_bound_and_beyond_it(bound):
    pts = _cloud(0, 3000)
    q = _cloud(1, 20000) * np.random.default_rng(5).uniform(0.2, 2.2, (20000, 1))
    ref_d, ref_i = cKDTree(pts).query(q, distance_upper_bound=bound)
    d, i = PointTree(pts).query(q, distance_upper_bound=bound)
    assert d.dtype == np.float64 and i.dtype == np.intp and d.shape == (len(q),)
    far = ~np.isfinite(ref_d)
    if np.isfinite(bound):
        assert far.any() and (~far).any()  # both cases met
    np.testing.assert_array_equal(~np.isfinite(d), far)
    np.testing.assert_array_equal(i, ref_i)  # beyond the bound: len(points), as scipy
    np.testing.assert_allclose(d[~far], ref_d[~far], rtol=1e-12, atol=0)


def test_02_k_nearest_keep_their_order_and_the_queries_shape():
    pts, q = _cloud(2, 500), _cloud(3, 60).reshape(3, 20, 3)
    ref_d, ref_i = cKDTree(pts).query(q, k=8)
    d, i = PointTree(pts).query(q, k=8)
    assert d.shape == i.shape == (3, 20, 8)
    np.testing.assert_array_equal(i, ref_i)
    np.testing.assert_allclose(d, ref_d, rtol=1e-12)
    assert np.all(np.diff(d, axis=-1) >= 0)


def test_03_empty_queries_and_an_empty_tree():
    t = PointTree(_cloud(4, 10))
    d, i = t.query(np.zeros((0, 3)))
    assert d.shape == i.shape == (0,)
    d, i = t.query(np.zeros((0, 3)), k=3)
    assert d.shape == i.shape == (0, 3)
    with pytest.raises(ValueError, match="at least one point"):
        PointTree(np.zeros((0, 3)))


def test_04_cross3_and_norm3_are_numpys_bits():
    """``normals.cross3`` and ``normals.norm3`` (the hair's 3-vector products) give the
    bits of ``np.cross`` and ``np.linalg.norm(axis=-1)``, broadcast and in float32 too."""
    from hack_render.geometry.normals import cross3, norm3

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 500, 7, 3))
    for x, y in ((a, b), (a, np.array([0.0, 1.0, 0.0])), (a[:, 1:], b[:, :-1]),
                 (a[0], b[0, 0]), (a.astype(np.float32), b.astype(np.float32))):
        out = cross3(x, y)
        assert out.dtype == np.cross(x, y).dtype
        np.testing.assert_array_equal(out, np.cross(x, y))
    for x in (a, a[:, 1:], a.reshape(-1, 3), a[0, 0], a.astype(np.float32)):
        np.testing.assert_array_equal(norm3(x), np.linalg.norm(x, axis=-1))
        np.testing.assert_array_equal(norm3(x, keepdims=True),
                                      np.linalg.norm(x, axis=-1, keepdims=True))
