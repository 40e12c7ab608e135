"""End-to-end fits: a synthetic round trip (render known parameters, fit from the image and
its landmarks, parameters and vertices move toward the truth) and the astronaut photo
through the `hack-render fit` command at tiny settings. Time is measured in
bench/bench_fit.py, never asserted here."""

import json
import warnings

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")

from synthetic import synthetic_target  # after the skip: it renders


@pytest.mark.slow
def test_01_synthetic_round_trip_moves_toward_truth():
    """Opt-in (--runslow): the whole ``Fitter.run`` runs in test_02 (the astronaut CLI,
    every stage to its outputs); the landmark stages recovering a known shape and pose
    in test_fit_views_texel.py test_01 and test_fit_views.py test_01, the photometric
    stage recovering a known skin in test_fit_alpha.py test_02."""
    import colour

    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.photo import Photo
    from hack_render.geometry import load_default_model
    from hack_render.vision.detection import Detection

    torch.set_num_threads(1)
    model = load_default_model()
    img, lm, truth = synthetic_target(model)
    srgb = np.clip(colour.cctf_encoding(np.clip(img, 0, 1), function="sRGB"), 0, 1)
    photo = Photo(srgb.astype(np.float32), "synthetic")
    det = Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth")
    cfg = load_config(None, {"camera": {"iterations": 80}, "shape": {"iterations": 80,
                                                                     "n_beta": 20},
                             "photometric": {"resolutions": [32], "iterations": [5], "spp": 2,
                                             "n_alpha": 4, "torch_threads": 2}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fitter = Fitter([photo], [det], cfg, model=model, progress=False)
        face = slice(0, 9409)
        v = fitter.state.views[0]

        def face_error():
            with torch.no_grad():
                x = fitter.forward(v).vertices[0][face]
            y = truth["vertices"][face]
            return float(torch.linalg.vector_norm((x - x.mean(0)) - (y - y.mean(0)), dim=1).mean())

        e0 = face_error()
        fitter.run()
    e1 = face_error()
    assert torch.get_num_threads() == 1  # the stage's own thread count is undone after it
    # the head's orientation to the camera: the torso's turn plus the neck's (to first
    # order); a head turn on a frontal body and a body turned whole look alike in the
    # landmarks, and the fit gives the turn to the torso (camera.rotate "torso")
    ang = torch.rad2deg(v.head_angles.detach() + v.global_orient.detach()
                        - truth["angles"]).abs()
    with torch.no_grad():
        pred = fitter.project(v, fitter.forward(v).landmarks[0]).numpy()
    nme = np.linalg.norm(pred - lm, axis=1).mean() / np.linalg.norm(lm[36] - lm[45])
    assert e1 < 0.7 * e0, (e0, e1)  # vertices move toward the truth
    assert float(ang[1]) < 5.0, ang  # yaw recovered within 5 degrees (from 15)
    assert nme < 0.035  # 3.2 % since the skeleton moved behind the pharynx (3 % before)


def test_02_astronaut_cli_end_to_end(tmp_path, cli_in_process):
    import imageio.v3 as iio
    from skimage import data

    from hack_render.geometry.params import load_params

    iio.imwrite(tmp_path / "astronaut.png", data.astronaut())
    from hack_render.fit.config import tiny_overrides

    (tmp_path / "tiny.json").write_text(json.dumps(tiny_overrides()))
    out = tmp_path / "fit"
    r = cli_in_process("fit", tmp_path / "astronaut.png", "-o", out, "--config",
                       tmp_path / "tiny.json", "--quiet")
    code, err = r.returncode, r.stderr
    assert code == 0, err[-2000:]
    assert "2 faces found; fitting the largest" in err
    assert "the fitted landmarks lie" not in err   # a fit near its points: no warning
    for name in ("params.json", "params.npz", "mesh.obj", "mesh.ply", "textures/diffuse.exr",
                 "textures/diffuse.png", "overlay.png", "losses.png", "losses.json",
                 "timings.json", "cameras.json", "render.png", "render_over_photo.png",
                 "occlusion.png", "textures/iris.json", "textures/parts.npz",
                 "textures/skin.json"):
        assert (out / name).is_file(), name
    # the bake holds the photo's brows (final.features, on by default): --textures knows
    assert json.loads((out / "textures" / "skin.json").read_text())["brows_baked"] is True
    p = load_params(out / "params.json")
    assert len(p["beta"]) == 20 and np.asarray(p["theta"]).shape == (8, 3)
    npz = np.load(out / "params.npz")
    K, t = npz["view0_K"], npz["view0_t"]
    report = json.loads((out / "fit_report.json").read_text())
    # the final stage (fit/final.py) runs inside the fit, timed as "final"
    assert report["timings_s"]["final"] > 0 and report["final"]["iris"]["source"]
    # the eyes' fronts baked from the photo (final.part_bake, on by default) and written
    # beside the skin maps for --textures
    assert report["final"]["part_bake"]["iris"]["seen_vertices"] > 0
    # then solved together (final.part_solve, 3 steps)
    solve = report["final"]["part_bake"]["solve"]
    assert len(solve["steps"]) == 3 and all(s["pixels"] > 50 for s in solve["steps"])
    from hack_render.render.skin_maps import read_texture_folder

    assert read_texture_folder(out / "textures").part_rgb["iris"].shape == (
        report["final"]["part_bake"]["iris"]["vertices"], 3)
    # render_over_photo.png keeps the photo's hair in front (final.photo_hair): the
    # fringe over her forehead is the photo's, render.png the model alone
    over = iio.imread(out / "render_over_photo.png")[..., :3].astype(float)
    rgba = iio.imread(out / "render.png")
    photo = np.asarray(iio.imread(tmp_path / "astronaut.png"), float)
    from skimage.transform import resize

    photo = resize(photo, over.shape[:2], preserve_range=True, anti_aliasing=True)
    fringe = (rgba[..., 3] > 250) & (np.abs(over - photo).mean(-1) < 2)
    assert fringe.sum() > 20, fringe.sum()
    # dlib's points went through the landmark refiner; both sets are written
    assert report["views"][0]["landmarks_refined"] is True
    assert report["landmark_refiner"].startswith("derived")
    assert 0.0 < report["views"][0]["refiner_shift_iod"] < 0.1
    assert npz["view0_landmarks_dlib"].shape == (68, 2)
    focal = report["views"][0]["focal"]  # a PNG without EXIF: the 85 mm prior
    assert focal["source"] == "prior" and focal["prior_mm"] == pytest.approx(85.0)
    assert focal["fitted_mm"] == pytest.approx(K[0, 0] / 512 * 36, rel=1e-4)
    # the default "sg" lighting: one lobe, started by init_lobes, which lowered the residual
    light = report["views"][0]["lighting"]
    assert light["mode"] == "sg" and len(light["lobe_direction"]) == 1
    start = light["lobe_start"][0]
    assert start["residual_after"] < start["residual_before"]
    assert np.allclose(npz["view0_lobe_direction"], light["lobe_direction"], atol=1e-6)
    losses = json.loads((out / "losses.json").read_text())
    assert losses["shape"]["landmarks"][-1] < losses["camera"]["landmarks"][0]
    # the fitted landmarks agree with the detector (normalised mean error)
    from hack_render.fit.fitter import R0
    from hack_render.fit.landmark_embedding import load_default
    from hack_render.geometry import load_default_model
    from hack_render.geometry.params import model_inputs

    model = load_default_model()
    emb = load_default(model)  # what dlib's points are fitted to (README: embedding)
    with torch.no_grad():
        out_ = model(**model_inputs(model, p))
        lm3 = (emb.points(out_.vertices[0]) if emb is not None else out_.landmarks[0]).numpy()
    cam = lm3 @ R0.numpy().T + t
    px = (cam[:, :2] / cam[:, 2:3]) * K[0, 0] + K[:2, 2]
    det = npz["view0_landmarks_detected"]
    nme = np.linalg.norm(px[17:] - det[17:], axis=1).mean() / np.linalg.norm(det[36] - det[45])
    assert nme < 0.05
    # params.npz carries the fitted points, the report their distance to the detected ones
    idx = [8] + list(range(17, 68))
    assert np.abs(npz["view0_landmarks_fitted"][idx] - px[idx]).max() < 0.1
    own = np.linalg.norm(px[idx] - det[idx], axis=1).mean() / np.linalg.norm(det[36] - det[45])
    assert report["views"][0]["landmark_residual_iod"] == pytest.approx(own, abs=3e-4)
    # the fit re-renders through `hack-render render --params`
    r = cli_in_process("render", "--params", out / "params.json", "-o",
                       tmp_path / "re.png", "--resolution", "32", "--spp", "1")
    code, err = r.returncode, r.stderr
    assert code == 0, err[-2000:]
