"""Clips with known parameters, for the tracker's accuracy tests and benchmark: the
default model rendered by the project's renderer, frame by frame, with neck motion
(whole-head rotations shared over the 8 joints), expressions (a jaw opening, a smile, a
brow raise), a swallow (the packaged averaged tau curve) and the key light turning.

Everything here is procedural: the identity and skin come from seeds (``appearance``'s
procedural subjects), the motion from smooth curves. The truth file says so.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from tqdm import tqdm

from hack_render.fit.camera import R0, SENSOR_MM
from hack_render.fit.landmark_embedding import load_default
from hack_render.geometry import load_default_model
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.io.image import to_srgb8
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from hack_render.render.skin_maps import skin_maps
from hack_render.render.turntable import swallow_tau
from hack_render.track.rig import landmark_points
from scenes.cameras import Camera
from scenes.lights import preset

#: Motion amplitudes of a clip (degrees; flexion, axial, lateral)
HEAD_AMPLITUDE_DEG = (12.0, 30.0, 8.0)


def clip_truth(model, frames: int, fps: float, seed: int = 0, swallow: bool = True,
               expressions: bool = True) -> dict:
    """Per-frame truth: head angles ``h`` (T, 3) radians, ``theta`` (T, 8, 3), ``psi``
    (T, E), ``tau`` (T,) metres, the identity ``beta`` (1, 20) and the light's rotation
    (T,) degrees."""
    import torch

    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    dur = max(frames / fps, 1e-6)
    ph = rng.uniform(0, 2 * math.pi, 3)
    amp = np.deg2rad(HEAD_AMPLITUDE_DEG)
    # about one and a half slow cycles over the clip, whatever its length
    w = 2 * math.pi * np.array([1.0, 1.5, 0.75]) / dur
    h = amp * np.sin(w * t[:, None] + ph)
    E = model.num_expressions
    psi = np.zeros((frames, E))
    names = list(model.expression_names)
    u = t / dur
    if expressions:
        def bump(c, width):
            return np.exp(-0.5 * ((u - c) / width) ** 2)
        psi[:, names.index("jawOpen")] = 0.7 * bump(0.3, 0.08)
        for n in ("mouthSmile_L", "mouthSmile_R"):
            psi[:, names.index(n)] = 0.8 * bump(0.65, 0.1)
        psi[:, names.index("browInnerUp_L")] = 0.6 * bump(0.85, 0.06)
        psi[:, names.index("browInnerUp_R")] = 0.6 * bump(0.85, 0.06)
    tau = np.array([swallow_tau(x) for x in u]) if swallow else np.zeros(frames)
    g = torch.Generator().manual_seed(1000 + seed)
    beta = torch.randn(1, 20, generator=g)
    theta = distribute_head_rotation(torch.as_tensor(h), clamp=False).numpy()
    light = 40.0 * np.sin(2 * math.pi * u)
    return {"h": h, "theta": theta, "psi": psi, "tau": tau, "beta": beta.numpy(),
            "light_deg": light, "fps": float(fps)}


def render_clip(outdir: str | Path, frames: int = 48, fps: float = 24.0, size=(320, 240),
                seed: int = 0, spp: int = 16, focal_mm: float = 60.0, progress: bool = False,
                swallow: bool = True, expressions: bool = True) -> dict:
    """Render a clip into ``outdir/frames/frame_0000.png ...`` and write
    ``outdir/truth.npz`` (the per-frame parameters, the true 2-D landmarks of the
    calibrated embedding and the camera). Returns the truth."""
    import torch

    out = Path(outdir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    model = load_default_model()
    truth = clip_truth(model, frames, fps, seed, swallow, expressions)
    w, h = size
    f = focal_mm / SENSOR_MM * max(w, h)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    cam_t = np.array([0.0, -0.04, 0.75])
    cam = Camera(K, R0.numpy().astype(np.float64), cam_t, w, h, "clip")
    beta = torch.as_tensor(truth["beta"], dtype=torch.float32)
    with torch.no_grad():
        o = model(beta=beta.expand(frames, -1), psi=torch.as_tensor(truth["psi"]).float(),
                  theta=torch.as_tensor(truth["theta"]).float(),
                  tau=torch.as_tensor(truth["tau"]).float())
    verts = o.vertices.numpy()
    emb = load_default(model)
    lm = landmark_points(o.vertices.double(), emb, model).numpy()
    lm2d = np.stack([cam.project(x) for x in lm])
    head = HeadScene(Topology.from_model(model), verts[0], preset("studio"), cam,
                     RenderSettings(w, h, spp, 6, seed), skin_maps(seed=seed))
    for i in tqdm(range(frames), desc="clip", disable=not progress, leave=False):
        head.set_vertices(verts[i], update=False)
        head.set_light_rotation(float(truth["light_deg"][i]))
        img = head.render(seed=seed * 100003 + i)
        iio.imwrite(out / "frames" / f"frame_{i:04d}.png", to_srgb8(img[..., :3], 0.0, "aces"))
    meta = {"provenance": "procedural: the default model rendered by hack_render.track."
                          "synthetic.render_clip (identity, skin and motion from seeds)",
            "seed": seed, "frames": frames, "fps": fps, "size": [w, h], "spp": spp}
    np.savez(out / "truth.npz", landmarks=lm2d, K=K, cam_t=cam_t, meta=json.dumps(meta),
             **{k: v for k, v in truth.items() if k != "fps"}, fps=fps)
    truth.update(landmarks=lm2d, K=K, cam_t=cam_t)
    return truth
