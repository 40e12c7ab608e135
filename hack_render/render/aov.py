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

Like the path tracer (``hide_emitters``), every pass here looks through the area lights'
rectangles (:func:`hack_render.render.footprint.camera_hit`): a pixel is background,
depth 0, exactly where no surface of the subject is met, so segmentation and depth agree.
"""

from __future__ import annotations

import numpy as np

from hack_render.errors import HackError
from hack_render.render.footprint import CARD_LAYERS, camera_hit, emitter_layers, opacity_at
from hack_render.render.parts import REGIONS

AOV_NAMES = ("depth", "normal", "albedo", "uv", "segmentation")
#: :func:`label_pass` sums coverage in units of 1 / COVERAGE_ONE (exact integer sums)
COVERAGE_ONE = 1 << 24


def card_opacity(head, si, active):
    """Opacity of the scene's see-through cards (``head.see_through_cards``: the lash cards'
    strand texture) at intersections ``si``; 1 where the hit is on no card or not
    ``active``. A Dr.Jit Float."""
    import drjit as dr
    import mitsuba as mi

    ids = dr.reinterpret_array(mi.UInt32, si.bsdf())
    out = dr.full(mi.Float, 1.0, dr.width(si.t))
    for bsdf, opacity in getattr(head, "see_through_cards", ()):
        on = mi.Bool(active) & si.is_valid() & (
            ids == dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf)))
        out = dr.select(on, opacity_at(opacity, si, on), out)
    return out


def emitter_pixels(head) -> np.ndarray:
    """(H, W) bool: pixels whose centre ray meets an emitter's shape before any surface
    of the subject (where a light would show in frame if camera rays saw emitters)."""
    import drjit as dr
    import mitsuba as mi

    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = head.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5, 0.5))
    pi = head.scene.ray_intersect_preliminary(ray)
    hit = pi.is_valid() & pi.shape.is_emitter()
    return np.asarray(hit, dtype=bool).reshape(h, w)


def environment_backdrop(head) -> np.ndarray:
    """(H, W, 3) float32: the environment's radiance along each pixel-centre camera ray
    of ``head`` (zeros without an environment), lights excluded."""
    import drjit as dr
    import mitsuba as mi

    w, h = head.settings.width, head.settings.height
    env = head.scene.environment()
    if env is None:
        return np.zeros((h, w, 3), np.float32)
    idx = dr.arange(mi.UInt32, w * h)
    xy = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = head.scene.sensors()[0].sample_ray(0.0, 0.5, xy, mi.Point2f(0.5))
    si = dr.zeros(mi.SurfaceInteraction3f, w * h)
    si.wi = -ray.d
    rgb = env.eval(si)
    return np.stack([np.broadcast_to(np.asarray(rgb[c], np.float32), (w * h,))
                     for c in range(3)], -1).reshape(h, w, 3)


def gbuffer(head, see_through=(), hits: bool = False) -> dict[str, np.ndarray]:
    """Compute every AOV of a :class:`~hack_render.render.scene.HeadScene`'s current state:
    ``depth``, ``normal`` (camera frame), ``albedo``, ``uv`` (model UV) and
    ``segmentation`` (``parts.REGIONS`` ids) of each pixel centre's first surface. With
    ``see_through`` (region names, e.g. ``("eyelashes",)``) a centre ray whose first
    surface is in one of them is continued past them (through up to
    ``footprint.CARD_LAYERS`` layered cards, as the footprint rays) and the AOVs are
    the first other surface's behind; with ``hits``, also ``prim`` (H, W) int32, the
    hit triangle's index in its shape (-1 where none), and ``position`` (H, W, 3) the
    hit point (world frame, metres), from which a triangle's barycentric coordinates
    follow (:func:`hack_render.fit.part_solve` reads the parts' vertex colours so);
    ``card_opacity`` (H, W) is then the card's opacity at the first hit (0 where the ray
    met none) and ``through`` (H, W) bool where the ray went through one."""
    import drjit as dr
    import mitsuba as mi

    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    x = mi.Float(idx % w) + 0.5
    y = mi.Float(idx // w) + 0.5
    sensor = head.scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    si = camera_hit(head, ray)
    valid = si.is_valid()
    see = [REGIONS.index(name) for name in see_through if name in REGIONS]
    opacity = through = None
    if see:
        through = mi.Bool(False)
        on = mi.Bool(True)
        for layer in range(CARD_LAYERS):  # the cards are layered: on to the first other
            region, _, _ = _region_uv_jit(head, si, valid)
            card = mi.Bool(False)
            for r_ in see:
                card |= valid & on & (region == r_)
            if layer == 0:
                opacity = dr.select(card, card_opacity(head, si, card), 0.0)
            through |= card
            si = dr.select(card, camera_hit(head, si.spawn_ray(ray.d), card), si)
            valid = si.is_valid()
            on = card
    albedo = si.bsdf(ray).eval_diffuse_reflectance(si, valid)
    region, u_model, v_model = _region_uv_jit(head, si, valid)
    dr.eval(si.p, si.sh_frame.n, albedo, region, u_model, v_model, valid, si.prim_index)

    def arr(v, c):
        return np.asarray(v, dtype=np.float64).reshape(c, h, w).transpose(1, 2, 0) \
            if c > 1 else np.asarray(v, dtype=np.float64).reshape(h, w)

    hit = np.asarray(valid, dtype=bool).reshape(h, w)
    p = arr(si.p, 3)
    cam_p = p @ cam.R.T + cam.t
    n_cam = arr(si.sh_frame.n, 3) @ cam.R.T
    region = np.asarray(region).astype(np.int32).reshape(h, w)
    uv_model = np.stack([arr(u_model, 1), arr(v_model, 1)], axis=-1)
    zero = ~hit
    out = {
        "depth": np.where(zero, 0.0, cam_p[..., 2]),
        "normal": np.where(zero[..., None], 0.0, n_cam),
        "albedo": np.where(zero[..., None], 0.0, arr(albedo, 3)),
        "uv": np.where(zero[..., None], 0.0, uv_model),
        "segmentation": region,
    }
    if hits:
        out["position"] = np.where(zero[..., None], 0.0, p)
        prim = np.asarray(si.prim_index, np.int64).reshape(h, w)
        out["prim"] = np.where(zero, -1, prim).astype(np.int32)
    if opacity is not None:
        out["card_opacity"] = np.asarray(opacity, dtype=np.float64).reshape(h, w)
    out = {k: v.astype(np.float32) if k not in ("segmentation", "prim", "position") else v
           for k, v in out.items()}
    if through is not None:
        out["through"] = np.asarray(through, dtype=bool).reshape(h, w)
    return out


def _hit_region_uv(head, si, valid, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Region id (H, W) and model UV (H, W, 2) of a pixel grid of intersections (0 if none)."""
    import drjit as dr

    region, u, v = _region_uv_jit(head, si, valid)
    dr.eval(region, u, v)
    uv = np.stack([np.asarray(u, np.float64), np.asarray(v, np.float64)], -1)
    return np.asarray(region).astype(np.int32).reshape(h, w), uv.reshape(h, w, 2)


def _region_luts(head):
    """Shape registry id -> (region, u offset, u scale) as Dr.Jit lookup arrays (cached)."""
    import mitsuba as mi

    luts = getattr(head, "_aov_region_luts", None)
    if luts is None:
        size = max(head._shape_regions, default=0) + 1
        region = np.zeros(size, np.uint32)
        u_off = np.zeros(size, np.float32)
        u_scale = np.ones(size, np.float32)
        for sid, (reg, off, scale) in head._shape_regions.items():
            region[sid], u_off[sid], u_scale[sid] = reg, off, scale
        luts = (mi.UInt32(region), mi.Float(u_off), mi.Float(u_scale), size)
        head._aov_region_luts = luts
    return luts


def _region_uv_jit(head, si, active):
    """Region id and model UV of intersections, as Dr.Jit arrays (0 where not ``active``)."""
    import drjit as dr
    import mitsuba as mi

    lut_region, lut_off, lut_scale, size = _region_luts(head)
    sid = dr.reinterpret_array(mi.UInt32, si.shape)
    ok = active & si.is_valid() & (sid < size)
    region = dr.gather(mi.UInt32, lut_region, sid, ok)
    u = dr.select(ok, si.uv.x / dr.gather(mi.Float, lut_scale, sid, ok)
                  + dr.gather(mi.Float, lut_off, sid, ok), 0.0)
    v = dr.select(ok, 1.0 - si.uv.y, 0.0)
    return region, u, v


def label_pass(head, k: int, region_labels, uv_label_map: np.ndarray, uv_regions=(),
               see_through=("eyelashes",), num_labels: int | None = None,
               see_through_opacity: float | None = None) -> dict[str, np.ndarray]:
    """Label coverage of k x k sub-pixel rays per pixel and the pixel-centre G-buffer, in
    one ray batch and one kernel.

    A ray's label is ``region_labels[region]`` of the surface it meets (``parts.REGIONS``
    ids), except in ``uv_regions``, where it is the texel of ``uv_label_map`` (Hm, 2 Hm)
    at the hit's model UV (u in [0, 2] across, v up; row 0 is v = 1). A ray whose first
    surface is in a ``see_through`` region is continued once: it counts the card's opacity
    at the hit for its own label and the rest for the label behind; the opacity is the
    renderer's (:func:`card_opacity`: the lash cards' strand texture at the hit's UV), or
    the number ``see_through_opacity`` when one is given. Sub-pixel
    point s = b k + a is ((a + 0.5) / k, (b + 0.5) / k); the pixel centre is one of them
    for odd k and an extra ray (not counted in the coverage) otherwise. Coverage is
    accumulated in the kernel, in fixed point (:data:`COVERAGE_ONE`: integer sums, the same
    in whatever order the threads add a pixel's rays; the opacity is rounded to 2^-24),
    and the centre rays scatter the G-buffer, so nothing per ray leaves the kernel.

    Returns:
        ``coverage`` (H, W, L) float32, L = ``num_labels`` (default: max label + 1), summing
        to 1 over L (k = 0: (H, W, 0)); ``centre_label`` (H, W) uint8; and
        :func:`gbuffer`'s arrays for the pixel centres (``depth``, ``normal``, ``albedo``,
        ``uv``, ``segmentation``).
    """
    import drjit as dr
    import mitsuba as mi

    cam = head.camera
    w, h, kk = cam.width, cam.height, k * k
    n = w * h
    odd = k % 2 == 1
    c = kk // 2  # the sub-pixel point at the centre (odd k)
    m = kk - 1 if odd else kk  # other points per pixel
    lut_np = np.asarray(region_labels, np.uint32)
    lab_max = int(max(lut_np.max(initial=0), np.max(uv_label_map, initial=0)))
    L = lab_max + 1 if num_labels is None else int(num_labels)
    if lab_max >= L:
        raise HackError(f"label_pass: num_labels {L} is below the largest label {lab_max}.")
    sensor = head.scene.sensors()[0]
    lut = mi.UInt32(lut_np)
    is_uv = mi.Bool(np.isin(np.arange(len(REGIONS)), [REGIONS.index(r) for r in uv_regions]))
    hm = uv_label_map.shape[0]
    texels = mi.UInt32(np.asarray(uv_label_map, np.uint32).ravel())
    # the see-through regions this scene has a shape of (a scene with hair strands has no
    # lash cards): none, and no ray is continued (the same labels and coverage)
    present = {reg for reg, _, _ in head._shape_regions.values()}
    see = [REGIONS.index(name) for name in see_through
           if name in REGIONS and REGIONS.index(name) in present]

    def labels_of(si_, active):
        region, u, v = _region_uv_jit(head, si_, active)
        j = dr.clip(mi.Int32(dr.floor(u * hm)), 0, 2 * hm - 1)
        i = dr.clip(mi.Int32(dr.floor((1.0 - v) * hm)), 0, hm - 1)
        texel = dr.gather(mi.UInt32, texels, mi.UInt32(i * (2 * hm) + j))
        uv_hit = dr.gather(mi.Bool, is_uv, region)
        return dr.select(uv_hit, texel, dr.gather(mi.UInt32, lut, region)), region, u, v

    # rays 0 .. n-1: the pixel centres (also the middle sub-pixel point for odd k); then
    # the other m points of every pixel
    j = dr.arange(mi.UInt32, n * (1 + m))
    centre = j < n
    rest = dr.select(centre, 0, j - n)
    pix = dr.select(centre, j, rest // max(m, 1))
    sub = rest - (pix * m if m else 0)
    if odd:
        sub += dr.select(sub >= c, 1, 0)
    ox = dr.select(centre, 0.5, (mi.Float(sub % max(k, 1)) + 0.5) / max(k, 1))
    oy = dr.select(centre, 0.5, (mi.Float(sub // max(k, 1)) + 0.5) / max(k, 1))
    x = mi.Float(pix % w) + ox
    y = mi.Float(pix // w) + oy
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    # coherent: camera rays, a pixel's sub-pixel rays side by side (Embree's coherent
    # traversal; ~15 % faster here, same hits)
    si = camera_hit(head, ray, coherent=True)
    label, region, u, v = labels_of(si, mi.Bool(True))
    through = mi.Bool(False)
    for r_ in see:
        through |= region == r_
    if see:
        si2 = camera_hit(head, si.spawn_ray(ray.d), through)
        behind = dr.select(through, labels_of(si2, through)[0], 0)
    valid = si.is_valid()
    albedo = si.bsdf(ray).eval_diffuse_reflectance(si, valid & centre)

    # the centre rays' G-buffer and labels, scattered to per-pixel arrays
    def to_pixels(value, dtype):
        target = dr.zeros(dtype, n)
        dr.scatter(target, value, pix, centre)
        return target

    def to_pixels3(value):
        return [to_pixels(value[i], mi.Float) for i in range(3)]

    outs = {"p": to_pixels3(si.p), "n": to_pixels3(si.sh_frame.n),
            "albedo": to_pixels3(albedo), "region": to_pixels(region, mi.UInt32),
            "u": to_pixels(u, mi.Float), "v": to_pixels(v, mi.Float),
            "valid": to_pixels(valid, mi.Bool), "label": to_pixels(label, mi.UInt32)}
    if kk:
        counted = ~centre | odd  # the even-k centre ray is not a sub-pixel point
        if not see:
            alpha = mi.Float(1.0)
        elif see_through_opacity is None:
            alpha = dr.select(through, card_opacity(head, si, through), 1.0)
        else:
            alpha = dr.select(through, float(see_through_opacity), 1.0)
        # summed in fixed point (the opacity in units of 2^-24, its complement 2^24 minus
        # it): a pixel's rays are scatter-added from several threads in whatever order they
        # run, and float32 sums of fractional opacities changed in the last bit from run to
        # run (lash pixels, 256 px); integer sums are exact in any order
        acc = mi.UInt32 if kk * COVERAGE_ONE < 2 ** 32 else mi.UInt64  # k < 16: 32 bits
        q = acc(dr.round(alpha * COVERAGE_ONE))
        cov = dr.zeros(acc, n * L)
        dr.scatter_reduce(dr.ReduceOp.Add, cov, q, pix * L + label, counted)
        if see:
            dr.scatter_reduce(dr.ReduceOp.Add, cov, COVERAGE_ONE - q, pix * L + behind,
                              counted & through)
        outs["coverage"] = cov
    dr.eval(outs)

    def img(a, c=1, dtype=np.float64):
        if c > 1:
            return np.stack([np.asarray(x, dtype=dtype).reshape(h, w) for x in a], -1)
        return np.asarray(a, dtype=dtype).reshape(h, w)

    hit = img(outs["valid"], dtype=bool)
    zero = ~hit[..., None]
    cam_p = img(outs["p"], 3) @ cam.R.T + cam.t
    result = {
        "depth": np.where(hit, cam_p[..., 2], 0.0).astype(np.float32),
        "normal": np.where(zero, 0.0, img(outs["n"], 3) @ cam.R.T).astype(np.float32),
        "albedo": np.where(zero, 0.0, img(outs["albedo"], 3)).astype(np.float32),
        "uv": np.where(zero, 0.0, np.stack([img(outs["u"]), img(outs["v"])], -1)).astype(np.float32),
        "segmentation": img(outs["region"], dtype=np.int64).astype(np.int32),
        "centre_label": np.asarray(outs["label"]).astype(np.uint8).reshape(h, w),
        # fixed point -> float32 (exact for whole rays: the float32 sums of before), / k^2
        "coverage": ((np.asarray(outs["coverage"]).astype(np.float64).astype(np.float32)
                      * np.float32(1.0 / COVERAGE_ONE)).reshape(h, w, L) / np.float32(kk)
                     if kk else np.zeros((h, w, 0), np.float32)),
    }
    return result


def region_hits(head, offset=(0.5, 0.5), see_through=("eyelashes",)) -> dict[str, np.ndarray]:
    """What one primary ray per pixel, through sub-pixel point ``offset``, hits.

    Used for soft (coverage) segmentation masks: call it for a grid of offsets in
    [0, 1)^2 and average. Rays that hit a region named in ``see_through`` (the
    see-through lash cards) are continued once, so the surface behind is known too.

    Returns:
        ``region`` (H, W) int32 id (``parts.REGIONS``, 0 = nothing), ``uv`` (H, W, 2) model
        UVs of that hit; ``region_behind`` / ``uv_behind``: the same for the next surface
        behind a see-through hit (0 elsewhere); ``opacity`` (H, W) float32: the card's
        opacity at a see-through hit as the renderer sees it (:func:`card_opacity`), 1
        elsewhere.
    """
    import drjit as dr
    import mitsuba as mi

    cam = head.camera
    w, h = cam.width, cam.height
    idx = dr.arange(mi.UInt32, w * h)
    x = mi.Float(idx % w) + float(offset[0])
    y = mi.Float(idx // w) + float(offset[1])
    sensor = head.scene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
    si = camera_hit(head, ray)
    region, uv = _hit_region_uv(head, si, si.is_valid(), h, w)
    out = {"region": region, "uv": uv, "region_behind": np.zeros_like(region),
           "uv_behind": np.zeros_like(uv), "opacity": np.ones(region.shape, np.float32)}
    through = [REGIONS.index(n) for n in see_through if n in REGIONS]
    if through and np.isin(region, through).any():
        si2 = camera_hit(head, si.spawn_ray(ray.d))
        mask = mi.Bool(np.isin(region, through).ravel())
        out["opacity"] = np.asarray(card_opacity(head, si, mask), np.float32).reshape(h, w)
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
    lut_region, _, _, size = _region_luts(head)
    see = np.zeros(len(REGIONS), bool)
    see[[REGIONS.index(n) for n in see_through if n in REGIONS]] = True
    see = mi.Bool(see)
    limit = mi.Float((dist - tolerance).astype(np.float32))
    blocked = mi.Bool(False)
    alive = mi.Bool(True)
    travelled = mi.Float(0.0)
    # At most a few see-through layers in front of a point, unrolled into one kernel, on
    # the camera-to-point line: each layer starts 10 um past the last hit. Preliminary
    # intersections (Embree's distance and shape only): no surface interaction is needed,
    # and tracing one is a virtual call over every shape, which cost more than the rays.
    step = 1e-5
    for _ in range(4 + emitter_layers(head)):
        pi = head.scene.ray_intersect_preliminary(ray, False, alive)
        sid = dr.reinterpret_array(mi.UInt32, pi.shape)
        valid = alive & pi.is_valid()
        ok = valid & (sid < size)
        region = dr.gather(mi.UInt32, lut_region, sid, ok)
        hit_before = valid & (travelled + pi.t < limit)
        # lash cards and the lights' rectangles (which camera rays look through) pass
        passes = hit_before & ((ok & dr.gather(mi.Bool, see, region, ok))
                               | pi.shape.is_emitter())
        blocked |= hit_before & ~passes
        alive = passes
        travelled += dr.select(alive, pi.t + step, 0.0)
        ray = mi.Ray3f(ray(pi.t + step), ray.d)
    dr.eval(blocked)
    return in_image, in_image & ~np.asarray(blocked, bool)
