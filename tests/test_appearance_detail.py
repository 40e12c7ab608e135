"""Pore detail layer composed with PCA normals."""

import numpy as np
import torch

from appearance.detail import compose_detail, detail_slopes, upsample_normals


def _flat(h=16, b=2):
    n = torch.zeros(b, h, 2 * h, 3, dtype=torch.float64)
    n[..., 2] = 1
    n[0, :, :, 0] = 0.3
    return n / n.norm(dim=-1, keepdim=True)


def test_detail_deterministic_and_seeded():
    a, b, c = detail_slopes(256, 0), detail_slopes(256, 0), detail_slopes(256, 1)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0


def test_compose_unit_normals_and_strength_zero():
    n = _flat()
    out = compose_detail(n, 256, seed=0)
    assert out.shape == (2, 256, 512, 3)
    assert torch.allclose(out.norm(dim=-1), torch.ones((), dtype=out.dtype), atol=1e-9)
    assert (out[..., 2] > 0).all()
    base = compose_detail(n, 256, strength=0.0)
    assert torch.allclose(base, upsample_normals(n, 256))
    # a constant input normal stays constant when upsampled
    assert torch.allclose(base[0, ..., 0], base[0, 0, 0, 0].expand_as(base[0, ..., 0]))
    assert (out - base).abs().max() > 1e-3  # the detail layer changes the normals


def test_pores_where_expected():
    from appearance.regions import REGION_ID, region_labels

    d = detail_slopes(1024, 0)
    lab = region_labels(1024)
    mag = np.linalg.norm(d, axis=-1)
    assert mag[lab == REGION_ID["nose"]].mean() > 2 * mag[lab == REGION_ID["lips"]].mean()
