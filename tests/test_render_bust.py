"""The bust cap: the skin's cut is closed, so no view sees the inside of the skin."""

import numpy as np
import pytest
import torch

from hack_render.render.engine import ensure_variant
from hack_render.render.parts import (
    REGIONS,
    Topology,
    boundary_loops,
    split_parts,
    triangulate_polygon,
)

ensure_variant()

import drjit as dr
import mitsuba as mi

from hack_render.geometry import load_default_model
from hack_render.render import footprint
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights


@pytest.fixture(scope="module")
def model_mesh():
    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    return model, Topology.from_model(model), v


def test_01_ear_clipping_covers_a_concave_polygon_exactly():
    """A seeded concave star: n - 2 counter-clockwise triangles whose areas sum to the
    polygon's (shoelace) area, for both windings."""
    rng = np.random.default_rng(4)
    n = 40
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = np.where(np.arange(n) % 2, 1.0, 0.35) * rng.uniform(0.8, 1.2, n)
    pts = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
    area = 0.5 * abs(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))
    for poly in (pts, pts[::-1]):
        tri = triangulate_polygon(poly)
        a, b, c = poly[tri[:, 0]], poly[tri[:, 1]], poly[tri[:, 2]]
        signed = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
        assert tri.shape == (n - 2, 3) and (signed > 0).all()
        assert signed.sum() == pytest.approx(area, rel=1e-9)


def test_02_cap_closes_the_skin(model_mesh):
    """Skin + cap has no boundary left; the cap faces outwards (down, away from the head)."""
    _, topo, v = model_mesh
    parts, _ = split_parts(topo, v, cap=True)
    cap = parts[-1]
    assert cap.name == "bust_cap" and cap.region == REGIONS.index("bust") and cap.flat
    skin = np.isin(topo.face_material, [topo.material_names.index(m)
                                        for m in ("M_Face", "M_BackHead")])
    assert len(boundary_loops(topo.faces[skin])) == 1
    closed = np.concatenate([topo.faces[skin], cap.gather[cap.faces]])
    assert boundary_loops(closed) == []
    f = v[cap.gather][cap.faces]
    n = np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0]).sum(0)
    assert n[1] < 0 and np.dot(n, v[cap.gather].mean(0) - v.mean(0)) > 0


def _inside_pixels(head) -> int:
    """Pixels whose centre ray first meets the skin from behind (its inside)."""
    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = head.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5))
    si = footprint.camera_hit(head, ray)
    back = si.is_valid() & (dr.dot(si.n, ray.d) > 0)
    g = head.aovs()
    skin = np.isin(g["segmentation"], [REGIONS.index("face"), REGIONS.index("back_head")])
    return int((np.asarray(back, bool).reshape(h, w) & skin).sum())


def test_03_no_view_sees_inside_the_skin(model_mesh):
    """Orbit views all round and from below: without the cap the inside of the skin
    shows (the black of the issue); with it, not one pixel."""
    _, topo, v = model_mesh
    res = 64
    counts = {}
    for cap in (False, True):
        head = HeadScene(topo, v, lights.preset("studio"), cameras.orbit(res, res, 85.0, 0, 5),
                         RenderSettings(res, res, 1), bust_cap=cap)
        counts[cap] = []
        for yaw in range(0, 360, 30):
            for pitch in (5.0, -30.0):
                head.set_camera(cameras.orbit(res, res, 85.0, yaw, pitch))
                counts[cap].append(_inside_pixels(head))
    assert sum(counts[False]) > 200
    assert sum(counts[True]) == 0, counts[True]
