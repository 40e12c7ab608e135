"""Before/after close-ups of the eye for docs/images/lashes_before_after.png.

Uniform 50 % lash cards (``HeadScene(lash_strands=False)``, the earlier look) against the
procedural strand texture (``materials.lash_opacity_map``), two views of the left eye
(from above, from below), studio light, ``render(sss=True)``. Prints each render's share
of dark pixels in the lash cards' footprint (darker than half the median skin luminance).

    python scripts/lashes_figure.py [--spp 128] [--res 256] [--integrator volpath]
        [--out docs/images/...]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from PIL import Image

from hack_render.geometry import load_default_model
from hack_render.render.parts import REGIONS, Topology
from hack_render.render.scene import HeadScene, RenderSettings
from scenes import cameras, lights

VIEWS = {"above": [0.036, 0.040, 0.200], "below": [0.040, 0.010, 0.190]}
TARGET = [0.034, 0.033, 0.092]  # the left eye's lid margin, model metres


def srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear[..., :3], 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return (255 * x + 0.5).astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--integrator", default="volpath", help="volpath or path (earlier)")
    ap.add_argument("--out", default="docs/images/lashes_before_after.png")
    args = ap.parse_args()
    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    topo = Topology.from_model(model)
    rows = []
    for view, eye in VIEWS.items():
        R, t = cameras.look_at(eye, TARGET)
        cam = cameras.Camera(cameras.intrinsics(args.res, args.res, 90.0), R, t, args.res,
                             args.res, view)
        row = []
        for strands in (False, True):
            head = HeadScene(topo, v, lights.preset("studio"), cam,
                             RenderSettings(args.res, args.res, args.spp,
                                            integrator=args.integrator), lash_strands=strands)
            img = head.render(sss=True)
            hits = head.region_hits()
            band = hits["region"] == REGIONS.index("eyelashes")
            skin = hits["region"] == REGIONS.index("face")
            lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
            dark = float((lum[band] < 0.5 * np.median(lum[skin & ~band])).mean())
            print(f"{view:6s} {'strands' if strands else 'uniform':8s} dark share in the lash "
                  f"band {dark:.3f} ({int(band.sum())} px)")
            row.append(srgb8(img))
        rows.append(np.concatenate(row, 1))
    Image.fromarray(np.concatenate(rows, 0)).save(args.out, optimize=True)
    print(f"wrote {args.out} (left: uniform 50 % cards, right: strand texture; "
          f"{args.res} px, {args.spp} spp, sss, {args.integrator})")


if __name__ == "__main__":
    main()
