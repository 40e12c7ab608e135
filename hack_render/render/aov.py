"""Arbitrary output variables from one primary ray through each pixel centre.

Mitsuba's ``aov`` integrator averages integer ids over the pixel filter and reports
depth as ray distance; we want crisp region ids and OpenCV-style depth, so this pass
traces its own primary rays (one per pixel centre, no filter) and reads the hit:

- ``depth``: (H, W) z in the OpenCV camera frame (distance along the optical axis),
  metres; 0 where nothing is hit.
- ``normal``: (H, W, 3) shading normal in the OpenCV camera frame (x right, y down,
  z forward), so a surface facing the camera has z < 0; 0 where nothing is hit.
- ``albedo``: (H, W, 3) diffuse reflectance of the hit material (linear).
- ``uv``: (H, W, 2) the model's own UDIM-style texture coordinates (u in [0, 7], v up).
- ``segmentation``: (H, W) region id (``parts.REGIONS``; 0 = background).
"""

from __future__ import annotations

import numpy as np

AOV_NAMES = ("depth", "normal", "albedo", "uv", "segmentation")


def gbuffer(head) -> dict[str, np.ndarray]:
    """Compute every AOV of a :class:`~hack_render.render.scene.HeadScene`'s current state."""
    import drjit as dr
    import mitsuba as mi

    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    x = mi.Float(idx % w) + 0.5
    y = mi.Float(idx // w) + 0.5
    sensor = head.scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    si = head.scene.ray_intersect(ray)
    valid = si.is_valid()
    albedo = si.bsdf(ray).eval_diffuse_reflectance(si, valid)
    shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
    dr.eval(si.p, si.sh_frame.n, si.uv, albedo, shape_id, valid)

    def arr(v, c):
        return np.asarray(v, dtype=np.float64).reshape(c, h, w).transpose(1, 2, 0) \
            if c > 1 else np.asarray(v, dtype=np.float64).reshape(h, w)

    hit = np.asarray(valid, dtype=bool).reshape(h, w)
    p = arr(si.p, 3)
    cam_p = p @ cam.R.T + cam.t
    n_cam = arr(si.sh_frame.n, 3) @ cam.R.T
    uv = arr(si.uv, 2)
    ids = np.asarray(shape_id, dtype=np.int64).reshape(h, w)
    region = np.zeros((h, w), np.int32)
    u_model = uv[..., 0].copy()
    for sid, (reg, u_off, u_scale) in head._shape_regions.items():
        m = hit & (ids == sid)
        region[m] = reg
        u_model[m] = uv[..., 0][m] / u_scale + u_off
    uv_model = np.stack([u_model, 1.0 - uv[..., 1]], axis=-1)
    zero = ~hit
    out = {
        "depth": np.where(zero, 0.0, cam_p[..., 2]),
        "normal": np.where(zero[..., None], 0.0, n_cam),
        "albedo": np.where(zero[..., None], 0.0, arr(albedo, 3)),
        "uv": np.where(zero[..., None], 0.0, uv_model),
        "segmentation": region,
    }
    return {k: v.astype(np.float32) if k != "segmentation" else v for k, v in out.items()}
