"""Before/after close-ups of the eye for docs/images/cornea_before_after.png.

The plain iris (``HeadScene(cornea=False)``, the earlier look) against the iris seen
through the cornea (``cornea.py``), two views of the left eye (model +x): frontal, along
the eye's optical axis, and from the side (``--side`` degrees about the vertical, to the
temporal side), studio light, ``render(sss=True)``. Prints what the cornea does to the
pupil in each view (geometry, no render needed): the apparent pupil's area in the image
over the plain one's (the magnification squared) and the shift of its centre, in pixels
and in millimetres at the eye.

    python scripts/cornea_figure.py [--spp 128] [--res 256] [--integrator volpath]
        [--side 50] [--out ...]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from PIL import Image

from hack_render.geometry import load_default_model
from hack_render.render.cornea import CorneaRig
from hack_render.render.parts import PUPIL_RADIUS, Topology, radial_eye_distance, split_parts
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights

DISTANCE = 0.11  # camera to the eye, metres
FOCAL_MM = 120.0  # about 30 mm across at DISTANCE


def srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear[..., :3], 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return (255 * x + 0.5).astype(np.uint8)


def eye_cameras(axes, res: int, side_deg: float) -> dict[str, cameras.Camera]:
    """Frontal and side close-ups of the left eye (the +x one)."""
    centre, axis = max(axes, key=lambda ca: ca[0][0])
    target = centre + 0.015 * axis  # the iris
    out = {}
    for name, deg in (("frontal", 0.0), ("side", side_deg)):
        a = np.radians(deg)
        rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0,
                                                                       np.cos(a)]])
        R, t = cameras.look_at(target + DISTANCE * (rot @ axis), target)
        out[name] = cameras.Camera(cameras.intrinsics(res, res, FOCAL_MM), R, t, res, res,
                                   name)
    return out


def pupil_change(rig: CorneaRig, v: np.ndarray, axes, cam: cameras.Camera) -> str:
    """The apparent pupil against the plain one, in ``cam``'s image."""
    centre, axis = max(axes, key=lambda ca: ca[0][0])
    plain = v[rig.iris_gather]
    seen = rig.iris_positions(v, cam.center)
    r, _ = radial_eye_distance(plain, axes)
    sel = (r < PUPIL_RADIUS) & (np.linalg.norm(plain - centre, axis=1) < 0.02) \
        & ((plain - centre) @ axis > 0)
    a, b = cam.project(plain[sel]), cam.project(seen[sel])

    def area(p):  # of the points' convex hull, pixels^2
        from scipy.spatial import ConvexHull

        return ConvexHull(p).volume

    shift = b.mean(0) - a.mean(0)
    mm_per_px = 1e3 * np.linalg.norm(cam.center - centre) / cam.K[0, 0]
    return (f"pupil area x{area(b) / area(a):.3f} (linear x{np.sqrt(area(b) / area(a)):.3f}), "
            f"centre moved {np.linalg.norm(shift):.2f} px = {np.linalg.norm(shift) * mm_per_px:.3f}"
            f" mm at the eye, direction ({shift[0]:+.2f}, {shift[1]:+.2f}) px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--integrator", default="volpath", help="volpath or path (earlier)")
    ap.add_argument("--side", type=float, default=50.0)
    ap.add_argument("--out", default="docs/images/cornea_before_after.png")
    args = ap.parse_args()
    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    topo = Topology.from_model(model)
    parts, axes = split_parts(topo, v)
    iris = next(p for p in parts if p.name == "iris")
    rig = CorneaRig.from_topology(topo, v, axes, iris.gather)
    rows = []
    for view, cam in eye_cameras(axes, args.res, args.side).items():
        print(f"{view:8s} {pupil_change(rig, v, axes, cam)}")
        row = []
        for cornea in (False, True):
            head = HeadScene(topo, v, lights.preset("studio"), cam,
                             RenderSettings(args.res, args.res, args.spp,
                                            integrator=args.integrator), cornea=cornea)
            row.append(srgb8(head.render(sss=True)))
        rows.append(np.concatenate(row, 1))
    Image.fromarray(np.concatenate(rows, 0)).save(args.out, optimize=True)
    print(f"wrote {args.out} (left: plain iris, right: through the cornea; top: frontal, "
          f"bottom: {args.side:g} deg to the side; {args.res} px, {args.spp} spp, sss, "
          f"{args.integrator})")


if __name__ == "__main__":
    main()
