"""Known-truth composites: the model's renders over real photographs.

A face detector's accuracy at a yaw, pitch or roll can only be measured where the truth
is known. :func:`render_composite` renders a random subject of the model (shape, mild
expression, appearance, lighting preset) with the project's path tracer from a camera
orbiting the head at a given yaw and pitch, composites it over a real, openly licensed
photograph shipped by scikit-image (:data:`BACKGROUNDS`), optionally turns the image in
its plane (roll) and lays a synthetic occluder (a patch of another photograph, shaped
like a hand or a strand of hair) over part of the face. It returns the image with its
truth: the 68 landmarks (the calibrated embedding's points, Multi-PIE order, the jawline
on the model's landmark vertices), their line-of-sight visibility, the person mask (the
render's coverage), the face-skin mask and the occluder mask.

Derived data: everything here is procedural (the model's renders); only the backgrounds
are photographs. Used by ``bench/bench_real_photos.py``, ``tests/test_vision.py``, the
calibration of the dense-to-68 landmark map (:mod:`hack_render.learn.dense68`, the map
:mod:`hack_render.vision.dense68`) and the training of the shape predictors
(:mod:`hack_render.learn.face_ert`). A dataset of its own, not part of the vision package
it measures: the truth's points are the fitter's calibrated landmark embedding's
(:mod:`hack_render.fit.landmark_embedding`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from appearance.model import AppearanceModel
from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default
from hack_render.geometry import load_default_model
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.render.materials import SkinMaps
from hack_render.render.parts import REGIONS, Topology
from hack_render.render.scene import HeadScene, RenderSettings
from scenes.cameras import Camera, intrinsics, look_at
from scenes.lights import PRESETS, preset

#: scikit-image sample photographs with no face in them, all public domain or CC0
#: (skimage.data docstrings): coffee (CC0, Rachel Michetti), rocket (public domain,
#: SpaceX), brick, grass, gravel (CC0 Textures / DeviantArt, CC0), hubble_deep_field
#: (public domain, NASA), motorcycle_left (Middlebury 2014 stereo, research use: not
#: used), chelsea (a cat's face: not used, it is a face).
BACKGROUNDS = ("coffee", "rocket", "brick", "grass", "gravel", "hubble_deep_field")


@dataclass
class Composite:
    """One composite and its truth.

    image: (H, W, 3) uint8 sRGB. points: (68, 2) true landmarks, pixels (pixel centres
    at +0.5). visible: (68,) bool, the landmark's surface point seen from the camera and
    not under the occluder. person: (H, W) float32 in [0, 1], the render's coverage.
    face: (H, W) bool, face skin (the ``face`` region of the render). occluder: (H, W)
    bool. yaw, pitch, roll: degrees (yaw > 0: the camera on the subject's left; pitch
    > 0: the camera above; roll: the image turned counter-clockwise).
    """

    image: np.ndarray
    points: np.ndarray
    visible: np.ndarray
    person: np.ndarray
    face: np.ndarray
    occluder: np.ndarray
    yaw: float
    pitch: float
    roll: float
    meta: dict = field(default_factory=dict)

    @property
    def box_size(self) -> float:
        """sqrt(width * height) of the true landmarks' box, pixels."""
        span = self.points.max(0) - self.points.min(0)
        return float(np.sqrt(max(span[0] * span[1], 1e-9)))


def background(name: str, res: int, rng: np.random.Generator) -> np.ndarray:
    """A random (res, res, 3) uint8 crop of a scikit-image sample photograph."""
    import skimage.data
    from skimage.color import gray2rgb
    from skimage.transform import resize

    img = getattr(skimage.data, name)()
    if img.ndim == 2:
        img = gray2rgb(img)
    img = img[..., :3]
    h, w = img.shape[:2]
    side = int(min(h, w) * rng.uniform(0.6, 1.0))
    y, x = rng.integers(0, h - side + 1), rng.integers(0, w - side + 1)
    crop = img[y:y + side, x:x + side]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    return (resize(crop, (res, res), anti_aliasing=True) * 255).astype(np.uint8)


def _camera(res: int, focal_mm: float, yaw: float, pitch: float, target: np.ndarray,
            face_frac: float):
    K = intrinsics(res, res, focal_mm)
    d = K[0, 0] * 0.24 / (face_frac * res)        # a ~0.24 m head spans face_frac of the frame
    y, p = math.radians(yaw), math.radians(pitch)
    eye = target + d * np.array([math.sin(y) * math.cos(p), math.sin(p),
                                 math.cos(y) * math.cos(p)])
    R, t = look_at(eye, target)
    return Camera(K, R, t, res, res, f"yaw{yaw:+.0f}_pitch{pitch:+.0f}")


class CompositeRenderer:
    """Renders composites; the scene is built once and changed per sample (camera,
    vertices, maps), as the performance notes ask.

    Args:
        res: image side, pixels. spp: samples per pixel. seed: the random stream of
        subjects, backgrounds and occluders (the same seed gives the same composites).
    """

    def __init__(self, res: int = 256, spp: int = 16, seed: int = 0):
        self.res, self.spp = int(res), int(spp)
        self.rng = np.random.default_rng(seed)
        self.model = load_default_model()
        self.app = AppearanceModel.load()
        emb = load_default(self.model)
        self.emb = emb if emb is not None else LandmarkEmbedding.from_vertices(
            self.model.landmark_indices.numpy(), self.model.faces.numpy())
        #: one scene per lighting preset, built at its first use and then changed per
        #: sample (camera, vertices, maps, the rig's rotation): a scene's lights are fixed
        #: when it is built, so a single scene would light every sample like the first
        self._scenes: dict = {}

    def _subject(self):
        import torch

        g = torch.Generator().manual_seed(int(self.rng.integers(2 ** 31)))
        beta = 0.8 * torch.randn(1, 20, generator=g)
        psi = torch.zeros(1, self.model.num_expressions)
        units = torch.randperm(self.model.num_expressions, generator=g)[:2]
        psi[0, units] = 0.4 * torch.rand(2, generator=g)
        ang = torch.deg2rad(torch.tensor([4.0, 4.0, 3.0]) * (2 * torch.rand(3, generator=g) - 1))
        with torch.no_grad():
            out = self.model(beta=beta, psi=psi, theta=distribute_head_rotation(ang)[None])
            maps = self.app.maps(torch.randn(1, 20, generator=g))
        return out.vertices[0].numpy().astype(np.float64), maps

    def render(self, yaw: float, pitch: float, roll: float = 0.0, occluder: bool = False,
               bg: str | None = None, light: str | None = None) -> Composite:
        """One composite at camera ``yaw``/``pitch`` (degrees, about the head), turned by
        ``roll`` degrees in the image plane, with an occluder when asked. ``bg`` and
        ``light`` name the background photograph and the lighting preset (default: drawn
        at random; the draws are made either way, so the sample stream stays the same)."""
        rng = self.rng
        V, maps = self._subject()
        lm3 = self.emb.points_np(V)
        target = lm3[27:36].mean(0) - np.array([0.0, 0.0, 0.07])   # inside the head
        cam = _camera(self.res, float(rng.uniform(50, 100)), yaw, pitch, target,
                      float(rng.uniform(0.35, 0.5)))
        name, rotation = str(rng.choice(list(PRESETS))), float(rng.uniform(-40, 40))
        name = light or name
        rig = preset(name, rotation_deg=rotation)
        skin = SkinMaps.from_appearance(maps)
        head = self._scenes.get(name)
        if head is None:
            # volpath: the composites the detectors were calibrated and benchmarked on
            # (docs/vision.md); hack_path, the default since, renders the same image in
            # the mean but other noise, which would move every figure a little
            head = self._scenes[name] = HeadScene(
                Topology.from_model(self.model), V, rig, cam,
                RenderSettings(self.res, self.res, self.spp, 4, 0, integrator="volpath"), skin)
        else:
            head.set_camera(cam, update=False)
            head.set_maps(skin, update=False)
            head.set_light_rotation(rotation, update=False)
            head.set_vertices(V, update=True)
            head.sync_environment()     # the render a function of this sample alone
        # backdrop=False: the subject alone (premultiplied), so the background is the
        # photograph's and not the photograph plus the rig's environment
        rgba = head.render(seed=int(rng.integers(2 ** 20)), backdrop=False)
        aov = head.aovs()
        alpha = np.clip(rgba[..., 3], 0, 1)
        face = aov["segmentation"] == REGIONS.index("face")
        _, vis = head.visibility(lm3)
        pts = cam.project(lm3)
        drawn = str(rng.choice(BACKGROUNDS))
        img = _composite(rgba[..., :3], alpha, background(bg or drawn, self.res, rng), rig.name)
        occ = np.zeros(alpha.shape, bool)
        if occluder:
            img, occ = _occlude(img, pts, rng, self.res)
        if roll:
            img, pts, alpha, face, occ = _roll(roll, img, pts, alpha, face, occ)
        h = self.res
        ij = np.clip(np.floor(pts).astype(int), 0, h - 1)
        vis = vis & ~occ[ij[:, 1], ij[:, 0]]
        return Composite(img, pts, vis, alpha.astype(np.float32), face, occ, float(yaw),
                         float(pitch), float(roll), {"lighting": rig.name})


def _composite(rgb_lin: np.ndarray, alpha: np.ndarray, bg8: np.ndarray, rig: str) -> np.ndarray:
    """Over the background in linear light, then sRGB-encoded (the render's exposure
    scaled so the face's 90th percentile sits at 0.8: presets differ in brightness)."""
    import colour

    bg = colour.cctf_decoding(bg8 / 255.0, function="sRGB")
    m = alpha > 0.5
    scale = 0.8 / max(float(np.percentile(rgb_lin[m].max(-1), 90)), 1e-3) if m.any() else 1.0
    # the render's colour is premultiplied by its coverage (alpha)
    lin = np.clip(rgb_lin * scale, 0, 1) + (1 - alpha[..., None]) * bg
    out = colour.cctf_encoding(np.clip(lin, 0, 1), function="sRGB")
    return np.round(out * 255).astype(np.uint8)


def _occlude(img, pts, rng, res):
    """A textured blob (an ellipse: a hand; a thin bent band: a strand of hair) from
    another photograph over 15-30 % of the face's box."""
    from skimage.draw import ellipse, polygon

    lo, hi = pts.min(0), pts.max(0)
    size = hi - lo
    tex = background(str(rng.choice(BACKGROUNDS)), res, rng)
    tint = rng.uniform(0.4, 1.0, 3)
    mask = np.zeros((res, res), bool)
    if rng.random() < 0.5:   # a hand-sized ellipse over the lower or upper face
        c = lo + size * rng.uniform([0.2, 0.3], [0.8, 0.9])
        rr, cc = ellipse(c[1], c[0], 0.3 * size[1], 0.22 * size[0], (res, res),
                         rotation=rng.uniform(0, np.pi))
        mask[rr, cc] = True
    else:                    # a hair strand: a band across the face from the top
        x0 = lo[0] + size[0] * rng.uniform(0.1, 0.9)
        x1 = x0 + size[0] * rng.uniform(-0.4, 0.4)
        wdt = size[0] * rng.uniform(0.12, 0.2)
        ys = np.array([lo[1] - 0.3 * size[1], hi[1]])
        xs = np.array([x0, x1])
        poly = np.array([[xs[0] - wdt, ys[0]], [xs[0] + wdt, ys[0]], [xs[1] + wdt, ys[1]],
                         [xs[1] - wdt, ys[1]]])
        rr, cc = polygon(poly[:, 1], poly[:, 0], (res, res))
        mask[rr, cc] = True
    out = img.copy()
    out[mask] = np.clip(tex[mask] * tint, 0, 255).astype(np.uint8)
    return out, mask


def _roll(deg, img, pts, *masks):
    """Turn the image ``deg`` degrees counter-clockwise about its centre (reflected
    border), the points with it."""
    from skimage.transform import rotate

    h, w = img.shape[:2]
    out = (rotate(img, deg, mode="reflect", preserve_range=True, order=1)
           ).round().astype(np.uint8)
    rot = []
    for m in masks:
        r = rotate(m.astype(np.float32), deg, order=1, mode="constant")
        rot.append(r if m.dtype != bool else r > 0.5)
    c = np.array([w / 2.0, h / 2.0])
    a = math.radians(deg)
    # counter-clockwise on screen (y down): x' = c + R(-a) (x - c)
    R = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
    return (out, (pts - c) @ R.T + c, *rot)
