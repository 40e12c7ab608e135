"""Train the any-angle 68-point shape predictor (dlib's ensemble of regression trees) on
the model's renders composited over photographs.

    python -m hack_render.learn.face_ert collect --samples 200 --seed 5301 --out ert_5301.npz
    python -m hack_render.learn.face_ert train ert_53*.npz      # -> hack_render/data/
    python -m hack_render.learn.face_ert mean-shape     # the head-pose fit's mean landmarks

MediaPipe's face mesh, dlib's and most public 68-point models are trained on faces
within about 45 degrees of frontal; past that (profiles, heads tilted far back) they
give up or guess. The project's renderer gives faces at any angle with exact landmarks,
so this trains them (one per range of yaw, :mod:`hack_render.vision.ert`): composites
(:mod:`hack_render.dataset.composites`; seeds 5301-5325 of 200 each, apart from the dense
map's 7100, the benchmark's 9000-9019 and the tests' 31-33 and 43) at yaw U(-90, 90), pitch
U(-50, 50), roll U(-25, 25) degrees, a third of them with an occluder; each face's box and
keypoints are BlazeFace's (as at run time: :func:`hack_render.vision.boxes.find_boxes`),
the targets the true 68 landmarks (3-D convention: hidden points where they project).
Derived data: the model learns the model's renders; docs/vision.md gives its accuracy on
other subjects and backgrounds, and on real photos against the mesh detector.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hack_render.dataset.composites import CompositeRenderer
from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default
from hack_render.geometry import load_default_model
from hack_render.io.npz import write_npz
from hack_render.render.parts import vertex_normals
from hack_render.vision import ert
from hack_render.vision.boxes import find_boxes
from hack_render.vision.pose import MEAN_FILE


def collect(n: int, seed: int = 5300, res: int = 256, spp: int = 16, out=None) -> dict:
    """Composites with BlazeFace's box nearest the truth: images (S, res, res, 3) uint8,
    boxes (S, 4), kps (S, 6, 2) BlazeFace's keypoints, points (S, 68, 2), yaw (S,)."""

    rng = np.random.default_rng(seed)
    ren = CompositeRenderer(res, spp, seed)
    data = {"images": [], "boxes": [], "kps": [], "points": [], "yaw": []}
    for i in tqdm(range(n), desc="training composites", unit="sample"):
        c = ren.render(rng.uniform(-90, 90), rng.uniform(-50, 50), rng.uniform(-25, 25),
                       occluder=i % 3 == 0)
        boxes = find_boxes(c.image)
        if not boxes:
            continue
        ctr = c.points.mean(0)
        b = min(boxes, key=lambda b: np.hypot((b[0] + b[2]) / 2 - ctr[0],
                                              (b[1] + b[3]) / 2 - ctr[1]))
        if not (b[0] < ctr[0] < b[2] and b[1] < ctr[1] < b[3]):
            continue
        data["images"].append(c.image)
        data["boxes"].append(b[:4])
        data["kps"].append(b[5])
        data["points"].append(c.points)
        data["yaw"].append(c.yaw)
    arrays = {k: np.asarray(v) for k, v in data.items()}
    if out is not None:       # whole or not at all: a run stopped mid-write leaves no file
        write_npz(out, arrays, compressed=True)
    return arrays


def prepare(data: dict, weights=None, augment: int = 0, seed: int = 0) -> dict:
    """Each composite as the run-time predictor sees it (:mod:`hack_render.vision.ert`):
    the upright crop, its points and keypoints in the crop, the keypoints' yaw estimate
    (from ``weights``, else a regression fitted here on the data's true yaw), mirrored
    where that estimate is negative; ``augment`` more copies of each with the crop
    jittered (turned up to 8 degrees, scaled up to 8 %, shifted up to 5 % of the box: the
    spread of BlazeFace's boxes and keypoints) and its exposure and contrast changed
    (up to 25 %; half of them grey). Returns crops (S, P, P, 3), points (S, 68, 2),
    est_yaw (S,), weights."""
    rng = np.random.default_rng(seed)
    crops, pts, kps, yaws = [], [], [], []
    for img, b, k, p, y in zip(data["images"], data["boxes"], data["kps"], data["points"],
                               data["yaw"]):
        m0 = ert.upright_map(b, k)
        for a in range(augment + 1):
            m = m0 if a == 0 else _jitter(m0, rng)
            c = ert.crop(img, m)
            if a:
                c = _photometric_jitter(c, rng)
            crops.append(c)
            pts.append(ert.apply(m, p))
            kps.append(ert.apply(m, k))
            yaws.append(y)
    kps = np.asarray(kps)
    if weights is None:
        weights = ert.fit_yaw_regression(kps, np.asarray(yaws))
    est = ert.yaw_features(kps) @ weights
    mirror = ert.mirror_ids()
    for i in np.flatnonzero(est < 0):
        crops[i] = np.ascontiguousarray(crops[i][:, ::-1])
        q = pts[i].copy()
        q[:, 0] = ert.CROP_PX - q[:, 0]
        pts[i] = q[mirror]
    return {"crops": np.asarray(crops), "points": np.asarray(pts), "est_yaw": est,
            "weights": weights}


def _jitter(m: np.ndarray, rng) -> np.ndarray:
    """The crop map ``m`` turned, scaled and shifted a little about the crop's centre."""
    a = np.radians(rng.uniform(-8, 8))
    k = np.exp(rng.uniform(-0.08, 0.08))
    c, s = np.cos(a) * k, np.sin(a) * k
    h = ert.CROP_PX / 2
    shift = rng.uniform(-0.05, 0.05, 2) * ert.CROP_PX / ert.CROP_SCALE
    j = np.array([[c, -s, 0.0], [s, c, 0.0]])
    j[:, 2] = h - j[:, :2] @ [h, h] + shift
    return np.c_[j[:, :2] @ m[:, :2], j[:, :2] @ m[:, 2] + j[:, 2]]


def _photometric_jitter(img: np.ndarray, rng) -> np.ndarray:
    x = img.astype(np.float32)
    if rng.random() < 0.5:
        x = np.repeat(x @ np.array([0.299, 0.587, 0.114], np.float32), 3).reshape(x.shape)
    mean = x.mean()
    x = (x - mean) * rng.uniform(0.75, 1.25) + mean * rng.uniform(0.75, 1.25)
    return np.clip(x, 0, 255).astype(np.uint8)


def train(data: dict, out_dir=None, trees: int = 50, depth: int = 4, cascade: int = 10,
          oversampling: int = 10, nu: float = 0.1, threads: int = 2,
          augment: int = 2) -> list[Path]:
    """The yaw regression and one dlib.train_shape_predictor per yaw range
    (:data:`hack_render.vision.ert.YAW_BINS`), on the prepared upright, one-sided crops."""
    import dlib

    out_dir = Path(out_dir) if out_dir is not None else ert.DATA
    prep = prepare(data, augment=augment)
    np.savez_compressed(out_dir / ert.YAW_FILE.name, weights=prep["weights"],
                        what=np.array("derived: ridge regression of yaw (degrees) on BlazeFace "
                                      "keypoints in the upright crop, fitted on the model's "
                                      "renders (python -m hack_render.learn.face_ert train)"))
    opt = dlib.shape_predictor_training_options()
    opt.num_trees_per_cascade_level = trees
    opt.tree_depth = depth
    opt.cascade_depth = cascade
    opt.oversampling_amount = oversampling
    opt.nu = nu
    opt.feature_pool_size = 400
    opt.num_threads = threads
    opt.be_verbose = False
    rect = dlib.rectangle(*ert.crop_box())
    written = []
    for i in range(len(ert.YAW_BINS)):
        sel = [j for j, y in enumerate(prep["est_yaw"]) if i in ert.training_bins(abs(y))]
        imgs = [prep["crops"][j] for j in sel]
        objs = [[dlib.full_object_detection(
            rect, [dlib.point(round(x - 0.5), round(y - 0.5)) for x, y in prep["points"][j]])]
            for j in sel]
        t = time.time()
        predictor = dlib.train_shape_predictor(imgs, objs, opt)
        f = out_dir / ert.bin_file(i).name
        predictor.save(str(f))
        print(f"yaw {ert.YAW_BINS[i]}: trained on {len(imgs)} faces in {time.time() - t:.0f} s "
              f"-> {f} ({f.stat().st_size / 1e6:.1f} MB)")
        written.append(f)
    return written


def write_mean_shape(out=None) -> Path:
    """The model's mean 68 landmarks (the calibrated embedding's points on the template,
    metres) and their unit surface normals (area-weighted vertex normals interpolated
    the same way): ``hack_render/data/landmarks68_mean.npz`` for
    :mod:`hack_render.vision.pose`."""
    model = load_default_model()
    emb = load_default(model) or LandmarkEmbedding.from_vertices(
        model.landmark_indices.numpy(), model.faces.numpy())
    V = model.template.numpy().astype(np.float64)
    N = vertex_normals(V, model.faces.numpy())
    pts = emb.points_np(V)
    nrm = emb.points_np(N)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    out = Path(out or MEAN_FILE)
    np.savez_compressed(out, points=pts.astype(np.float32), normals=nrm.astype(np.float32),
                        what=np.array("derived: the HACK model's template, calibrated "
                                      "landmark embedding points and normals"))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--samples", type=int, default=200)
    c.add_argument("--seed", type=int, default=5301)
    c.add_argument("--out", required=True)
    t = sub.add_parser("train")
    t.add_argument("data", nargs="+", help="collect's .npz files")
    t.add_argument("--out-dir", default=None, help="default: the package's data folder")
    t.add_argument("--trees", type=int, default=50)
    t.add_argument("--nu", type=float, default=0.1)
    t.add_argument("--augment", type=int, default=2)
    sub.add_parser("mean-shape")
    a = ap.parse_args(argv)
    if a.cmd == "mean-shape":
        print(write_mean_shape())
    elif a.cmd == "collect":
        collect(a.samples, a.seed, out=a.out)
    else:
        parts = []
        for f in a.data:
            with np.load(f) as z:
                parts.append({k: z[k] for k in ("images", "boxes", "kps", "points", "yaw")})
        data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        train(data, a.out_dir, a.trees, nu=a.nu, augment=a.augment)


if __name__ == "__main__":
    main()
