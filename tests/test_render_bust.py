"""The bust cap: the skin's cut is closed, so no view sees the inside of the skin."""

import numpy as np
import pytest
import torch

from hack_render.render.engine import ensure_variant
from hack_render.render.parts import (
    CAP_APEX,
    REGIONS,
    Topology,
    boundary_loops,
    bust_cap,
    split_parts,
)

ensure_variant()

import drjit as dr
import mitsuba as mi

from hack_render.geometry import load_default_model
from hack_render.geometry.skeleton import distribute_head_rotation, head_rotation_range_deg
from hack_render.render import footprint
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights


@pytest.fixture(scope="module")
def model_mesh():
    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    return model, Topology.from_model(model), v


def test_01_the_cone_follows_the_posed_cut():
    """Over the rest pose, the 8 corners of the whole-head range and 7 seeded combined
    rotations: the apex lies CAP_APEX beyond the cut's centroid, on the side away from the
    skin; the cone's faces point out of the body (along its axis); NumPy and torch (the differentiable
    render's path) give the same positions, and the apex's gradient reaches the loop's
    vertices only."""
    model = load_default_model()
    topo = Topology.from_model(model)
    skin = topo.faces[np.isin(topo.face_material, [topo.material_names.index(m)
                                                   for m in ("M_Face", "M_BackHead")])]
    rng = np.random.default_rng(11)
    lo, hi = head_rotation_range_deg().numpy().T
    corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3)
    angles = np.concatenate([np.zeros((1, 3)), corners, rng.uniform(lo, hi, (7, 3))])
    for ang in angles:
        theta = distribute_head_rotation(torch.as_tensor(np.radians(ang), dtype=torch.float32))
        with torch.no_grad():
            v = model(theta=theta[None]).vertices[0].double().numpy()
        cap = bust_cap(topo, v)
        p = cap.positions(v)
        assert p.shape == (cap.num_vertices, 3) == (len(cap.gather) + 1, 3)
        apex, centre = p[-1], p[:-1].mean(0)
        assert np.linalg.norm(apex - centre) == pytest.approx(CAP_APEX, rel=1e-9)
        assert np.dot(apex - centre, centre - v[np.unique(skin)].mean(0)) > 0
        f = p[cap.faces]
        n = np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0])
        backwards = int((n @ (apex - centre) <= 0).sum())
        # measured: one face, at one corner (full extension, turn and bend at once), where
        # the cut's loop turns back on itself as seen along the axis
        assert backwards <= (1 if np.abs(ang).min() > 60 else 0), (ang, backwards)
        t = torch.as_tensor(v).requires_grad_(True)
        pt = cap.positions(t)
        assert torch.allclose(pt, torch.as_tensor(p), atol=1e-12, rtol=0)
        pt[-1].sum().backward()
        moved = t.grad.abs().sum(1) > 0
        assert moved[cap.gather].all() and moved.sum() == len(cap.gather)


def test_02_cap_closes_the_skin(model_mesh):
    """Skin + cap has no boundary left; the cap faces outwards (down, away from the head)."""
    _, topo, v = model_mesh
    parts, _ = split_parts(topo, v, cap=True)
    cap = parts[-1]
    assert cap.name == "bust_cap" and cap.region == REGIONS.index("bust") and cap.flat
    skin = np.isin(topo.face_material, [topo.material_names.index(m)
                                        for m in ("M_Face", "M_BackHead")])
    assert len(boundary_loops(topo.faces[skin])) == 1
    # the apex becomes a new vertex after the model's
    index = np.append(cap.gather, len(v))
    closed = np.concatenate([topo.faces[skin], index[cap.faces]])
    assert boundary_loops(closed) == []
    f = cap.positions(v)[cap.faces]
    n = np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0])
    assert n.sum(0)[1] < 0 and np.dot(n.sum(0), v[cap.gather].mean(0) - v.mean(0)) > 0
    # every cone face points out of the body (down, away from the head)
    assert (np.einsum("ij,ij->i", n, f.mean(1) - v[cap.gather].mean(0)) > 0).all()


def _inside_pixels(head, regions=("face", "back_head")) -> int:
    """Pixels whose centre ray first meets one of ``regions`` from behind: the skin's inside
    (its back faces), or for ``bust`` the cap's inner side (its faces point out of the
    body: the cap lies outside the skin there, poking through it)."""
    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = head.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5))
    si = footprint.camera_hit(head, ray)
    back = si.is_valid() & (dr.dot(si.n, ray.d) > 0)
    g = head.aovs()
    hit = np.isin(g["segmentation"], [REGIONS.index(r) for r in regions])
    return int((np.asarray(back, bool).reshape(h, w) & hit).sum())


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


def test_04_the_cap_stays_inside_the_skin_across_the_neck_range():
    """The corners of the whole-head range and seeded combined rotations, seen from the
    three presets' directions and from behind and below: no pixel shows the cap's inner
    side but one at one corner (the flat cap it replaced, wound outwards: 337 such pixels
    in 29 of these 48 views at 64 px; `docs/render.md`)."""
    model = load_default_model()
    topo = Topology.from_model(model)
    lo, hi = head_rotation_range_deg().numpy().T
    corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3)
    angles = np.concatenate([corners, np.random.default_rng(12).uniform(lo, hi, (4, 3))])
    res, total = 64, []
    for ang in angles:
        theta = distribute_head_rotation(torch.as_tensor(np.radians(ang), dtype=torch.float32))
        with torch.no_grad():
            v = model(theta=theta[None]).vertices[0].double().numpy()
        head = HeadScene(topo, v, lights.preset("studio"), cameras.orbit(res, res, 85.0, 0, 5),
                         RenderSettings(res, res, 1))
        for yaw, pitch in ((0.0, 5.0), (-35.0, 5.0), (-90.0, 5.0), (150.0, -30.0)):
            head.set_camera(cameras.orbit(res, res, 85.0, yaw, pitch))
            total.append(_inside_pixels(head, ("bust",)))
    # the one exception: one cone face turns over at the corner of full extension, turn
    # and bend at once (the cut's loop turns back on itself seen along the cone's axis;
    # test_01), showing 1 pixel of its inner side from behind and below
    turned = [i for i, a in enumerate(angles) if np.allclose(a, (lo[0], hi[1], lo[2]))]
    per_pose = np.array(total).reshape(len(angles), 4).sum(1)
    assert per_pose[turned].sum() <= 1 and np.delete(per_pose, turned).sum() == 0, str(total)
