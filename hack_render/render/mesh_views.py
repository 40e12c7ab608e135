"""Any triangle mesh (a scan, a registration) in front of a camera: shaded or coloured
images and the surface point under every pixel.

Used by registration to find a scan's face (render it from several views, detect 2-D
landmarks, read the 3-D point under each) and to draw error heat maps. The mesh is lit
by an ambient term and a key light above and to the left of the camera (moving with
it), so a surface without colours reads by its shading alone. Images are ray cast
(Mitsuba's ``ray_intersect``, a few rays a pixel) and shaded in numpy: no Monte Carlo
noise for a face detector to trip on.
"""

from __future__ import annotations

import numpy as np

from hack_render.render import emitters
from hack_render.render.emitters import camera_to_world, check_centred
from hack_render.render.engine import ensure_variant, release_parked, release_when_safe
from hack_render.render.parts import vertex_normals
from scenes.cameras import Camera, intrinsics, look_at


def _mesh(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None,
          normals: np.ndarray | None):
    import mitsuba as mi

    v = np.asarray(vertices, np.float64)
    n = vertex_normals(v, faces) if normals is None else np.asarray(normals, np.float64)
    mesh = mi.Mesh("mesh", len(v), len(faces), has_vertex_normals=True)
    p = mi.traverse(mesh)
    p["vertex_positions"] = mi.Float(v.ravel().astype(np.float32))
    p["vertex_normals"] = mi.Float(n.ravel().astype(np.float32))
    p["faces"] = mi.UInt32(np.asarray(faces).ravel().astype(np.uint32))
    p.update()
    if colors is not None:
        mesh.add_attribute("vertex_color", 3, mi.Float(np.asarray(colors, np.float32).ravel()))
        bsdf = {"type": "diffuse", "reflectance": {"type": "mesh_attribute",
                                                   "name": "vertex_color"}}
    else:
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.6, 0.6]}}
    mesh.set_bsdf(mi.load_dict(bsdf))
    return mesh


class MeshViews:
    """One mesh in a Mitsuba scene; ray cast it from any camera of one size."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray,
                 colors: np.ndarray | None = None, width: int = 256, height: int = 256,
                 variant: str | None = None, normals: np.ndarray | None = None):
        ensure_variant(variant)
        release_parked()
        import mitsuba as mi

        self.width, self.height = width, height
        K = intrinsics(width, height, 50.0)
        R, t = look_at((0, 0, 1), (0, 0, 0))
        cam = Camera(K, R, t, width, height, "view")
        self.scene = mi.load_dict({
            "type": "scene",
            "sensor": emitters.sensor_dict(cam, 1, pixel_format="rgba", pixel_filter="box"),
            "mesh": _mesh(vertices, faces, colors, normals),
        }, parallel=False, optimize=False)
        self.params = mi.traverse(self.scene)
        release_when_safe(self, self.scene, self.params)  # see engine.release_when_safe
        self.light = np.zeros(3)

    def set_vertices(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Move the mesh (same topology): new positions and their vertex normals."""
        import mitsuba as mi

        v = np.asarray(vertices, np.float64)
        self.params["mesh.vertex_positions"] = mi.Float(v.ravel().astype(np.float32))
        self.params["mesh.vertex_normals"] = mi.Float(
            vertex_normals(v, faces).ravel().astype(np.float32))
        self.params.update()

    def _set_camera(self, cam: Camera) -> None:
        import mitsuba as mi

        if (cam.width, cam.height) != (self.width, self.height):
            raise ValueError(f"camera size {cam.width}x{cam.height}, views are "
                             f"{self.width}x{self.height}")
        check_centred(cam)
        self.params["sensor.to_world"] = mi.Transform4f(camera_to_world(cam).tolist())
        self.params["sensor.x_fov"] = cam.fov_x_deg
        self.params.update()
        # the key light: up and to the left of the camera by half its distance to the
        # world origin (a portrait key light that moves with the camera)
        d = float(np.linalg.norm(cam.t)) or 1.0
        right, down = cam.R[0], cam.R[1]
        self.light = cam.center + 0.5 * d * (-down - 0.6 * right)

    def _intersect(self, cam: Camera, supersample: int = 1, window=None):
        """Mitsuba rays through a ``supersample`` x ``supersample`` grid in each pixel of
        ``window`` (x0, y0, x1, y1; default: the whole image) -> (ray, surface
        interaction, hit mask, rows h*s, columns w*s)."""
        import drjit as dr
        import mitsuba as mi

        self._set_camera(cam)
        s = int(supersample)
        x0, y0, x1, y1 = window or (0, 0, self.width, self.height)
        w, h = (x1 - x0) * s, (y1 - y0) * s
        idx = dr.arange(mi.UInt32, w * h)
        x = mi.Float(idx % w) + 0.5 + x0 * s
        y = mi.Float(idx // w) + 0.5 + y0 * s
        sensor = self.scene.sensors()[0]
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / (self.width * s),
                                                        y / (self.height * s)),
                                   mi.Point2f(0.5, 0.5))
        si = self.scene.ray_intersect(ray)
        return ray, si, si.is_valid(), h, w

    def _trace(self, cam: Camera, supersample: int = 1, window=None):
        """(position, shading normal, diffuse albedo, hit), each (h*s, w*s[, 3]), of the
        rays of :meth:`_intersect`."""
        import drjit as dr

        ray, si, valid, h, w = self._intersect(cam, supersample, window)
        albedo = si.bsdf(ray).eval_diffuse_reflectance(si, valid)
        dr.eval(si.p, si.sh_frame.n, albedo, valid)
        arr = lambda v: np.asarray(v, np.float64).reshape(3, h, w).transpose(1, 2, 0)
        return arr(si.p), arr(si.sh_frame.n), arr(albedo), np.asarray(valid, bool).reshape(h, w)

    def trace_triangles(self, cam: Camera, window: tuple[int, int, int, int] | None = None):
        """The triangle under each pixel centre of ``window`` (as :meth:`trace`): (triangle
        index (h, w) int64, barycentric weights of its three corners (h, w, 3), hit
        (h, w)); a point is ``sum_k bary[..., k] * vertices[faces[tri, k]]``. Misses have
        index 0 and weights 0."""
        import drjit as dr

        _, si, valid, h, w = self._intersect(cam, 1, self._window(window))
        dr.eval(si.prim_index, si.uv, valid)
        hit = np.asarray(valid, bool).reshape(h, w)
        tri = np.where(hit, np.asarray(si.prim_index, np.int64).reshape(h, w), 0)
        b = np.asarray(si.uv, np.float64).reshape(2, h, w).transpose(1, 2, 0)
        bary = np.concatenate([1.0 - b.sum(-1, keepdims=True), b], -1) * hit[..., None]
        return tri, bary, hit

    def _window(self, window):
        if window is None:
            return None
        x0, y0, x1, y1 = (int(v) for v in window)
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise ValueError(f"window {window} is not inside the {self.width}x"
                             f"{self.height} image")
        return x0, y0, x1, y1

    def trace(self, cam: Camera, window: tuple[int, int, int, int] | None = None):
        """The surface under each pixel centre of ``window`` (x0, y0, x1, y1: pixel columns
        x0..x1-1 and rows y0..y1-1; default the whole image): (position (h, w, 3), unit
        shading normal (h, w, 3), diffuse albedo or vertex colour (h, w, 3), hit (h, w))."""
        return self._trace(cam, 1, self._window(window))

    def render(self, cam: Camera, supersample: int = 2) -> np.ndarray:
        """(H, W, 4) linear RGBA of the mesh seen by ``cam``: diffuse albedo (the mesh's
        colours, or grey) lit by an ambient term and the key light, Lambert, no shadows.
        Ray cast (no Monte Carlo noise), ``supersample``^2 rays a pixel."""
        p, n, albedo, hit = self._trace(cam, supersample)
        to_light = self.light - p
        to_light /= np.maximum(np.linalg.norm(to_light, axis=-1, keepdims=True), 1e-12)
        view = cam.center - p
        n = np.where(((n * view).sum(-1) < 0)[..., None], -n, n)  # back faces lit as front
        lambert = np.clip((n * to_light).sum(-1), 0, None)
        rgb = albedo * (0.25 + 0.85 * lambert)[..., None]
        rgba = np.concatenate([np.where(hit[..., None], rgb, 0.0), hit[..., None]], -1)
        s = int(supersample)
        rgba = rgba.reshape(self.height, s, self.width, s, 4).mean((1, 3))
        return rgba.astype(np.float32)

    def surface_points(self, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(position (H, W, 3) world point under each pixel centre, hit (H, W) bool)."""
        p, _, _, hit = self._trace(cam, 1)
        return p, hit
