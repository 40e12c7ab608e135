"""The landmark refiner's accuracy and its settings (figures for the README; not a test).

    python bench/bench_landmark_refiner.py --cache renders/ --out bench/results/landmark_refiner.json
    python bench/bench_landmark_refiner.py --cache renders/ --variants default
    python bench/bench_landmark_refiner.py --cache renders/ --variants ""   # mirror checks only

Trains refiners on the calibration sampler's renders (``hack-render train-landmark-
refiner``'s training set, read from --cache when it holds them, else rendered: ~2 s per
subject) and measures them on the benchmark's synthetic subjects (``bench_fit.py``'s,
another sampler, 256 px): rms distance over the 52 inner points and the chin to the true
embedding points, % of the inter-ocular distance, median and mean over the subjects,
against dlib's own points. Variants: stages, mirroring, lambda, training-set size.

Also the shipped refiner's mirror consistency (detect on the mirrored image, refine,
mirror back; mean distance to the unmirrored result, same units) for dlib's and the
refined points, on the benchmark subjects and the real portraits (``bench_fit.PORTRAITS``),
and how far it moves the portraits' points: the only checks there are on real photos,
which have no ground truth here.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings

import numpy as np
import torch
from provenance import write_result  # bench/ is sys.path[0] when run as a script

VARIANTS = {
    "default": {},                       # the shipped settings: 3 stages, mirror, lambda 100
    "stages1": {"stages": 1}, "stages2": {"stages": 2},
    "no_mirror": {"mirror": False},
    "lambda30": {"lam": 30.0}, "lambda300": {"lam": 300.0},
    "train150": {"n_train": 150},
}


def bench_subjects(n: int, res: int):
    """(gray images, rgb8 images, dlib points, true embedding points, iod) of the
    benchmark's subjects dlib finds."""
    from bench_fit import render_subject

    from appearance.model import AppearanceModel
    from hack_render.fit.landmark_embedding import load_default
    from hack_render.geometry import load_default_model
    from hack_render.vision.landmarks68 import detect_landmarks

    model, app = load_default_model(), AppearanceModel.load()
    emb = load_default(model)
    li = model.landmark_indices.numpy()
    out = {"rgb": [], "dlib": [], "truth": [], "iod": [], "subject": [], "missed": []}
    for k in range(n):
        s = render_subject(k, res, model, app)
        img = s["photo"].uint8()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                det = detect_landmarks(img, name=s["photo"].name)
        except Exception as err:  # noqa: BLE001 - reported: the benchmark's "no face" subject
            out["missed"].append([k, str(err)])
            continue
        V = s["out"].vertices[0].numpy().astype(np.float64)
        lv = s["cam"].project(V[li])
        out["rgb"].append(img), out["dlib"].append(det.points)
        out["truth"].append(s["cam"].project(emb.points_np(V)))
        out["iod"].append(float(np.linalg.norm(lv[36] - lv[45]))), out["subject"].append(k)
    return {k: (v if k in ("rgb", "missed") else np.asarray(v)) for k, v in out.items()}


def mirror_consistency(rgb8: np.ndarray, ref) -> tuple[float, float, float]:
    """(dlib, refined, shift): mean distance over the chin and the inner points between
    the result on the image and the mirrored result on the mirrored image, and between
    the refined and dlib's points; % of dlib's inter-ocular distance."""
    from hack_render.fit.landmark_refiner import INNER, mirror_points
    from hack_render.vision.landmarks68 import detect_landmarks

    w = rgb8.shape[1]
    im = np.ascontiguousarray(rgb8[:, ::-1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = detect_landmarks(rgb8).points
        dm_raw = detect_landmarks(im).points
    dm = mirror_points(dm_raw, w)
    r = ref.refine(rgb8, d)
    rm = mirror_points(ref.refine(im, dm_raw), w)
    iod = np.linalg.norm(d[36] - d[45])
    f = lambda a, b: float(np.linalg.norm(a - b, axis=1)[INNER].mean() / iod * 100)
    return f(d, dm), f(r, rm), f(r, d)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", required=True, help="the training renders' folder "
                    "(hack-render learn landmark-refiner --cache)")
    ap.add_argument("--subjects", type=int, default=1150, help="training subjects")
    ap.add_argument("--bench-subjects", type=int, default=20)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated: "
                    + ", ".join(VARIANTS))
    ap.add_argument("--out", default=None, help="JSON to write")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from hack_render.fit import landmark_refiner as lr
    from hack_render.learn import landmark_refiner_training as lt

    data = lt.render_training_set(args.subjects, 5150, args.cache, progress=True)
    n = len(data["indices"])
    n_tr = n - round(0.1 * n)  # the shipped file's split: the last 10 % held out
    grays = [im.astype(np.float32) / 255.0 for im in data["images"]]
    b = bench_subjects(args.bench_subjects, args.res)
    before = lt.inner_nme(b["dlib"], b["truth"], b["iod"])
    out = {"training_subjects": n_tr, "bench_subjects": [int(k) for k in b["subject"]],
           "bench_missed": b["missed"],
           "dlib": {"median": 100 * float(np.median(before)),
                    "mean": 100 * float(before.mean())}, "variants": {}}
    print(json.dumps(out), flush=True)
    for name in [v for v in args.variants.split(",") if v]:
        kw = dict(VARIANTS[name])
        m = kw.pop("n_train", n_tr)
        t0 = time.perf_counter()
        ref = lt.train(grays[:m], list(data["dlib"][:m]), list(data["targets"][:m]),
                       progress=False, **{"stages": 3, "lam": 100.0, **kw})
        after = lt.inner_nme(np.array([ref.refine(g, p) for g, p in zip(b["rgb"], b["dlib"])]),
                             b["truth"], b["iod"])
        out["variants"][name] = {"train": int(m), "median": 100 * float(np.median(after)),
                                 "mean": 100 * float(after.mean()),
                                 "better": int((after < before).sum()),
                                 "train_s": time.perf_counter() - t0, **VARIANTS[name]}
        print(name, json.dumps(out["variants"][name]), flush=True)
    # the shipped refiner: mirror consistency on the renders and the real portraits
    import imageio.v3 as iio
    from bench_fit import PORTRAITS, portrait_file

    from hack_render.errors import HackError

    ref = lr.load_refiner("dlib")
    mc, no_mirror_face = [], 0
    for img in b["rgb"]:
        try:
            mc.append(mirror_consistency(img, ref))
        except HackError:  # dlib finds no face in the mirrored image: counted
            no_mirror_face += 1
    mc = np.array(mc)
    out["mirror_consistency"] = {"renders_median": {"dlib": float(np.median(mc[:, 0])),
                                                    "refined": float(np.median(mc[:, 1])),
                                                    "shift": float(np.median(mc[:, 2])),
                                                    "renders": len(mc),
                                                    "no_face_when_mirrored": no_mirror_face}}
    with tempfile.TemporaryDirectory() as d:
        for name in PORTRAITS:
            img = iio.imread(portrait_file(name, d))[..., :3]
            c = mirror_consistency(np.ascontiguousarray(img, dtype=np.uint8), ref)
            out["mirror_consistency"][name] = {"dlib": c[0], "refined": c[1], "shift": c[2]}
    print(json.dumps(out["mirror_consistency"]), flush=True)
    if args.out:
        write_result(args.out, out)


if __name__ == "__main__":
    main()
