"""Writing a fit: parameters (JSON + npz), meshes (OBJ + .mtl + PLY, in the model's vertex
order), texture maps (EXR + PNG), an overlay sheet, loss curves (PNG + JSON), timings and a
report. Every file is written under a temporary name and renamed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from PIL import Image

from appearance.texture_io import write_exr, write_png
from hack_render.boundary import clean_temporaries as clean
from hack_render.fit import terms
from hack_render.fit.bake_weights import feature_rings, mask_at
from hack_render.fit.camera import focal_prior_px
from hack_render.fit.final import FinalRenders
from hack_render.fit.fitter import R0, SENSOR_MM, FitResult
from hack_render.fit.landmark_refiner import load_refiner
from hack_render.fit.photometric import level_maps, render_view, setup_level
from hack_render.fit.terms import fitted_points, landmark_residual_iod
from hack_render.fit.virtual_view import on_photo, warp_photo
from hack_render.geometry.obj_io import ObjMaterials, write_mesh
from hack_render.geometry.params import save_params
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.io import TEMP_GLOB, atomic_path, write_json
from hack_render.io.image import straight_colour, to_srgb8
from hack_render.io.npz import write_npz
from hack_render.render.materials import material_base_colours
from hack_render.render.skin_maps import IRIS_FILE, PARTS_FILE, SKIN_FILE
from hack_render.vision.neck import above_brows, below_face

#: The hidden temporaries a killed fit may leave in its folder: ``hack_render.io``'s, and
#: the names older versions gave them (one pattern per output).
TEMPORARIES = (TEMP_GLOB, ".params*", ".cameras.*", ".fit_report.*", ".timings.*",
               ".losses.*", ".overlay*", ".mesh*", ".fit_run.*", ".render*", ".occlusion*")


def clean_temporaries(outdir: Path) -> None:
    """Remove what a killed fit left half-written in ``outdir`` (its own names only)."""
    for pattern in TEMPORARIES:
        clean(outdir, pattern)
    clean(outdir / "textures", ".*")


def view_params(res: FitResult, i: int) -> dict:
    """Parameter mapping of view ``i`` in the format of `hack-render render --params`."""
    v = res.views[i]
    with torch.no_grad():
        theta = distribute_head_rotation(v.head_angles, clamp=False) + v.dtheta
        psi = (v.psi if v.psi is not None else res.psi)[0]
    return {"beta": res.beta[0].detach().tolist(), "psi": psi.detach().tolist(),
            "theta": theta.detach().tolist(), "global_orient": v.global_orient.detach().tolist(),
            "transl": [0.0, 0.0, 0.0], "eta": float(torch.as_tensor(res.eta).detach()),
            "tau": float(torch.as_tensor(res.tau).detach())}


def camera_dict(v) -> dict:
    f = float(v.focal.detach())
    K = [[f, 0.0, v.photo.width / 2], [0.0, f, v.photo.height / 2], [0.0, 0.0, 1.0]]
    return {"name": v.photo.name, "width": v.photo.width, "height": v.photo.height, "K": K,
            "R": R0.tolist(), "t": v.transl.detach().tolist(),
            "convention": "OpenCV: x_cam = R @ X_world + t; x right, y down, z forward"}


def _colour_cast(v) -> float | None:
    """The view's fitted light's colour cast (``Lighting.colour_cast`` on the skin of its
    last photometric level), as an rms log-chromaticity."""
    reach = v.level.reach if v.level is not None else None
    with torch.no_grad():
        return round(float(v.lighting.colour_cast(reach=reach)) ** 0.5, 4)


def _refiner_shift(det) -> float | None:
    """Mean distance the landmark refiner (and the fusion, ``landmarks_fused``) moved the
    chin and inner points, in units of dlib's inter-ocular distance (None: not refined)."""
    if not det.refined:
        return None
    iod = max(float(np.linalg.norm(det.raw[36] - det.raw[45])), 1e-9)
    idx = [8] + list(range(17, 68))
    return float(np.linalg.norm(det.points[idx] - det.raw[idx], axis=1).mean() / iod)


def fitted_landmarks(res: FitResult, v) -> np.ndarray:
    """(68, 2) the fitted model's landmark points (the jawline on its contour) projected
    into the view's photo, in pixels."""
    return fitted_points(res.state, res.config, v, rematch=True)


def _refiner_provenance(res) -> str | None:
    """The landmark refiner's provenance when a view's points were refined."""
    if not any(v.detection.refined for v in res.views):
        return None

    ref = load_refiner(res.config.landmarks.refiner)
    return None if ref is None else ref.meta.get("provenance")


def _pose_entry(state, v) -> dict:
    """Torso, neck and head angles of a view (degrees, pitch/yaw/roll about the model's
    x, y, z): the torso (global_orient, relative to the camera), the neck's turn (the
    head's rotation shared over the cervical joints, plus their residuals: the sum over
    the 8 joints), and the head's (the two together, to first order); and what set the
    torso: the silhouette where the person mask shows the shoulders, else the priors
    (a turn the landmarks cannot place goes to the torso)."""
    with torch.no_grad():
        torso = np.rad2deg(v.global_orient.numpy())
        neck = np.rad2deg(state.theta(v)[0].sum(0).numpy())
    return {"torso": torso.round(2).tolist(), "neck": neck.round(2).tolist(),
            "head": (torso + neck).round(2).tolist(),
            "torso_from": ("silhouette (the shoulders are in the person mask)"
                           if v.shoulders and v.silhouette is not None
                           else "priors (no shoulders in a person mask)")}


def _focal_entry(cfg, v) -> dict:
    """The view's focal length, fitted and prior, in 35 mm-equivalent mm, and the
    prior's source ("prior": camera.focal_mm_prior; "exif"; "--focal-mm")."""
    mm = SENSOR_MM / max(v.photo.width, v.photo.height)
    f0, sigma, source = focal_prior_px(cfg.camera, v.photo)
    return {"fitted_mm": float(v.focal.detach()) * mm, "prior_mm": f0 * mm,
            "prior_log_sigma": sigma, "source": source}


def write_all(res: FitResult, outdir: Path, extra: dict | None = None,
              sheet_passes: int = 16) -> list[Path]:
    """Write everything of the fit ``res`` (its state and its final stage's renders) to
    ``outdir``; returns the paths written. ``sheet_passes``: the overlay sheets' render
    passes where the final stage did not run (:func:`_final_render`; fewer, a noisier
    render panel, faster)."""
    outdir = Path(outdir)
    state, final = res.state, res.final
    outdir.mkdir(parents=True, exist_ok=True)
    clean_temporaries(outdir)
    written = []
    for i, v in enumerate(res.views):
        name = "params.json" if i == 0 else f"params_view{i}.json"
        params = view_params(res, i)
        if final is not None and final.hair_style is not None:  # final.hair
            params["hair"] = final.hair_style.to_dict()
        written.append(save_params(outdir / name, params))
    fitted = [fitted_landmarks(res, v) for v in res.views]   # the npz's and the report's
    arrays = {"beta": res.beta.detach().numpy(), "psi": res.psi.detach().numpy(),
              "alpha": res.alpha.detach().numpy(), "eta": res.eta.detach().numpy(),
              "tau": res.tau.detach().numpy()}
    teeth = None if res.state is None else res.state.teeth
    if teeth is not None:  # the upper teeth's drop, metres (fit/teeth.py)
        arrays["teeth_drop"] = teeth.detach().numpy().astype(np.float32)
    for i, v in enumerate(res.views):
        p = view_params(res, i)
        arrays[f"view{i}_theta"] = np.asarray(p["theta"], np.float32)
        arrays[f"view{i}_psi"] = np.asarray(p["psi"], np.float32)
        arrays[f"view{i}_global_orient"] = np.asarray(p["global_orient"], np.float32)
        if v.gaze is not None:  # the eyeballs' (yaw, pitch), radians (fit/eyes.py)
            arrays[f"view{i}_gaze"] = v.gaze.detach().numpy().astype(np.float32)
        cam = camera_dict(v)
        arrays[f"view{i}_K"] = np.asarray(cam["K"])
        arrays[f"view{i}_R"] = np.asarray(cam["R"])
        arrays[f"view{i}_t"] = np.asarray(cam["t"])
        arrays[f"view{i}_landmarks_detected"] = v.detection.points  # refined, if so
        arrays[f"view{i}_landmarks_fitted"] = fitted[i]
        if v.detection.refined:  # dlib's own points, before the landmark refiner
            arrays[f"view{i}_landmarks_dlib"] = v.detection.raw
        if v.lighting is not None:
            arrays[f"view{i}_env_map"] = v.lighting.env_map().detach().numpy()
            if v.lighting.mode in ("sh", "sg"):
                arrays[f"view{i}_sh"] = v.lighting.coeffs.detach().numpy()
            for key, val in v.lighting.summary().items():  # "sg": the lobes
                arrays[f"view{i}_{key}"] = np.asarray(val, np.float32)
    with atomic_path(outdir / "params.npz") as tmp:
        np.savez(tmp, **arrays)
    written.append(outdir / "params.npz")
    cams = [camera_dict(v) for v in res.views]
    written.append(write_json(outdir / "cameras.json", {"cameras": cams}, indent=1))
    m = res.model
    # the photo-size renders and the baked skin (the final stage, fit/final.py; without
    # the photometric stage's lighting it did not run: the textures are the model's maps)
    textures = write_textures(state, outdir / "textures", final,
                              brows_baked=final is not None and res.config.final.features)
    written += textures
    # the OBJs' .mtl names the fitted maps written just above (PNG, relative paths)
    mats = ObjMaterials(m.material_names, m.face_material.numpy(),
                        {t.stem: f"textures/{t.name}" for t in textures if t.suffix == ".png"},
                        colours=material_base_colours(
                            m.material_names, final.maps.iris_rgb if final else None,
                            final.maps.sclera_rgb if final else None))
    for i, v in enumerate(res.views):
        with torch.no_grad():
            verts = state.forward(v).vertices[0].numpy()
        stem = "mesh" if i == 0 else f"mesh_view{i}"
        for ext in (".obj", ".ply"):
            written.append(write_mesh(outdir / f"{stem}{ext}", verts, m.faces.numpy(),
                                      m.uvs.numpy(), m.uv_faces.numpy(), mats))
            if ext == ".obj":
                written.append(outdir / f"{stem}.mtl")
    if final is not None:
        written += write_photo_renders(res, final, outdir)
    written += write_overlays(res, outdir, final, sheet_passes)
    written += write_losses(res, outdir)
    report = {"timings_s": res.timings, "total_s": float(sum(res.timings.values())),
              "failures": res.failures, "config": res.config.to_dict(),
              "stages": [{"name": r.name, "iterations": r.iterations, "seconds": r.seconds,
                          "best_loss": r.best_loss, "failure": r.failure,
                          "mean_iteration_s": float(np.mean(r.per_iteration_s))
                          if r.per_iteration_s else None} for r in res.reports],
              "views": [{"photo": v.photo.name, "notes": v.photo.notes,
                         "faces_found": v.detection.n_faces,
                         "landmark_source": v.detection.source,
                         "landmarks_refined": v.detection.refined,
                         "landmarks_fused": v.detection.fused is not None,
                         "refiner_shift_iod": _refiner_shift(v.detection),
                         # the fit's points against the detected ones (drift: a fit
                         # the photo term pulled off the landmarks)
                         "landmark_residual_iod": landmark_residual_iod(v, fitted[i]),
                         "landmark_points": "embedding" if getattr(v, "embedded", False)
                         else "vertices", "silhouette": v.silhouette_note,
                         "focal": _focal_entry(res.config, v),
                         "pose_deg": _pose_entry(state, v),
                         # "sg" lighting: the lobes fitted, and how init_lobes started them;
                         # colour_cast: the light's rms log-chromaticity on the skin
                         "lighting": ({"mode": v.lighting.mode, **v.lighting.summary(),
                                       "lobe_start": v.lighting_init,
                                       "colour_cast": _colour_cast(v)}
                                      if v.lighting is not None else None)}
                        for i, v in enumerate(res.views)],
              # photometric.balance_albedo: the skin's colour moved from the light to alpha
              "albedo_balance": state.albedo_balance or None,
              "final": final.report if final is not None else None,
              "eyes": getattr(res, "eyes", None),
              "mouth": getattr(res, "mouth", None),
              "landmark_embedding": (state.embedding.meta.get("provenance")
                                     if state.embedding is not None else None),
              "landmark_refiner": _refiner_provenance(res)}
    report.update(extra or {})
    written.append(write_json(outdir / "fit_report.json", report, indent=1))
    written.append(write_json(outdir / "timings.json", {"stages_s": res.timings,
                                                        "total_s": report["total_s"]}, indent=1))
    return written


#: :func:`photo_layer` leaves out the eyes' landmark rings scaled by this (the lids too)
#: and the outer lips' ring scaled by PHOTO_LAYER_LIPS
PHOTO_LAYER_EYES = 1.6
PHOTO_LAYER_LIPS = 1.25


def photo_layer(v, h: int, w: int, soft: float = 0.7) -> np.ndarray | None:
    """(h, w) float in [0, 1]: what of the photo stays in front of the render in
    ``render_over_photo.png`` (``final.photo_hair``): the segmentation's hair, occluders
    (hands, glasses' frames) and clothes (a collar over the neck), the model having no
    hair and no clothes, and below the face (:func:`~hack_render.vision.neck.below_face`)
    or above the brows (:func:`~hack_render.vision.neck.above_brows`) and outside its
    oval all but the view's skin (the neck the bake took), without the eyes and the
    mouth
    (the eyes' rings scaled :data:`PHOTO_LAYER_EYES`, the outer lips' by
    :data:`PHOTO_LAYER_LIPS`), at the render's size,
    their edge softened by a Gaussian of ``soft`` px; None where the view has no
    segmentation."""
    from scipy.ndimage import gaussian_filter
    from skimage.draw import polygon

    masks = [m for m in (v.hair, v.occluder, getattr(v, "clothes", None)) if m is not None]
    if not masks:
        return None
    if v.skin is not None and v.face is not None:
        # below the face or above the brows, outside the face's oval (inside it, what is
        # not skin is an occluder), all but the skin the bake took (the neck's; none in a
        # grey photo): the model's neck and chest over a collar, a hand or the background
        # beside the neck, its bare scalp over hair the segmentation missed or over the
        # background above the head are not the person
        pts, shape = v.detection.points, v.skin.shape
        masks.append((below_face(pts, shape) | above_brows(pts, shape))
                     & ~np.asarray(v.skin, bool) & ~np.asarray(v.face, bool))
    m = np.zeros((h, w), bool)
    for mk in masks:
        m |= mask_at(mk, h, w)
    # never the eyes or the mouth (the segmentation calls a dark iris, dark lips or the
    # gaps between teeth occluders): those are the model's to show
    pts = v.detection.points * (w / v.photo.width)
    m &= ~feature_rings(pts, (h, w), eye_scale=PHOTO_LAYER_EYES)["eyes"]
    lips = pts[48:60]
    lips = lips.mean(0) + PHOTO_LAYER_LIPS * (lips - lips.mean(0))
    rr, cc = polygon(lips[:, 1] - 0.5, lips[:, 0] - 0.5, (h, w))
    m[rr, cc] = False
    return np.clip(gaussian_filter(m.astype(np.float32), soft), 0.0, 1.0)


def write_photo_renders(res: FitResult, final: FinalRenders, outdir: Path) -> list[Path]:
    """``render.png`` (the fit re-rendered with the baked skin at the photo's size, over a
    transparent background; with ``final.hair``, with the photo's hair read as a style of
    the hair layer), ``render_over_photo.png`` (the hairless render over the photo; with
    ``final.photo_hair`` the photo's hair and occluders stay in front: the model has no
    hair, and a fringe over the forehead is the person's, not the model's bare skin), and
    ``occlusion.png`` (the bake's per-pixel weights: 0 where the photo was not used as
    skin, e.g. occluders, clothes, the silhouette's edge), one set per view. A grey photo
    gets grey renders (their luminance): it says nothing of the skin's colour."""
    from skimage.transform import resize

    out = []
    for i, (v, r) in enumerate(zip(res.views, final.renders)):
        sfx = "" if i == 0 else f"_view{i}"
        # render.png: with the photo's hair as the hair layer's style (final.hair);
        # render_over_photo.png: the hairless render under the photo's own hair
        hair = final.hair_renders[i].rgba if final.hair_renders else None
        rgba = hair if hair is not None else r.rgba
        if v.photo.is_grey:
            lum = rgba[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
            rgba = np.concatenate([np.repeat(lum[..., None], 3, -1), rgba[..., 3:]], -1)
        a = np.clip(rgba[..., 3:4], 0.0, 1.0)
        rgb8 = to_srgb8(straight_colour(rgba[..., :3], a[..., 0]), 0.0, "clip")
        img = np.concatenate([rgb8, np.round(a * 255).astype(np.uint8)], -1)
        h, w = rgba.shape[:2]
        photo = v.photo.linear()
        if photo.shape[:2] != (h, w):
            photo = resize(photo, (h, w), order=1, anti_aliasing=True).astype(np.float32)
        bald = r.rgba
        if v.photo.is_grey:
            lum = bald[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
            bald = np.concatenate([np.repeat(lum[..., None], 3, -1), bald[..., 3:]], -1)
        over = bald[..., :3] + (1.0 - np.clip(bald[..., 3:4], 0.0, 1.0)) * photo
        layer = photo_layer(v, h, w) if res.config.final.photo_hair else None
        if layer is not None:
            over = layer[..., None] * photo + (1.0 - layer[..., None]) * over
        over = to_srgb8(over, 0.0, "clip")
        occ = np.round(255 * np.clip(final.baked.pixel_weights[i], 0, 1)).astype(np.uint8)
        for name, arr in ((f"render{sfx}.png", img), (f"render_over_photo{sfx}.png", over),
                          (f"occlusion{sfx}.png", occ)):
            with atomic_path(outdir / name) as tmp:
                Image.fromarray(arr).save(tmp, "PNG")
            out.append(outdir / name)
    return out


def write_textures(state, folder: Path, final: FinalRenders | None = None,
                   brows_baked: bool = False) -> list[Path]:
    """Fitted skin maps: EXR (linear, float) and PNG (sRGB for diffuse, raw otherwise).
    With ``final``: the baked diffuse map at ``final.atlas_height`` (the other maps
    resampled to its size), its ``confidence`` and the model's own ``diffuse_model``;
    ``brows_baked`` (the bake holds the photo's brows: ``final.features``) is written to
    ``skin.json``, so ``render --textures`` draws no brow strands over them."""
    folder.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        maps = {k: (x.detach().numpy() if x is not None else None)
                for k, x in state.maps().items()}
    extra = []
    if final is not None:
        fm = final.maps
        extra = [("diffuse_model", maps["albedo"]),
                 ("confidence", final.baked.confidence[..., None])]
        if final.specular_confidence is not None:
            extra.append(("specular_confidence", final.specular_confidence[..., None]))
        maps = {"albedo": fm.diffuse, "specular": fm.specular, "roughness": fm.roughness,
                "normal": fm.normal}
    out = []
    for name, key in (("diffuse", "albedo"), ("specular", "specular"),
                      ("roughness", "roughness"), ("normal", "normal")) + tuple(
                          (n, n) for n, _ in extra):
        img = maps[key] if key in maps else dict(extra)[key]
        if img is None:
            continue
        img = np.ascontiguousarray(img, np.float32)
        write_exr(folder / f"{name}.exr", img if img.shape[2] > 1 else img[..., 0])
        out.append(folder / f"{name}.exr")
        png = img if name != "normal" else 0.5 * img + 0.5
        write_png(folder / f"{name}.png", png if png.shape[2] > 1 else png[..., 0],
                  srgb=name.startswith("diffuse"))
        out.append(folder / f"{name}.png")
    if final is not None and final.maps.iris_rgb is not None:  # read by --textures

        doc = {**final.iris, "iris_rgb": list(final.maps.iris_rgb),
               "sclera_rgb": None if final.maps.sclera_rgb is None
               else list(final.maps.sclera_rgb), "eye_gloss": final.maps.eye_gloss,
               "derived": "linear Rec.709; the photo over renders of the fit, over the "
                          "iris's and the eye whites' pixels (hack_render/fit/iris.py)"}
        out.append(write_json(folder / IRIS_FILE, doc, indent=1))
    if final is not None:  # read by --textures
        out.append(write_json(folder / SKIN_FILE, {
            "brows_baked": bool(brows_baked),
            "derived": "whether diffuse.exr holds the photo's brows (the fit's final.features)"},
            indent=1))
    if final is not None and final.maps.part_rgb:  # read by --textures
        out.append(write_npz(folder / PARTS_FILE, {
            "derived": np.array("linear Rec.709 per vertex of each part: the photo over "
                                "renders of the fit, at the fitted pose, gaze and jaw "
                                "(hack_render/fit/part_bake.py)"),
            **{k: np.asarray(v, np.float32) for k, v in final.maps.part_rgb.items()}}))
    return out


def _final_render(state, v, passes: int = 16):
    """A render of the view at its last level with the fitted maps: ``passes`` renders
    of the level's spp (4 by default) with their own seeds, averaged (64 spp)."""
    with torch.no_grad():
        maps, verts = level_maps(state, v), state.forward(v).vertices[0]
        img = sum(render_view(v, maps, verts, 12345 + k).numpy() for k in range(passes))
    return img / passes


def _final_in_level(final, i: int, v) -> np.ndarray:
    """View ``i``'s ``render.png`` (the final render: baked skin, denoised or at the final
    spp; premultiplied linear RGBA at the photo's size or below) resampled into the
    view's last level, as that level's own renders are."""
    rgba = final.renders[i].rgba
    lv = v.level
    s = rgba.shape[1] / v.photo.width            # render pixels per photo pixel
    Hr = np.diag([s, s, 1.0]) @ lv.H              # level pixel -> render pixel
    scale = float(np.sqrt(abs(np.linalg.det(Hr[:2, :2]) / Hr[2, 2] ** 2)))
    img = warp_photo(rgba.astype(np.float32), Hr, lv.res, scale, mode="constant")
    if v.photo.is_grey:   # as render.png: a grey photo gets a grey render
        lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
        img[..., :3] = lum[..., None]
    return img


def write_overlays(res: FitResult, outdir: Path, final=None, passes: int = 16) -> list[Path]:
    """Overlay sheet per view: photo, landmarks (detected green, fitted red), render,
    render over photo, error map. With ``final`` (:class:`FinalRenders`) the render
    panels show ``render.png`` (the baked skin, no visible noise); else a render of the
    last photometric level with the fitted maps (``passes`` renders averaged)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = []
    state, cfg = res.state, res.config
    for i, v in enumerate(res.views):
        if v.renderer is None:  # photometric stage off: build a level for the sheet
            setup_level(state, cfg, v, int(cfg.photometric.resolutions[-1]))
        lv = v.level
        img = (_final_in_level(final, i, v) if final is not None
               else _final_render(state, v, passes))
        target = lv.target.numpy()
        photo8 = to_srgb8(target, 0.0, "clip")
        photo8[~on_photo(v.photo.height, v.photo.width, lv.H, lv.res)] = 0  # (not its edge
        # repeated, as the level's target has it: streaks where the crop passes the photo)
        rend8 = to_srgb8(img[..., :3], 0.0, "clip")
        a = img[..., 3:4]
        over = (a * rend8 + (1 - a) * photo8).astype(np.uint8)
        err = np.abs(img[..., :3] - target).mean(-1) * lv.mask.numpy()
        H = np.linalg.inv(lv.H)
        with torch.no_grad():
            verts = state.forward(v).vertices[0]
            fit_px = state.project(v, terms.model_landmarks(state, cfg, v, verts, 1)).numpy()
        def to_v(p, H=H):
            q = np.c_[p, np.ones(len(p))] @ H.T
            return q[:, :2] / q[:, 2:3]
        det_v, fit_v = to_v(v.detection.points), to_v(fit_px)
        fig, ax = plt.subplots(1, 5, figsize=(15, 3.4))
        panels = [(photo8, "photo"), (photo8, "landmarks: detected (g) / fitted (r)"),
                  (rend8, "render" + (" (render.png)" if final is not None else "")),
                  (over, "render over photo"), (err, "|error| (skin mask)")]
        for k, (im, title) in enumerate(panels):
            ax[k].imshow(im, cmap="magma" if im.ndim == 2 else None,
                         extent=(0, im.shape[1], im.shape[0], 0))
            ax[k].set_title(title, fontsize=8)
            ax[k].axis("off")
        ax[1].scatter(det_v[:, 0], det_v[:, 1], s=4, c="lime")
        ax[1].scatter(fit_v[:, 0], fit_v[:, 1], s=4, c="red")
        fig.tight_layout()
        path = outdir / ("overlay.png" if i == 0 else f"overlay_view{i}.png")
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=100)
        plt.close(fig)
        out.append(path)
    return out


def write_losses(res: FitResult, outdir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = {r.name: r.history for r in res.reports}
    p_json = write_json(outdir / "losses.json", data, indent=1)
    n = max(1, len(data))
    fig, ax = plt.subplots(1, n, figsize=(4 * n, 3))
    ax = np.atleast_1d(ax)
    for k, (name, hist) in enumerate(data.items()):
        for term, vals in hist.items():
            if vals and max(vals) > 0:
                ax[k].semilogy(vals, label=term, lw=1.5 if term == "total" else 0.8)
        ax[k].set_title(name, fontsize=9)
        ax[k].set_xlabel("iteration")
        ax[k].legend(fontsize=6)
    fig.tight_layout()
    p_png = outdir / "losses.png"
    with atomic_path(p_png) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return [p_json, p_png]
