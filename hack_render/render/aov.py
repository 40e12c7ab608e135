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


def _hit_region_uv(head, si, valid, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Region id (H, W) and model UV (H, W, 2) of a pixel grid of intersections (0 if none)."""
    import drjit as dr
    import mitsuba as mi

    shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
    dr.eval(si.uv, shape_id, valid)
    hit = np.asarray(valid, dtype=bool).reshape(h, w)
    uv = np.asarray(si.uv, dtype=np.float64).reshape(2, h, w).transpose(1, 2, 0)
    ids = np.asarray(shape_id, dtype=np.int64).reshape(h, w)
    region = np.zeros((h, w), np.int32)
    u_model = np.zeros((h, w))
    for sid, (reg, u_off, u_scale) in head._shape_regions.items():
        m = hit & (ids == sid)
        region[m] = reg
        u_model[m] = uv[..., 0][m] / u_scale + u_off
    v_model = np.where(hit, 1.0 - uv[..., 1], 0.0)
    return region, np.stack([u_model, v_model], axis=-1)


def region_hits(head, offset=(0.5, 0.5), see_through=("eyelashes",)) -> dict[str, np.ndarray]:
    """What one primary ray per pixel, through sub-pixel point ``offset``, hits.

    Used for soft (coverage) segmentation masks: call it for a grid of offsets in
    [0, 1)^2 and average. Rays that hit a region named in ``see_through`` (the
    half-transparent lash cards) are continued once, so the surface behind is known too.

    Returns:
        ``region`` (H, W) int32 id (``parts.REGIONS``, 0 = nothing), ``uv`` (H, W, 2) model
        UVs of that hit; ``region_behind`` / ``uv_behind``: the same for the next surface
        behind a see-through hit (0 elsewhere).
    """
    import drjit as dr
    import mitsuba as mi

    from hack_render.render.parts import REGIONS

    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    x = mi.Float(idx % w) + float(offset[0])
    y = mi.Float(idx // w) + float(offset[1])
    sensor = head.scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    si = head.scene.ray_intersect(ray)
    region, uv = _hit_region_uv(head, si, si.is_valid(), h, w)
    out = {"region": region, "uv": uv, "region_behind": np.zeros_like(region),
           "uv_behind": np.zeros_like(uv)}
    through = [REGIONS.index(n) for n in see_through if n in REGIONS]
    if through and np.isin(region, through).any():
        si2 = head.scene.ray_intersect(si.spawn_ray(ray.d))
        mask = mi.Bool(np.isin(region, through).ravel())
        r2, uv2 = _hit_region_uv(head, si2, si2.is_valid() & mask, h, w)
        out["region_behind"], out["uv_behind"] = r2, uv2
    return out


def point_visibility(head, points, tolerance: float = 2e-3,
                     see_through=("eyelashes",)) -> tuple[np.ndarray, np.ndarray]:
    """Whether world points (n, 3) metres are seen by the current camera.

    A point is ``in_image`` when it lies in front of the camera and projects inside the
    image; it is ``visible`` when it is in the image and the ray from the camera centre
    to it meets no surface more than ``tolerance`` metres before it (surfaces of the
    ``see_through`` regions, the lash cards, do not occlude). Points inside the body
    (e.g. the cervical joints) are in the image but never visible.

    Returns:
        (in_image (n,) bool, visible (n,) bool).
    """
    import drjit as dr
    import mitsuba as mi

    from hack_render.render.parts import REGIONS

    cam = head.camera
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = (p @ cam.R.T + cam.t)[:, 2]
    px = cam.project(p)
    in_image = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) \
        & (px[:, 1] < cam.height)
    o = cam.center
    d = p - o
    dist = np.linalg.norm(d, axis=1)
    d = d / np.maximum(dist, 1e-12)[:, None]
    ray = mi.Ray3f(mi.Point3f(*[np.full(len(p), c, np.float32) for c in o]),
                   mi.Vector3f(*[d[:, k].astype(np.float32) for k in range(3)]))
    blocked = np.zeros(len(p), bool)
    alive = np.ones(len(p), bool)
    through_regions = [REGIONS.index(n) for n in see_through if n in REGIONS]
    through_ids = [sid for sid, (reg, _, _) in head._shape_regions.items() if reg in through_regions]
    travelled = np.zeros(len(p))
    for _ in range(4):  # at most a few see-through layers in front of a point
        si = head.scene.ray_intersect(ray)
        shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
        dr.eval(si.t, shape_id)
        t = np.where(np.asarray(si.is_valid(), bool), np.asarray(si.t, np.float64), np.inf)
        ids = np.asarray(shape_id, np.int64)
        hit_before = alive & (travelled + t < dist - tolerance)
        passes = hit_before & np.isin(ids, through_ids)
        blocked |= hit_before & ~passes
        alive = passes
        if not alive.any():
            break
        travelled = travelled + np.where(alive, t, 0.0)
        ray = si.spawn_ray(ray.d)
    return in_image, in_image & ~blocked
