"""Train the any-angle 68-point shape predictor (dlib's ensemble of regression trees) on
the model's renders composited over photographs.

    python -m hack_render.learn.face_ert collect --samples 600 --out ert_data.npz
    python -m hack_render.learn.face_ert train ert_data.npz
    python -m hack_render.learn.face_ert mean-shape     # the head-pose fit's mean landmarks

MediaPipe's face mesh, dlib's and most public 68-point models are trained on faces
within about 45 degrees of frontal; past that (profiles, heads tilted far back) they
give up or guess. The project's renderer gives faces at any angle with exact landmarks,
so this trains one: composites (:mod:`hack_render.vision.synthetic`; seed 5300, apart
from the dense map's 7100, the benchmark's 9000 and the tests' 31-33) at yaw U(-90, 90),
pitch U(-50, 50), roll U(-25, 25) degrees, a third of them with an occluder; each face's
box is BlazeFace's (as at run time: :func:`hack_render.vision.detect.find_boxes`), the
targets the true 68 landmarks (3-D convention: hidden points where they project).
Derived data: the model learns the model's renders; docs/vision.md gives its accuracy on
other subjects and backgrounds, and on real photos against the mesh detector.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

DEFAULT_FILE = Path(__file__).resolve().parents[1] / "data" / "face_ert_68.dat"


def collect(n: int, seed: int = 5300, res: int = 256, spp: int = 32, out=None) -> dict:
    """Composites with BlazeFace's box nearest the truth: images (S, res, res, 3) uint8,
    boxes (S, 4), points (S, 68, 2), yaw (S,)."""
    from tqdm import tqdm

    from hack_render.vision.detect import find_boxes
    from hack_render.vision.synthetic import CompositeRenderer

    rng = np.random.default_rng(seed)
    ren = CompositeRenderer(res, spp, seed)
    data = {"images": [], "boxes": [], "points": [], "yaw": []}
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
        data["points"].append(c.points)
        data["yaw"].append(c.yaw)
    arrays = {k: np.asarray(v) for k, v in data.items()}
    if out is not None:
        np.savez_compressed(out, **arrays)
    return arrays


def train(data: dict, out=DEFAULT_FILE, trees: int = 50, depth: int = 4, cascade: int = 10,
          oversampling: int = 10, nu: float = 0.4, threads: int = 2) -> Path:
    """dlib.train_shape_predictor on the composites (mirrored copies added: a face and
    its mirror image, the points relabelled left for right)."""
    import dlib

    from hack_render.vision.detect import MIRROR_68

    imgs, objs = [], []
    for img, b, p in zip(data["images"], data["boxes"], data["points"]):
        w = img.shape[1]
        for flip in (False, True):
            im = img[:, ::-1] if flip else img
            pts = p.copy()
            box = np.array(b, float)
            if flip:
                pts[:, 0] = w - pts[:, 0]
                pts = pts[MIRROR_68]
                box = np.array([w - b[2], b[1], w - b[0], b[3]])
            rect = dlib.rectangle(*[round(v) for v in box])
            parts = [dlib.point(round(x - 0.5), round(y - 0.5)) for x, y in pts]
            imgs.append(np.ascontiguousarray(im))
            objs.append([dlib.full_object_detection(rect, parts)])
    opt = dlib.shape_predictor_training_options()
    opt.num_trees_per_cascade_level = trees
    opt.tree_depth = depth
    opt.cascade_depth = cascade
    opt.oversampling_amount = oversampling
    opt.nu = nu
    opt.feature_pool_size = 400
    opt.num_threads = threads
    opt.be_verbose = False
    t = time.time()
    predictor = dlib.train_shape_predictor(imgs, objs, opt)
    out = Path(out)
    predictor.save(str(out))
    print(f"trained on {len(imgs)} faces in {time.time() - t:.0f} s -> {out} "
          f"({out.stat().st_size / 1e6:.1f} MB)")
    return out


def write_mean_shape(out=None) -> Path:
    """The model's mean 68 landmarks (the calibrated embedding's points on the template,
    metres) and their unit surface normals (area-weighted vertex normals interpolated
    the same way): ``hack_render/data/landmarks68_mean.npz`` for
    :mod:`hack_render.vision.pose`."""
    from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default
    from hack_render.geometry import load_default_model
    from hack_render.render.parts import vertex_normals
    from hack_render.vision.pose import MEAN_FILE

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
    c.add_argument("--samples", type=int, default=600)
    c.add_argument("--seed", type=int, default=5300)
    c.add_argument("--out", required=True)
    t = sub.add_parser("train")
    t.add_argument("data")
    t.add_argument("--out", default=str(DEFAULT_FILE))
    t.add_argument("--trees", type=int, default=50)
    t.add_argument("--nu", type=float, default=0.4)
    sub.add_parser("mean-shape")
    a = ap.parse_args(argv)
    if a.cmd == "mean-shape":
        print(write_mean_shape())
    elif a.cmd == "collect":
        collect(a.samples, a.seed, out=a.out)
    else:
        with np.load(a.data) as z:
            train({k: z[k] for k in z.files}, a.out, a.trees, nu=a.nu)


if __name__ == "__main__":
    main()
