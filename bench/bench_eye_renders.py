"""The eye estimates' renders (``fit/iris.py``): four variants per view (the defaults, a
black iris, black whites, no gloss) from one scene whose eyes change in place
(``texture.render_eye_variants``, ``HeadScene.set_eyes``) against a scene built for each
(``texture.render_at_photo`` four times, the path before), in one run on the same state.

    python bench/bench_eye_renders.py --out bench/results/eye_renders.json

The state: the astronaut (scikit-image, public domain) after the fit's landmark stages,
under a uniform light; renders at the photo's size (512 px), 16 spp, as ``fit_colour`` makes them. The two
paths alternate ``--reps`` times; the medians and their ratio are reported, and the
largest pixel difference between the two paths' images.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=3, help="timed rounds of each path")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--out", type=str, default=None, help="result JSON (provenance added)")
    a = ap.parse_args(argv)
    if a.reps < 1 or a.spp < 1:
        ap.error("--reps and --spp: expected positive integers")
    from skimage import data

    from hack_render.fit import texture
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.lighting import Lighting
    from hack_render.fit.photo import from_array
    from hack_render.render.materials import DEFAULT_IRIS_RGB, SCLERA_RGB
    from hack_render.vision.landmarks68 import detect_landmarks

    ph = from_array(data.astronaut(), "astronaut")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        det = detect_landmarks(ph.uint8())
    fitter = Fitter([ph], [det], load_config(None, {}), progress=False)
    fitter.fit_camera()
    fitter.fit_shape()
    state, cfg, v = fitter.state, fitter.cfg, fitter.state.views[0]
    v.lighting = Lighting("env", 8)       # uniform light (the photometric stage's start)
    with torch.no_grad():
        v.lighting.log_texels.fill_(0.0)
    maps = texture._skin_maps(state)
    black = (0.0, 0.0, 0.0)
    eyes = [(DEFAULT_IRIS_RGB, SCLERA_RGB, None), (black, SCLERA_RGB, None),
            (DEFAULT_IRIS_RGB, black, None), (DEFAULT_IRIS_RGB, SCLERA_RGB, 0.0)]
    side = max(ph.width, ph.height)

    def built():
        return [texture.render_at_photo(state, cfg, v, spp=a.spp, max_side=side,
                                        maps=dataclasses.replace(maps, iris_rgb=i,
                                                                 sclera_rgb=s, eye_gloss=g))
                for i, s, g in eyes]

    def in_place():
        return texture.render_eye_variants(state, cfg, v, maps, eyes, a.spp, side)

    built(), in_place()           # compile the kernels of both first
    times: dict = {"built": [], "in_place": []}
    for _ in range(a.reps):
        for name, fn in (("built", built), ("in_place", in_place)):
            t = time.perf_counter()
            out = fn()
            times[name].append(time.perf_counter() - t)
            if name == "built":
                ref = out
    diff = max(float(np.abs(x.rgba - y.rgba).max()) for x, y in zip(ref, out))
    med = {k: float(np.median(t)) for k, t in times.items()}
    res = {"photo": "astronaut", "size": [ph.width, ph.height], "spp": a.spp,
           "variants": len(eyes), "reps": a.reps, "seconds": times, "median_s": med,
           "ratio_in_place_over_built": med["in_place"] / med["built"],
           "max_pixel_difference": diff}
    print(f"four eye renders: built {med['built']:.2f} s, in place {med['in_place']:.2f} s "
          f"(x{res['ratio_in_place_over_built']:.2f}); images within {diff:.1e}")
    if a.out:
        from provenance import write_result

        write_result(a.out, res)


if __name__ == "__main__":
    main()
