"""Lighting and camera presets: conventions checked against Mitsuba, EXR sky, OpenCV K R t."""

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.render.engine import ensure_variant
from scenes import cameras, lights


def test_01_latlong_convention_matches_mitsuba_envmap():
    ensure_variant()
    import drjit as dr
    import mitsuba as mi

    h = 32
    img = np.zeros((h, 2 * h, 3), np.float32)
    marks = [(6, 9), (20, 45), (16, 32)]
    for r, c in marks:
        img[r, c] = 100.0
    env = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(img)})
    d = lights.latlong_directions(h)
    for r, c in marks:
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*(-d[r, c]).tolist())
        hit = float(np.asarray(env.eval(si))[0, 0])
        si.wi = mi.Vector3f(*(d[r, c]).tolist())  # the opposite direction sees nothing
        miss = float(np.asarray(env.eval(si))[0, 0])
        assert hit > 10.0 and miss < 1.0
    assert d[h // 2, h, 2] > 0.99  # the centre of the map lies in front of the face (+Z)


def test_02_overcast_sky_is_written_as_exr_and_brightest_at_the_sun(tmp_path, monkeypatch):
    from hack_render.io.image import read_hdr_image

    monkeypatch.setattr(lights, "DATA_DIR", tmp_path)
    path = lights.overcast_sky_file()
    assert path.parent == tmp_path and path.suffix == ".exr"
    sky = read_hdr_image(path)
    d = lights.latlong_directions(sky.shape[0])
    sun = np.asarray((0.45, 0.75, 0.5)) / np.linalg.norm((0.45, 0.75, 0.5))
    r, c = np.unravel_index(np.argmax(sky[..., 1]), sky.shape[:2])
    assert d[r, c] @ sun > np.cos(np.radians(4.0))
    up = sky[: sky.shape[0] // 8].mean()
    horizon = sky[sky.shape[0] // 2 - 2: sky.shape[0] // 2].mean()
    assert up > horizon  # CIE overcast: brighter at the zenith than at the horizon


@pytest.mark.parametrize("name", sorted(lights.PRESETS))
def test_03_every_lighting_preset_has_light(name):
    rig = lights.preset(name, rotation_deg=20.0, exposure=1.0)
    assert rig.area or rig.env_constant is not None or rig.env_file or rig.env_map is not None
    assert rig.scale == 2.0 and rig.rotation_deg == 20.0


def test_04_unknown_presets_are_errors():
    with pytest.raises(HackError, match="studio"):
        lights.preset("disco")
    with pytest.raises(HackError, match="portrait"):
        cameras.preset("fisheye", 64, 64)


def test_05_cameras_frame_the_target_and_are_rigid():
    for cam in cameras.preset("ring", 64, 48, n=6) + cameras.preset("profile", 64, 48):
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(cam.R) == pytest.approx(1.0)
        np.testing.assert_allclose(cam.project(np.asarray(cameras.DEFAULT_TARGET)), [32, 24],
                                   atol=1e-9)
    ring = cameras.preset("ring", 64, 48, n=6)
    yaw = [np.degrees(np.arctan2(c.center[0], c.center[2] - cameras.DEFAULT_TARGET[2])) for c in ring]
    np.testing.assert_allclose(np.diff(np.unwrap(np.radians(yaw))), np.radians(60.0), atol=1e-9)


def test_06_portrait_focal_length_sets_k():
    cam = cameras.portrait(720, 900, focal_mm=50.0)[0]
    assert cam.K[0, 0] == pytest.approx(50.0 / 36.0 * 720)
    # the framed head (0.36 m) fits: its top and bottom project inside the image
    top = np.asarray(cameras.DEFAULT_TARGET) + [0, 0.18, 0]
    bottom = np.asarray(cameras.DEFAULT_TARGET) - [0, 0.18, 0]
    assert 0 < cam.project(top)[1] < cam.project(bottom)[1] < 900
