"""The face mesh's eye points on the model's own renders (fit/eyes.py MESH_OFFSET; a
calibration, not a test).

    python bench/eye_mesh_offsets.py --res 768           # the neutral eye: the offsets
    python bench/eye_mesh_offsets.py --res 768 --shapes  # and the lids half closed / open

Renders the neutral model, frontal at 1 m (110 mm equivalent), lit by a uniform white
environment, at ``--res`` px (final stage's renderer, 16 spp), runs MediaPipe's face mesh
with its iris landmarks on it and prints per eye (the 68's order) the model's measures
(``fit/eyes.py``: the landmark embedding's six eye points and the eyeball's front) and the
face mesh's, and their difference (model - mesh): MESH_OFFSET.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=768)
    ap.add_argument("--shapes", action="store_true",
                    help="also the lids half closed (blink 0.4), squinting (0.6), wide (0.6)")
    a = ap.parse_args()
    warnings.filterwarnings("ignore")
    import colour
    import torch
    from synthetic import landmark_view

    from hack_render.fit import eyes as fit_eyes
    from hack_render.fit import face_mesh, gaze, texture
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.lighting import Lighting
    from hack_render.geometry import load_default_model

    model = load_default_model()
    photo, det = landmark_view(model, angles_deg=(0.0, 0.0, 0.0), res=a.res)
    cfg = load_config(None, {"final": {"spp": 16, "max_side": a.res},
                             "silhouette": {"mode": "off"}})
    f = Fitter([photo], [det], cfg, model=model, progress=False)
    st, v = f.state, f.state.views[0]
    with torch.no_grad():
        v.transl.copy_(torch.tensor([0.0, -0.03, 1.0]))
        v.log_focal.fill_(float(np.log(50.0 / 36.0 * a.res * 2.2)))
    v.lighting = Lighting("env", 8)
    with torch.no_grad():
        v.lighting.log_texels.fill_(0.0)
    names = [str(n) for n in model.expression_names]
    settings = [{}]
    if a.shapes:
        settings += [{"eyeBlink_L": 0.4, "eyeBlink_R": 0.4},
                     {"eyeSquint_L": 0.6, "eyeSquint_R": 0.6},
                     {"eyeWide_L": 0.6, "eyeWide_R": 0.6}]
    rig = gaze.eye_rig(model)
    for setting in settings:
        with torch.no_grad():
            st.psi.zero_()
            for k, x in setting.items():
                st.psi[0, names.index(k)] = x
        t0 = time.time()
        r = texture.render_at_photo(st, cfg, v, max_side=a.res)
        rgb = np.clip(r.rgba[..., :3] + (1 - r.rgba[..., 3:4]) * 0.5, 0, 1)
        u8 = (np.clip(colour.cctf_encoding(rgb), 0, 1) * 255).round().astype(np.uint8)
        mp = face_mesh.iris_landmarks(u8, det.points)
        with torch.no_grad():
            mm = [m.numpy() for m in fit_eyes._model_measures(st, v, st.psi, None, rig)]
        print(setting or "neutral", f"({time.time() - t0:.0f} s)")
        if mp is None:
            print("  the face mesh found no face")
            continue
        pm = fit_eyes._photo_targets(fit_eyes.photo_eye_points(mp))
        for k in range(2):
            print(f"  eye {k}: model {np.round(mm[k], 3)} mesh {np.round(pm[k], 3)} "
                  f"model - mesh {np.round(mm[k] - pm[k], 3)}")


if __name__ == "__main__":
    main()
