"""The overlay's rasteriser (``hack_render.render.raster``, ``hack_render.track.draw``):
the ray caster's image in a fraction of its time, and the hidden parts it skips."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hack_render.geometry import load_default_model
from hack_render.geometry.skeleton import distribute_head_rotation


@pytest.fixture(scope="module")
def model():
    return load_default_model()


def test_15_the_rasterised_overlay_equals_the_ray_cast_one(model):
    """overlay.mp4's model is rasterised (``render.raster``), not ray cast: on the model
    turned and tilted, the same pixels are covered (a few edge pixels may differ) and
    their shading agrees with the mesh viewer's ray caster's, back faces (the lashes'
    sheets) included, the skin's culled; the blend over a frame differs by under a grey
    level or two. The mouth is open in one of the views."""
    from hack_render.fit.camera import R0
    from hack_render.render.mesh_views import MeshViews
    from hack_render.render.raster import render_shaded
    from hack_render.track.draw import blend
    from hack_render.track.outputs import skin_faces
    from scenes.cameras import Camera

    faces = model.faces.numpy()
    h = torch.tensor([[0.1, 0.5, 0.05], [-0.2, -0.3, 0.1]])
    psi = torch.zeros(2, model.num_expressions)
    psi[1, list(model.expression_names).index("jawOpen")] = 0.8   # the mouth open
    with torch.no_grad():
        V = model(psi=psi, theta=distribute_head_rotation(h)).vertices.double().numpy()
    K = np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1.0]])
    camera = Camera(K, R0.double().numpy(), np.array([0.0, -0.06, 0.75]), 160, 120, "test")
    views = MeshViews(V[0], faces, width=160, height=120)
    img = np.random.default_rng(0).integers(0, 256, (120, 160, 3)).astype(np.uint8)
    for v in V:
        views.set_vertices(v, faces)
        ray = views.render(camera, supersample=1)
        ras = render_shaded(v, faces, camera, closed=skin_faces(model))
        a, b = ray[..., 3] > 0.5, ras[..., 3] > 0.5
        assert a.sum() > 3000 and (a != b).sum() <= 0.002 * a.sum()
        both = a & b
        d = np.abs(ray[..., :3] - ras[..., :3])[both]
        assert np.median(d) < 1e-4 and np.mean(d > 0.01) < 0.005
        diff = np.abs(blend(img, ray).astype(int) - blend(img, ras).astype(int))
        assert np.median(diff[both]) <= 1 and np.mean(diff > 2) < 0.005


def test_16_hidden_parts_are_culled_without_changing_the_image(model, monkeypatch):
    """The rasteriser draws the closed skin first and skips the open parts (teeth,
    tongue, the eyes' inner layers) that the skin hides over their whole box: the same
    fragments as drawing every triangle, mouth closed and open; with the mouth closed
    most open triangles are skipped."""
    from hack_render.fit.camera import R0
    from hack_render.render import raster
    from hack_render.track.outputs import skin_faces
    from scenes.cameras import Camera

    faces, closed = model.faces.numpy(), skin_faces(model)
    psi = torch.zeros(2, model.num_expressions)
    psi[1, list(model.expression_names).index("jawOpen")] = 0.9
    h = torch.tensor([[0.05, 0.3, 0.0], [-0.15, -0.2, 0.1]])
    with torch.no_grad():
        V = model(psi=psi, theta=distribute_head_rotation(h)).vertices.double().numpy()
    K = np.array([[900.0, 0, 128], [0, 900.0, 128], [0, 0, 1.0]])
    camera = Camera(K, R0.double().numpy(), np.array([0.0, -0.05, 0.75]), 256, 256, "test")
    names = list(model.material_names)
    mouth = np.isin(model.face_material.numpy(),
                    [names.index(n) for n in ("M_Teeth", "M_GumsTongue")])
    culled, seen = [], []
    real = raster._hidden

    def spy(*a):
        out = real(*a)
        culled.append(out)
        return out

    for i, v in enumerate(V):
        monkeypatch.setattr(raster, "_hidden", spy)
        got = raster.fragments(v, faces, camera, closed)
        monkeypatch.setattr(raster, "_hidden", lambda sbuf, lo, hi, near: np.zeros(len(lo), bool))
        want = raster.fragments(v, faces, camera, closed)
        order_g, order_w = np.argsort(got[0]), np.argsort(want[0])
        assert len(got[0]) > 10000 and np.array_equal(got[0][order_g], want[0][order_w])
        assert np.array_equal(got[1][order_g], want[1][order_w])
        np.testing.assert_allclose(got[2][order_g], want[2][order_w], atol=1e-9)
        seen.append(int(np.isin(got[1], np.flatnonzero(mouth)).sum()))
    # the mouth closed, most of the open parts skipped; opened, far more teeth are seen
    assert culled[0].mean() > 0.3 and seen[1] > 5 * max(seen[0], 1)
