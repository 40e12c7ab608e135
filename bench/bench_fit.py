"""Fitting accuracy and time (figures for the README; not a test).

    python bench/bench_fit.py --subjects 2 --res 256          # synthetic recovery
    python bench/bench_fit.py --astronaut --res 256           # real photo NME + time
    python bench/bench_fit.py --astronaut --portrait grace_hopper --res 256  # another portrait
    python bench/bench_fit.py --overhead --res 128            # bridge vs bare mi.render
    python bench/bench_fit.py --subjects 20 --detector-only   # dlib vs the true landmarks
    python bench/bench_fit.py ... --embedding vertices        # fit the model's vertices
    python bench/bench_fit.py --subjects 5 --oracle-landmarks # fit to the true points
    python bench/bench_fit.py --subjects 10 --out a.json & \
      python bench/bench_fit.py --subjects 20 --first 10 --out b.json; wait
    python bench/bench_fit.py --merge a.json b.json --out bench/results/fit_NAME.json
    python bench/bench_fit.py --subjects 8 --set '{"photometric": {"enabled": false}}'
    python bench/bench_fit.py --subjects 8 --expressions      # subjects with expressions
    python bench/bench_fit.py --subjects 20 --lighting random # random lighting presets
    python bench/bench_fit.py --subjects 20 --lighting random --oracle-lighting  # true light
    python bench/bench_fit.py --subjects 20 --lighting random --oracle-mask  # true mask
    python bench/bench_fit.py --subjects 20 --lighting random --camera random  # orbiting cameras

Landmarks: fits use dlib's points moved by the landmark refiner (hack_render/data/
landmark_refiner_dlib.npz; --set '{"landmarks": {"refiner": "off"}}' for dlib's own) and
the calibrated dlib embedding (hack_render/data/landmark_embedding_dlib.npz) unless
--embedding says otherwise. --detector-only reports
dlib's NME against the true landmark vertices (detector_nme) and against the true
embedding points (detector_nme_embedding); fits report the fitted-vs-true NME of both
(nme: landmark vertices, nme_embedding: embedding points). Both report mask_iou: the
automatic person mask (the silhouette term's, segmented from the photo as the fit config
says) against the render's true coverage (intersection over union; absent where the
photo gives no mask).

Synthetic: subjects from random beta (N(0, 0.8^2), 20 comps), head rotation, appearance
alpha and a frontal camera with random focal length (--expressions: plus 3 random FACS
units at 0.3-0.8); rendered with the path tracer (64 spp; light_stage, or with
--lighting random one of the four presets per subject, the rig turned U(-45, 45) deg
about the vertical) at --res; fitted from the image (dlib landmarks) and reported as
medians: face vertex error after similarity alignment (mm), landmark NME vs the true landmarks
(inter-ocular), albedo CIEDE2000 over the face tile, re-render PSNR over the skin mask,
neck joint angle error (degrees, mean over joints and axes). PSNR is reported for the
fitter's own re-render (4 spp, as it optimises) and for the same re-render at the
target's 64 spp (psnr_db_64spp), which leaves out most of the Monte Carlo noise.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from provenance import write_result  # bench/ is sys.path[0] when run as a script

from hack_render.fit.metrics import similarity_error


def _medians(rows: list) -> dict:
    ok = [r for r in rows if "error" not in r]
    keys = ("vertex_mm", "nme", "nme_embedding", "psi_mae", "albedo_de2000", "psnr_db", "psnr_db_64spp",
            "joint_deg", "mask_iou",
            "seconds", "detector_nme", "detector_nme_inner", "detector_nme_contour",
            "detector_nme_embedding", "detector_nme_embedding_inner",
            "detector_nme_embedding_contour")
    return {k: float(np.median([r[k] for r in ok if k in r])) for k in keys
            if any(k in r for r in ok)}


def render_subject(k: int, res: int, model, app, expressions: bool = False,
                   lighting: str = "light_stage", camera: str = "frontal") -> dict:
    """Synthetic subject k of the benchmark (torch generator seeded 100 + k): random
    beta, head rotation, appearance alpha, a frontal camera at a random focal length,
    rendered with the path tracer (64 spp). ``expressions``: also 3 random FACS units of
    the 53 at weights U(0.3, 0.8) (a second generator, seeded 1000 + k, so the other
    parameters are those of the neutral subject k). ``lighting``: a preset name
    (default ``light_stage``, uniform light) or ``"random"``: one of the four presets
    drawn with a rotation U(-45, 45) degrees about the vertical (a third generator,
    seeded 2000 + k; the other parameters stay those of subject k). ``camera``:
    ``"frontal"`` (default) or ``"random"``: the camera orbits the head by a yaw U(-25, 25)
    and a pitch U(-10, 10) degrees about the point between the ears, same distance and
    focal length (a fourth generator, seeded 3000 + k). Returns its
    parameters, the model output, the true skin maps, the camera, the lighting and the
    sRGB photo (and ``coverage``: 1 where a pixel centre's ray hits the head)."""
    import colour

    from hack_render.fit.fitter import R0
    from hack_render.fit.photo import Photo
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render.materials import SkinMaps
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes.cameras import Camera
    from scenes.lights import PRESETS, preset

    g = torch.Generator().manual_seed(100 + k)
    beta = 0.8 * torch.randn(1, 20, generator=g)
    ang = torch.deg2rad(torch.tensor([10.0, 30.0, 8.0]) * (2 * torch.rand(3, generator=g) - 1))
    theta = distribute_head_rotation(ang)[None]
    psi = torch.zeros(1, model.num_expressions)
    if expressions:
        ge = torch.Generator().manual_seed(1000 + k)
        units = torch.randperm(model.num_expressions, generator=ge)[:3]
        psi[0, units] = 0.3 + 0.5 * torch.rand(3, generator=ge)
    with torch.no_grad():
        out = model(beta=beta, psi=psi, theta=theta)
    alpha = torch.randn(1, 20, generator=g)
    with torch.no_grad():
        tmaps = app.maps(alpha)
    f = 50.0 / 36.0 * res * (1.8 + 0.6 * float(torch.rand(1, generator=g)))
    K = np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1.0]])
    R, t = R0.numpy().astype(np.float64), np.array([0.0, -0.03, 1.0])
    if camera == "random":
        from scipy.spatial.transform import Rotation

        gc = torch.Generator().manual_seed(3000 + k)
        yaw, pitch = (float(x) for x in (torch.tensor([25.0, 10.0])
                                         * (2 * torch.rand(2, generator=gc) - 1)))
        c = np.array([0.0, 0.03, 0.0])            # about the middle of the head
        Rw = Rotation.from_euler("yx", [yaw, pitch], degrees=True).as_matrix()
        t = t + R @ c - R @ Rw @ c
        R = R @ Rw
    cam = Camera(K, R, t, res, res)
    if lighting == "random":
        gl = torch.Generator().manual_seed(2000 + k)
        name = list(PRESETS)[int(torch.randint(len(PRESETS), (1,), generator=gl))]
        rig = preset(name, rotation_deg=float(90.0 * torch.rand(1, generator=gl) - 45.0))
    else:
        rig = preset(lighting)
    # the path integrator, as in the published figures: the fitter's prb has its light
    # transport (volpath, the final renders' default, also lights the skin under the lash
    # cards, which prb's shadow rays do not reach)
    head = HeadScene(Topology.from_model(model), out.vertices[0].numpy(),
                     rig, cam, RenderSettings(res, res, 64, 4, 0, integrator="path"),
                     SkinMaps.from_appearance(tmaps))
    img = head.render()[..., :3]
    srgb = np.clip(colour.cctf_encoding(np.clip(img, 0, 1), function="sRGB"), 0, 1)
    photo = Photo(srgb.astype(np.float32), f"synthetic{k}")
    return {"beta": beta, "psi": psi, "theta": theta, "alpha": alpha, "out": out, "tmaps": tmaps,
            "cam": cam, "lighting": f"{rig.name} {rig.rotation_deg:+.0f} deg", "rig": rig,
            "photo": photo, "coverage": (head.aovs()["depth"] > 0).astype(np.float32)}


def rig_env_map(rig, height: int = 64, centre=(0.0, 0.02, 0.05), ss: int = 4) -> np.ndarray:
    """A light rig as one lat-long environment map (height, 2 height, 3) seen from
    ``centre`` (the head): area lights rasterised where a ray from the centre meets them,
    the rig's environment turned by its rotation, supersampled ``ss`` x ``ss`` per texel.
    Diagnostic (``--oracle-lighting``): the best the photometric stage's environment can
    know of the light; it leaves out the area lights' parallax across the head."""
    import math

    from hack_render.render.emitters import area_light_transform, rotation_y
    from hack_render.io.image import read_hdr_image
    from scenes.lights import latlong_directions

    hs = height * ss
    d = latlong_directions(hs).reshape(-1, 3)
    c = np.asarray(centre, float)
    img = np.zeros((len(d), 3))
    if rig.env_constant is not None:
        img += np.asarray(rig.env_constant)
    src = rig.env_map if rig.env_map is not None else (
        read_hdr_image(rig.env_file)[..., :3] if rig.env_file is not None else None)
    if src is not None:  # world direction -> the map's own frame (the rig turns it)
        dl = d @ np.asarray(rotation_y(rig.rotation_deg))[:3, :3]
        th = np.arccos(np.clip(dl[:, 1], -1.0, 1.0))
        ph = np.arctan2(dl[:, 0], -dl[:, 2]) % (2 * math.pi)
        h = src.shape[0]
        img += src[np.clip((th / math.pi * h).astype(int), 0, h - 1),
                   np.clip((ph / (2 * math.pi) * 2 * h).astype(int), 0, 2 * h - 1)]
    for light in rig.area:
        m = area_light_transform(light, rig.rotation_deg)
        p, ex, ey, n = m[:3, 3], m[:3, 0], m[:3, 1], m[:3, 2] / np.linalg.norm(m[:3, 2])
        dn = d @ n
        t = ((p - c) @ n) / np.where(np.abs(dn) > 1e-9, dn, 1e-9)
        q = c + t[:, None] * d - p
        a, b = q @ ex / (ex @ ex), q @ ey / (ey @ ey)
        img[(t > 0) & (dn < 0) & (np.abs(a) <= 1) & (np.abs(b) <= 1)] += light.radiance
    img = img.reshape(hs, 2 * hs, 3) * rig.scale
    return img.reshape(height, ss, 2 * height, ss, 3).mean((1, 3)).astype(np.float32)


def synthetic(n: int, res: int, cfg_over: dict, out_path=None, detector_only=False,
              oracle_landmarks=False, first: int = 0, expressions: bool = False,
              known_focal: bool = False, lighting: str = "light_stage", camera: str = "frontal",
              oracle_lighting: bool = False, oracle_mask: bool = False) -> dict:
    """Fit synthetic subjects ``first`` .. ``n - 1``; with ``out_path`` the JSON is
    rewritten after every subject (and subjects already in it are skipped), so an
    interrupted run resumes. ``oracle_lighting``: the photometric stage lit by the
    subject's true rig (:func:`rig_env_map`, 64 rows, held fixed but for the exposure
    match), a diagnostic of what the lighting model costs. ``oracle_mask``: the person mask
    is the render's true coverage (> 0.5), not one segmented from the photo, a diagnostic
    of what the automatic segmentation costs."""
    from pathlib import Path

    import colour

    from appearance.model import AppearanceModel
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.landmarks import detect
    from hack_render.fit.silhouette import segment_plain_background
    from hack_render.geometry import load_default_model

    model = load_default_model()
    app = AppearanceModel.load()
    rows = []
    if out_path is not None and Path(out_path).is_file():
        rows = json.loads(Path(out_path).read_text()).get("subjects", [])
    done = {r["subject"] for r in rows}

    def save():
        if out_path is not None:
            write_result(out_path, {"config": cfg_over, "res": res,
                                    "expressions": expressions, "known_focal": known_focal,
                                    "lighting": lighting, "camera": camera,
                                    "subjects": rows,
                                    "n_ok": sum("error" not in r for r in rows),
                                    "median": _medians(rows)})

    from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default
    from hack_render.learn.landmark_calibration import CalibrationSet, evaluate

    emb = load_default(model)
    li = model.landmark_indices.numpy()
    vert_emb = LandmarkEmbedding.from_vertices(li, model.faces.numpy())
    template = model.template.numpy().astype(np.float64)
    for k in range(first, n):
        if k in done:
            continue
        subj = render_subject(k, res, model, app, expressions, lighting, camera)
        _beta, theta, out, tmaps, cam, photo = (subj[x] for x in ("beta", "theta", "out",
                                                                  "tmaps", "cam", "photo"))
        if known_focal:  # as a camera's EXIF FocalLengthIn35mmFilm would give it
            photo.focal_mm = float(cam.K[0, 0]) / max(photo.width, photo.height) * 36.0
            photo.focal_source = "exif (bench: the render's true focal length)"
        try:
            # dlib, refined as the fit config says (landmarks.refiner)
            det = detect(photo.uint8(), load_config(None, cfg_over).landmarks, photo.name)
        except Exception as err:  # noqa: BLE001 - reported, not hidden
            rows.append({"subject": k, "lighting": subj["lighting"], "error": str(err)})
            save()
            continue
        # the detector's own error against the true landmarks (a floor for the fit's
        # landmark error, which is fitted to the detector's points): against the model's
        # landmark vertices and against the calibrated embedding's points; "_contour":
        # the jawline matched to the true mesh's occluding contour, as the fitter does
        V = out.vertices[0].numpy().astype(np.float64)
        lm_true = cam.project(V[li])
        iod = np.linalg.norm(lm_true[36] - lm_true[45])
        one = CalibrationSet(V[None], cam.K[None], cam.R[None], cam.t[None],
                             det.points[None], np.array([k]))
        ev = evaluate(one, emb if emb is not None else vert_emb, li, template,
                      model.faces.numpy())
        names = {"vertices": "detector_nme", "vertices_inner": "detector_nme_inner",
                 "vertices_contour": "detector_nme_contour"}
        if emb is not None:
            names.update(embedding="detector_nme_embedding",
                         embedding_inner="detector_nme_embedding_inner",
                         embedding_contour="detector_nme_embedding_contour")
        det_nme = {b: ev[a][0] for a, b in names.items()}
        if emb is not None:
            emb_true = cam.project(emb.points_np(V))
        if oracle_landmarks:  # diagnostic: the fit from the true points, not dlib's
            import dataclasses

            # the true landmark vertices, fitted through the vertices (source "truth")
            det = dataclasses.replace(det, points=lm_true.astype(np.float64), source="truth")
        # the automatic person mask (as the fitter makes it) against the true coverage
        fcfg = load_config(None, cfg_over)
        auto, _ = segment_plain_background(photo.rgb, det.points,
                                           chroma=fcfg.silhouette.chroma)
        cov = subj["coverage"] > 0.5
        if auto is not None:
            det_nme["mask_iou"] = float((auto & cov).sum() / (auto | cov).sum())
        if detector_only:
            rows.append({"subject": k, **det_nme})
            print(json.dumps(rows[-1]), flush=True)
            save()
            continue
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fitter = Fitter([photo], [det], load_config(None, cfg_over), model=model,
                            appearance=app, progress=True,
                            masks=[subj["coverage"] > 0.5] if oracle_mask else None)
            if oracle_lighting:
                from hack_render.fit.lighting import Lighting

                fitter.state.views[0].lighting = Lighting("env", 64)
                with torch.no_grad():
                    env = torch.from_numpy(rig_env_map(subj["rig"], 64))
                    fitter.state.views[0].lighting.log_texels.copy_(torch.log(env.clamp_min(1e-4)))
            fitter.run()
        dt = time.perf_counter() - t0
        v = fitter.state.views[0]
        with torch.no_grad():
            fo = fitter.forward(v)
            fit_maps = fitter.maps()
        face = slice(0, 9409)
        verr = similarity_error(fo.vertices[0][face].numpy(), out.vertices[0][face].numpy())
        with torch.no_grad():
            lm_fit = fitter.project(v, fo.landmarks[0]).numpy()
        nme = np.linalg.norm(lm_fit - lm_true, axis=1).mean() / iod
        extra = {}
        if emb is not None:  # the same, for the embedding's points (fit vs truth)
            with torch.no_grad():
                ef = fitter.project(v, emb.points(fo.vertices[0])).numpy()
            extra["nme_embedding"] = float(np.linalg.norm(ef - emb_true, axis=1).mean() / iod)
        if expressions:  # mean absolute error of the 53 expression weights
            extra["psi_mae"] = float((fitter.state.psi.detach() - subj["psi"]).abs().mean())
        mask = app.mask_np[:, : app.height]
        lab = lambda x: colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.clip(x, 1e-6, 1),
                                                               apply_cctf_decoding=False))
        de = colour.delta_E(lab(fit_maps["albedo"].numpy()[:, : app.height][mask]),
                            lab(tmaps.diffuse[0].numpy()[:, : app.height][mask]),
                            method="CIE 2000")
        from hack_render.fit.photometric import level_maps, render_view, setup_level

        if v.renderer is None:  # photometric stage off: a level (and lighting) to render
            setup_level(fitter.state, fitter.cfg, v, res)
        with torch.no_grad():
            lmaps = level_maps(fitter.state, v)  # the atlas size of the level's scene
            rimg = render_view(v, lmaps, fo.vertices[0], 999)[..., :3].numpy()
            # the same re-render at the target's 64 spp: the fit without the 4-spp noise
            rimg64 = v.renderer.render(seed=999, spp=64, vertices=fo.vertices[0],
                                       albedo=lmaps["albedo"], specular=lmaps["specular"],
                                       roughness=lmaps["roughness"], normal=lmaps["normal"],
                                       env=v.lighting.env_map())[..., :3].numpy()
        m = v.level.mask.numpy()
        mse = float(((rimg - v.level.target.numpy())[m] ** 2).mean())
        psnr = 10 * np.log10(1.0 / max(mse, 1e-12))
        mse64 = float(((rimg64 - v.level.target.numpy())[m] ** 2).mean())
        extra["psnr_db_64spp"] = float(10 * np.log10(1.0 / max(mse64, 1e-12)))
        th_fit = fitter.theta(v).detach()
        from hack_render.geometry.rotations import axis_angle_to_euler

        jerr = float(torch.rad2deg((axis_angle_to_euler(th_fit) - axis_angle_to_euler(theta)).abs()).mean())
        rows.append({"subject": k, "lighting": subj["lighting"],
                     "vertex_mm": 1000 * verr, "nme": float(nme),
                     "albedo_de2000": float(np.median(de)), "psnr_db": float(psnr),
                     "joint_deg": jerr, "seconds": dt, **extra, **det_nme})
        print(json.dumps(rows[-1]), flush=True)
        save()
    return {"subjects": rows, "median": _medians(rows)}


#: openly licensed portraits that installed packages ship: scikit-image's astronaut (NASA,
#: public domain) and matplotlib's sample Grace Hopper (US Navy photograph, public domain)
PORTRAITS = ("astronaut", "grace_hopper")


def portrait_file(name: str, folder) -> Path:
    """Write portrait ``name`` (see :data:`PORTRAITS`) into ``folder``; its path."""
    from pathlib import Path

    if name == "astronaut":
        import imageio.v3 as iio
        from skimage import data

        p = Path(folder) / "astronaut.png"
        iio.imwrite(p, data.astronaut())
        return p
    if name == "grace_hopper":
        from matplotlib import cbook

        p = Path(folder) / "grace_hopper.jpg"  # the file as shipped (bytes, EXIF and all)
        p.write_bytes(Path(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)).read_bytes())
        return p
    raise ValueError(f"portrait: expected one of {', '.join(PORTRAITS)}, found {name!r}")


def astronaut(res: int, cfg_over: dict, name: str = "astronaut") -> dict:
    """Fit a real portrait (``name``: see :data:`PORTRAITS`) with `hack-render fit`'s
    library entry point; its time, stage times and landmark NME against the detector."""
    import tempfile
    from pathlib import Path

    from hack_render.fit import terms
    from hack_render.fit.cli import fit_photos
    from hack_render.fit.config import load_config

    with tempfile.TemporaryDirectory() as d:
        p = portrait_file(name, d)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res_, _ = fit_photos([p], Path(d) / "out", load_config(None, cfg_over))
        total = time.perf_counter() - t0
    state = res_.state
    v = state.views[0]
    with torch.no_grad():
        verts = state.forward(v).vertices[0]
        # it=1: the jaw stays matched to the contour as the last stage left it
        pred = state.project(v, terms.model_landmarks(state, res_.config, v, verts, 1)).numpy()
    det = v.detection.points
    err = np.linalg.norm(pred - det, axis=1) / np.linalg.norm(det[36] - det[45])
    groups = {"jaw": slice(0, 17), "brows": slice(17, 27), "nose": slice(27, 36),
              "eyes": slice(36, 48), "mouth": slice(48, 68)}
    # refined detections (landmarks.refiner): also against dlib's own points, and how far
    # the refiner moved them (mean over the chin and the inner points)
    raw = v.detection.raw if v.detection.refined else det
    iod_raw = np.linalg.norm(raw[36] - raw[45])
    err_raw = np.linalg.norm(pred - raw, axis=1) / iod_raw
    shift = np.linalg.norm(det - raw, axis=1)[[8] + list(range(17, 68))] / iod_raw
    return {"total_s": total, "stages_s": res_.timings, "refined": v.detection.refined,
            "landmark_nme_dlib_raw": float(err_raw.mean()),
            "refiner_shift_inner": float(shift.mean()),
            "landmark_nme": float(err.mean()), "landmark_nme_inner": float(err[17:].mean()),
            "landmark_nme_groups": {k: float(err[s].mean()) for k, s in groups.items()},
            "photometric_iteration_s": {r.name: float(np.mean(r.per_iteration_s))
                                        for r in res_.reports if r.per_iteration_s},
            "focal_px": float(v.focal.detach()), "photo": name,
            "silhouette": v.silhouette_note, "size_px": [v.photo.width, v.photo.height]}


def overhead(res: int, spp: int, reps: int = 5, overrides: dict | None = None) -> dict:
    """Photometric iteration through the bridge (torch model + appearance maps + light
    -> render -> loss -> backward into torch) vs pure-Mitsuba iterations of the same scene
    (same DiffRenderer: integrator, resolution, spp), see DiffRenderer.bare_iteration:
    ``bare_step`` writes the parameters the bridge feeds (vertex positions, skin maps,
    env texels) as an optimiser step does, so the geometry is rebuilt as in the fit;
    ``bare_render`` renders the unchanged scene (no rebuild; a lower bound). ``bridge``
    is the render path alone (maps, model, render, an L1 loss); ``stage_*`` the
    photometric stage's whole objective (photo term, landmarks, silhouette, priors)."""
    from skimage import data

    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import from_array
    from hack_render.fit.photometric import (
        init_lobes,
        level_maps,
        level_objective,
        render_view,
        setup_level,
    )
    from hack_render.vision.landmarks68 import detect_landmarks

    ph = from_array(data.astronaut(), "astronaut")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        det = detect_landmarks(ph.uint8())
    over = json.loads(json.dumps(overrides or {}))
    over.setdefault("photometric", {})["spp"] = spp
    fitter = Fitter([ph], [det], load_config(None, over), progress=False)
    v = fitter.state.views[0]
    # the state the photometric stage starts from: the landmark stages' fitted camera,
    # pose, beta and (sparse, clamped) psi
    fitter.fit_camera()
    fitter.fit_shape()
    # the torch threads the photometric stage runs with (photometric.torch_threads)
    torch.set_num_threads(fitter.cfg.photometric.torch_threads)
    setup_level(fitter.state, fitter.cfg, v, res)
    r = v.renderer
    target = v.level.target
    if v.lighting.mode == "sg":  # the lobe where the stage starts it
        init_lobes(fitter.state, fitter.cfg, v)
    leaves = [fitter.state.alpha, fitter.state.beta, fitter.state.psi, v.dtheta, v.head_angles,
              *v.lighting.parameters()]

    def bridge_iter(i):
        for p in leaves:
            p.grad = None
        maps = level_maps(fitter.state, v)  # the atlas size the photometric stage renders with
        verts = fitter.forward(v).vertices[0]
        img = render_view(v, maps, verts, i)
        (img[..., :3] - target).abs().mean().backward()

    def model_iter(i):  # the torch parts alone: HACK model forward + backward
        for p in leaves:
            p.grad = None
        fitter.forward(v).vertices[0].sum().backward()

    def maps_iter(i):  # appearance maps forward + backward, at the level's atlas size
        fitter.state.alpha.grad = None
        sum(x.sum() for x in level_maps(fitter.state, v).values() if x is not None).backward()

    _, stage_loss = level_objective(fitter.state, fitter.cfg)  # the photometric stage's own objective

    def stage_iter(i):  # one iteration of the stage: its whole loss + backward
        for p in leaves:
            p.grad = None
        stage_loss(i)[0].backward()

    # the stage refreshes the skin mask, the jawline and the silhouette contour every 10
    # iterations: "stage_step" times the other 9 (it = 10 k + 1), "stage_refresh" the
    # 10th (it = 10 k); "stage_amortised" = (9 stage_step + stage_refresh) / 10
    fns = {"bridge": bridge_iter, "model_fwd_bwd": model_iter, "maps_fwd_bwd": maps_iter,
           "stage_step": lambda i: stage_iter(10 * i + 1),
           "stage_refresh": lambda i: stage_iter(10 * i + 10),
           "bare_step": lambda i: r.bare_iteration(target.numpy(), i, write=True),
           "bare_render": lambda i: r.bare_iteration(target.numpy(), i, write=False)}
    for fn in fns.values():
        fn(0)  # compile
    ts = {k: [] for k in fns}
    for i in range(reps):  # interleaved, so load changes on the shared machine hit all
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn(i + 1)
            ts[name].append(time.perf_counter() - t0)
    out = {k: float(np.median(x)) for k, x in ts.items()}
    out["stage_amortised"] = (9 * out["stage_step"] + out["stage_refresh"]) / 10
    out["ratio_vs_bare_step"] = out["bridge"] / out["bare_step"]
    out["stage_ratio_vs_bare_step"] = out["stage_amortised"] / out["bare_step"]
    out["ratio_vs_bare_render"] = out["bridge"] / out["bare_render"]
    # the same ratios rep by rep (each rep's iterations ran back to back, so load changes
    # on the shared machine cancel), then their median
    step = np.asarray(ts["bare_step"])
    amort = (9 * np.asarray(ts["stage_step"]) + np.asarray(ts["stage_refresh"])) / 10
    out["ratio_vs_bare_step_per_rep"] = float(np.median(np.asarray(ts["bridge"]) / step))
    out["stage_ratio_vs_bare_step_per_rep"] = float(np.median(amort / step))
    out.update(res=res, spp=spp, reps=reps, integrator=r.integrator_name,
               torch_threads=torch.get_num_threads(),
               psi_nonzero=int((fitter.state.psi != 0).sum()), psi_size=int(fitter.state.psi.numel()))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--subjects", type=int, default=0)
    ap.add_argument("--astronaut", action="store_true",
                    help="fit a real portrait (--portrait; default the astronaut)")
    ap.add_argument("--overhead", action="store_true")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--iterations", type=str, default="40,30")
    ap.add_argument("--detector-only", action="store_true",
                    help="synthetic: render, detect and segment only (the detector's "
                         "landmark NME, the automatic mask's IoU)")
    ap.add_argument("--oracle-landmarks", action="store_true",
                    help="synthetic, diagnostic: fit to the true projected landmark points "
                         "instead of dlib's (what the fit reaches without detector noise)")
    ap.add_argument("--expressions", action="store_true",
                    help="synthetic: subjects also wear 3 random FACS units at 0.3-0.8 "
                         "(reports psi_mae, the mean absolute expression weight error)")
    ap.add_argument("--tiny", action="store_true",
                    help="astronaut: the CI settings of tests/test_fit_e2e.py (tiny_overrides)")
    ap.add_argument("--portrait", choices=PORTRAITS, default="astronaut",
                    help="the real photo --astronaut fits (default: astronaut)")
    ap.add_argument("--known-focal", action="store_true",
                    help="synthetic: give each photo its true focal length, as a camera's "
                         "EXIF FocalLengthIn35mmFilm would (default: fit from the image alone)")
    ap.add_argument("--reps", type=int, default=7, help="overhead: timed iterations each")
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch's threads (1: two synthetic runs share the 2 cores; "
                         "`hack-render fit` itself uses up to 2)")
    ap.add_argument("--embedding", type=str, default=None,
                    help="config landmarks.embedding for the fits: dlib (default: the "
                         "calibrated embedding), vertices (the model's landmark vertices, "
                         "the former behaviour) or an embedding file")
    ap.add_argument("--out", type=str, default=None,
                    help="synthetic: JSON written after every subject; resumes from it")
    ap.add_argument("--set", type=str, default=None, metavar="JSON",
                    help='config overrides by section, e.g. \'{"shape": {"w_psi": 0.02}, '
                         '"photometric": {"enabled": false}}\' (the ablations in the README)')
    ap.add_argument("--lighting", type=str, default="light_stage",
                    help="synthetic: the targets' lighting, a preset name or 'random' (one "
                         "of the four presets per subject, rotated U(-45, 45) deg)")
    ap.add_argument("--camera", choices=("frontal", "random"), default="frontal",
                    help="synthetic: the targets' camera, frontal or orbiting the head by a "
                         "random yaw U(-25, 25) and pitch U(-10, 10) deg")
    ap.add_argument("--oracle-lighting", action="store_true",
                    help="synthetic, diagnostic: the photometric stage lit by each subject's "
                         "true light rig as a fixed 64-row environment map (only its exposure "
                         "is matched), not a fitted lighting model")
    ap.add_argument("--oracle-mask", action="store_true",
                    help="synthetic, diagnostic: the silhouette term's person mask is the "
                         "render's true coverage, not one segmented from the photo")
    ap.add_argument("--first", type=int, default=0,
                    help="synthetic: first subject (split a run over processes, then "
                         "--merge their JSON files)")
    ap.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                    help="merge synthetic JSON files (from --first splits) into --out, "
                         "recomputing the medians; nothing is fitted")
    args = ap.parse_args()
    if args.merge:
        from pathlib import Path

        parts = [json.loads(Path(p).read_text()) for p in args.merge]
        rows = sorted({r["subject"]: r for p in parts for r in p["subjects"]}.values(),
                      key=lambda r: r["subject"])
        merged = {"config": parts[0]["config"], "res": parts[0]["res"],
                  "expressions": parts[0].get("expressions", False),
                  "known_focal": parts[0].get("known_focal", False),
                  "lighting": parts[0].get("lighting", "light_stage"),
                  "camera": parts[0].get("camera", "frontal"), "subjects": rows,
                  "n_ok": sum("error" not in r for r in rows), "median": _medians(rows)}
        if args.out:
            write_result(args.out, merged)
        print(json.dumps(merged["median"]))
        return
    torch.set_num_threads(args.torch_threads)
    its = [int(x) for x in args.iterations.split(",")]
    cfg = {"photometric": {"resolutions": [args.res // 2, args.res], "iterations": its,
                           "spp": args.spp}}
    if args.embedding:
        cfg["landmarks"] = {"embedding": args.embedding}
    if args.oracle_lighting:
        cfg["photometric"].update(lighting="env", env_height=64, lr_light=0.0)
    if args.set:
        for sec, val in json.loads(args.set).items():
            if isinstance(val, dict):
                cfg.setdefault(sec, {}).update(val)
            else:
                cfg[sec] = val
    out = {"config": cfg}
    if args.overhead:
        out["overhead"] = overhead(args.res, args.spp, args.reps, cfg)
        print(json.dumps(out["overhead"]))
    if args.astronaut:
        if args.tiny:
            from hack_render.fit.config import tiny_overrides

            cfg = out["config"] = tiny_overrides()
            if args.embedding:
                cfg["landmarks"] = {"embedding": args.embedding}
        out[args.portrait] = astronaut(args.res, cfg, args.portrait)
        print(json.dumps(out[args.portrait]))
    if args.subjects:
        out["synthetic"] = synthetic(args.subjects, args.res, cfg, args.out,
                                     args.detector_only, args.oracle_landmarks, args.first,
                                     args.expressions, args.known_focal, args.lighting,
                                     camera=args.camera, oracle_lighting=args.oracle_lighting,
                                     oracle_mask=args.oracle_mask)
        print(json.dumps(out["synthetic"]["median"]))
    elif args.out:  # --overhead / --astronaut: the synthetic run writes its own file
        write_result(args.out, out)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
