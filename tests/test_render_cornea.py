"""The cornea's refraction of the iris (hack_render/render/cornea.py): the solver against
the forward ray trace, the paraxial magnification of a spherical refracting surface, an
oblique view, the switch, and a render of the eye."""

import numpy as np
import pytest

from hack_render.render.engine import ensure_variant

ensure_variant()

from hack_render.render.cornea import (
    CORNEA_IOR,
    CORNEA_RADIUS,
    CorneaRig,
    CorneaSphere,
    apparent_points,
    trace,
)
from hack_render.render.parts import (
    LIMBUS_RADIUS,
    PUPIL_RADIUS,
    REGIONS,
    radial_eye_distance,
    split_parts,
)
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights


@pytest.fixture(scope="module")
def eye(head_model):
    """The rig, the left eye's (model +x) cornea and its refracted iris vertices (k, 3)."""
    topo, v = head_model
    parts, axes = split_parts(topo, v)
    iris = next(p for p in parts if p.name == "iris")
    rig = CorneaRig.from_topology(topo, v, axes, iris.gather)
    i = int(np.argmax([c[0] for c, _ in axes]))
    sphere = rig.spheres(v)[i]
    return rig, sphere, v[rig.iris_gather[rig.iris_of_eye[i]]], axes


def side_camera(sphere: CorneaSphere, degrees: float, distance: float = 0.1) -> np.ndarray:
    """A camera centre ``distance`` from the cornea's apex, ``degrees`` off the optical
    axis about the vertical, to the eye's temporal side (+x)."""
    a = np.radians(degrees)
    side = np.cross([0.0, 1.0, 0.0], sphere.axis)
    side /= np.linalg.norm(side)
    apex = sphere.centre + sphere.radius * sphere.axis
    return apex + distance * (np.cos(a) * sphere.axis + np.sin(a) * side)


def miss_distance(camera, apparent, true, sphere):
    """Distance of each true point from the refracted camera ray through its apparent one."""
    q, t, ok = trace(camera, apparent, sphere)
    assert ok.all(), f"{int((~ok).sum())} apparent points are not seen through the cornea"
    return np.linalg.norm(np.cross(true - q, t), axis=1)


def test_01_round_trip_through_the_cornea(eye):
    """The camera ray through each apparent vertex, refracted where it enters the cornea,
    passes through the true vertex (1e-6 m), for cameras in front, to the side, above."""
    _rig, sphere, p, _ = eye
    for cam in (side_camera(sphere, 0.0), side_camera(sphere, 30.0, 0.5),
                side_camera(sphere, 50.0), side_camera(sphere, -40.0, 0.3),
                sphere.centre + 0.2 * (sphere.axis + [0.0, 0.7, 0.0])):
        seen, moved = apparent_points(p, cam, sphere)
        assert moved.mean() > 0.9, f"only {moved.mean():.0%} of the iris refracted"
        miss = miss_distance(cam, seen[moved], p[moved], sphere)
        assert miss.max() < 1e-6, f"max miss {miss.max():.2e} m at {np.argmax(miss)}"
        # the apparent point lies behind the cornea, within 1.5 mm of the true one
        q, _, _ = trace(cam, seen[moved], sphere)
        assert np.all(np.linalg.norm(seen[moved] - cam, axis=1)
                      > np.linalg.norm(q - cam, axis=1))
        assert np.linalg.norm(seen - p, axis=1).max() < 1.5e-3


def test_02_frontal_magnification_is_the_paraxial_one():
    """Points of a plane d = 3 mm behind the apex, seen along the axis from D = 1 m,
    subtend the angle of their paraxial image: lateral magnification m = n s' / s of a
    single spherical surface (1 / s' = (n - 1) / R - n / d, the image virtual), times
    (D + d) / (D + |s'|) for the image's nearer depth."""
    n, r_c, d, dist = CORNEA_IOR, CORNEA_RADIUS, 3e-3, 1.0
    sphere = CorneaSphere(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    s_img = 1.0 / ((n - 1.0) / r_c - n / d)  # negative: a virtual image behind the apex
    m = n * -s_img / d
    expected = m * (dist + d) / (dist - s_img)
    assert 1.09 < m < 1.13  # the entrance pupil's known ~1.1x
    h = np.array([0.1e-3, 0.5e-3, 1.0e-3, 2.0e-3])
    p = np.stack([h, np.zeros_like(h), np.full_like(h, r_c - d)], 1)
    cam = np.array([0.0, 0.0, r_c + dist])
    seen, moved = apparent_points(p, cam, sphere)
    assert moved.all()

    def slope(x):  # tangent of the angle off the axis, from the camera
        return x[:, 0] / (cam[2] - x[:, 2])

    ratio = slope(seen) / slope(p)
    np.testing.assert_allclose(ratio[:2], expected, rtol=2e-3)  # paraxial
    np.testing.assert_allclose(ratio, expected, rtol=0.03)  # the iris's few mm
    # depth: the reduced distance d / n on the axis
    assert seen[0, 2] == pytest.approx(r_c - d / n, abs=2e-6)


def test_03_model_eye_frontal_magnification(eye):
    """The model's pupil, seen along the eye's axis, is magnified as its depth behind
    the cornea's apex predicts (paraxial formula of test 02, within 3 %)."""
    _rig, sphere, p, axes = eye
    apex = sphere.centre + sphere.radius * sphere.axis
    r, _ = radial_eye_distance(p, axes)
    pupil = p[r < PUPIL_RADIUS]
    d = float(np.mean((apex - pupil) @ sphere.axis))
    assert 2e-3 < d < 3e-3  # ICT's iris: 2.4 mm behind the apex (a real eye: ~3.6)
    n, dist = CORNEA_IOR, 0.1
    s_img = 1.0 / ((n - 1.0) / CORNEA_RADIUS - n / d)
    expected = n * -s_img / d * (dist + d) / (dist - s_img)
    cam = apex + dist * sphere.axis
    seen, _ = apparent_points(pupil, cam, sphere)

    def off_axis(x):  # tangent of the angle off the camera's axis
        rel = x - cam
        along = -(rel @ sphere.axis)
        return np.linalg.norm(rel + along[:, None] * sphere.axis, axis=1) / along

    ratio = np.median(off_axis(seen) / off_axis(pupil))
    assert ratio == pytest.approx(expected, rel=0.03)


def limbus_polygon(sphere: CorneaSphere, k: int = 180) -> np.ndarray:
    """(k, 3) points of the limbus circle (where the cornea meets the sclera)."""
    u = np.cross(sphere.axis, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(sphere.axis, u)
    a = np.linspace(0.0, 2.0 * np.pi, k, endpoint=False)
    return (sphere.centre + sphere.limbus_height * sphere.axis
            + LIMBUS_RADIUS * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * w))


def inside_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: (n,) bool for 2-D points (n, 2) in a closed polygon (k, 2)."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = ((y0 > y) != (y1 > y)) & (x < x0 + (y - y0) * (x1 - x0) / (y1 - y0 + 1e-300))
    return crosses.sum(1) % 2 == 1


def test_04_oblique_view_moves_the_pupil_towards_the_camera(eye):
    """At 50 degrees off the axis the apparent pupil moves towards the camera (across
    the axis, by 0.1-0.4 mm), and in the image it stays inside the limbus's outline."""
    _rig, sphere, p, axes = eye
    cam_c = side_camera(sphere, 50.0)
    r, _ = radial_eye_distance(p, axes)
    pupil = p[r < PUPIL_RADIUS]
    seen, moved = apparent_points(pupil, cam_c, sphere)
    assert moved.all()
    towards = cam_c - sphere.centre
    towards -= (towards @ sphere.axis) * sphere.axis
    towards /= np.linalg.norm(towards)
    shift = (seen.mean(0) - pupil.mean(0)) @ towards
    assert 1e-4 < shift < 4e-4, f"{shift * 1e3:.3f} mm"
    R, t = cameras.look_at(cam_c, sphere.centre + sphere.radius * sphere.axis)
    cam = cameras.Camera(cameras.intrinsics(256, 256, 120.0), R, t, 256, 256, "side")
    limbus = cam.project(limbus_polygon(sphere))
    assert inside_polygon(cam.project(seen), limbus).all()
    # (the iris's rim, on the far side, may show beyond the limbus's outline, through the
    # bulge of the cornea as it does in an eye seen from the side)


def test_05_points_the_cornea_cannot_show_keep_their_place():
    """Points on the sphere (the limbus circle) stay put; points in front of it, or seen
    from behind the eye, are not moved."""
    sphere = CorneaSphere(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    on = limbus_polygon(sphere, 8)
    cam = np.array([0.0, 0.0, 0.1])
    seen, _ = apparent_points(on * (1.0 - 1e-9), cam, sphere)
    np.testing.assert_allclose(seen, on, atol=1e-10)
    outside = np.array([[0.0, 0.0, CORNEA_RADIUS + 1e-3]])
    behind = np.array([[0.0, 0.0, -0.1]])
    inner = np.array([[1e-3, 0.0, 5e-3]])
    for pts, c in ((outside, cam), (inner, behind)):
        out, moved = apparent_points(pts, c, sphere)
        assert not moved.any() and np.array_equal(out, pts)


def test_06_the_rig_follows_a_moved_head(head_model, eye):
    """Turning the head and the camera together turns the apparent iris with them (the
    corneas ride on the eyes' rigid fit)."""
    _topo, v = head_model
    rig, sphere, _, _ = eye
    a = np.radians(25.0)
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    cam = side_camera(sphere, 20.0)
    base = rig.iris_positions(v, cam)
    turned = rig.iris_positions(v @ rot.T + [0.01, 0.0, 0.0], rot @ cam + [0.01, 0.0, 0.0])
    np.testing.assert_allclose(turned, base @ rot.T + [0.01, 0.0, 0.0], atol=1e-9)


def eye_camera(sphere: CorneaSphere, degrees: float, res: int) -> cameras.Camera:
    R, t = cameras.look_at(side_camera(sphere, degrees, 0.11), sphere.centre
                           + (sphere.radius - 2e-3) * sphere.axis)
    return cameras.Camera(cameras.intrinsics(res, res, 120.0), R, t, res, res, "eye")


def test_07_switch_and_camera_updates(head_model, eye):
    """cornea=False gives the model's vertices exactly; cornea=True moves the iris alone,
    as the current camera sees it, after set_camera and set_vertices alike."""
    topo, v = head_model
    rig, sphere, _, _ = eye
    cam0, cam1 = eye_camera(sphere, 0.0, 16), eye_camera(sphere, 45.0, 16)
    plain = HeadScene(topo, v, lights.preset("studio"), cam0, RenderSettings(16, 16, 1),
                      cornea=False)
    head = HeadScene(topo, v, lights.preset("studio"), cam0, RenderSettings(16, 16, 1))
    assert plain.cornea is None and head.cornea is not None

    def positions(h, name):
        return np.asarray(h.params[f"{name}.vertex_positions"]).reshape(-1, 3)

    for part in plain.parts:
        want = part.positions(v).astype(np.float32)
        assert np.array_equal(positions(plain, part.name), want), part.name
        if part.name != "iris":
            assert np.array_equal(positions(head, part.name), want), part.name
    iris = rig.iris_gather
    f32 = np.float32
    assert np.array_equal(positions(head, "iris"), rig.iris_positions(v, cam0.center).astype(f32))
    head.set_camera(cam1)
    assert np.array_equal(positions(head, "iris"), rig.iris_positions(v, cam1.center).astype(f32))
    v2 = v + [0.0, 0.002, 0.0]
    head.set_vertices(v2)
    assert np.array_equal(positions(head, "iris"), rig.iris_positions(v2, cam1.center).astype(f32))
    plain.set_camera(cam1)
    plain.set_vertices(v2)
    assert np.array_equal(positions(plain, "iris"), v2[iris].astype(f32))


def test_08_render_changes_the_iris_alone(head_model, eye):
    """A 48 px close-up at 50 degrees, same seed, with and without the cornea: the iris
    region changes (the labels see the moved iris too); away from it (2 px margin) the
    images agree within Monte Carlo noise."""
    topo, v = head_model
    _rig, sphere, _, _ = eye
    cam = eye_camera(sphere, 50.0, 48)
    out = {}
    for on in (False, True):
        head = HeadScene(topo, v, lights.preset("studio"), cam, RenderSettings(48, 48, 16),
                         cornea=on)
        out[on] = head.render(seed=3, backdrop=False), head.region_hits()["region"]
    (img0, reg0), (img1, reg1) = out[False], out[True]
    iris = (reg0 == REGIONS.index("iris")) | (reg1 == REGIONS.index("iris"))
    assert iris.sum() > 60
    assert (reg0 != reg1).sum() > 5  # the label pass sees the moved iris
    near = iris.copy()
    for _ in range(2):  # a 2 px margin: pixel filter, the iris's shadow and reflections
        near = near | np.roll(near, 1, 0) | np.roll(near, -1, 0) | np.roll(near, 1, 1) \
            | np.roll(near, -1, 1)
    diff = np.abs(img1[..., :3] - img0[..., :3]).mean(-1)
    assert diff[iris].mean() > 0.01
    assert diff[~near].mean() < 0.1 * diff[iris].mean()
    assert np.array_equal(img0[~near][:, 3], img1[~near][:, 3]) or \
        np.abs(img0[~near][:, 3] - img1[~near][:, 3]).max() < 1e-6
