"""Shared test helpers: a small synthetic HACK model with every optional component (fast
exact tests), landmark views of the model, and synthetic photo targets for the fitter."""

from __future__ import annotations

import numpy as np

from hack_render.geometry.skeleton import JOINT_NAMES, PARENTS, rotation_limits_deg


def synthetic_arrays(seed: int = 0, nx: int = 6, ny: int = 12) -> dict[str, np.ndarray]:
    """A cylinder-like 'neck' grid of nx * ny vertices along Y with random components."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0, 2 * np.pi, nx, endpoint=False)
    ys = np.linspace(-0.15, 0.0, ny)
    v = np.array([[0.05 * np.sin(a), y, 0.05 * np.cos(a)] for y in ys for a in ang])
    n = len(v)
    uv = np.array([[a / (2 * np.pi), (y + 0.15) / 0.15] for y in ys for a in ang])
    faces = []
    for j in range(ny - 1):
        for i in range(nx):
            a, b = j * nx + i, j * nx + (i + 1) % nx
            c, d = a + nx, b + nx
            faces += [[a, b, d], [a, d, c]]
    faces = np.array(faces, dtype=np.int32)
    s, e, k, c, m, h = 5, 4, 8, 3, n // 2, 16
    comps = np.linalg.qr(rng.standard_normal((3 * n, s)))[0].T.reshape(s, n, 3)
    joints_y = np.linspace(-0.13, -0.01, k)
    reg = np.zeros((k, n))
    for jj, y in enumerate(joints_y):
        ring = np.argsort(np.abs(v[:, 1] - y))[: 2 * nx]
        reg[jj, ring] = 1.0 / len(ring)
    w = rng.random((n, k + 1)) ** 4
    w /= w.sum(1, keepdims=True)
    sub = np.sort(rng.choice(n, m, replace=False)).astype(np.int32)
    arrays = {
        "template_vertices": v.astype(np.float32), "faces": faces, "uvs": uv.astype(np.float32),
        "uv_faces": faces.copy(), "face_material": np.zeros(len(faces), np.int16),
        "material_names": np.array(["M_Face"]), "vertex_uv": uv.astype(np.float32),
        "vertex_group": np.zeros(n, np.int16), "group_names": np.array(["face"]),
        "vertex_region": np.zeros(n, np.int16), "region_names": np.array(["neck"]),
        "landmark_indices": rng.choice(n, 68).astype(np.int32),
        "shape_components": comps.astype(np.float32),
        "shape_std": np.linspace(0.02, 0.005, s).astype(np.float32),
        "expression_basis": (0.005 * rng.standard_normal((e, n, 3))).astype(np.float32),
        "expression_names": np.array([f"shape{i}" for i in range(e)]),
        "au_names": np.array(["AU1", "AU2"]),
        "au_matrix": np.array([[1, 1, 0, 0], [0, 0, 1, 0]], np.float32),
        "joint_names": np.array(JOINT_NAMES), "joint_parents": np.array(PARENTS, np.int32),
        "joint_regressor": reg.astype(np.float32), "skinning_weights": w.astype(np.float32),
        "rotation_limits_deg": rotation_limits_deg().numpy().astype(np.float32),
        "pose_basis": (0.002 * rng.standard_normal((9 * k, n, 3))).astype(np.float32),
        "larynx_maps": (0.003 * rng.standard_normal((2, 3, 16, 16))).astype(np.float32),
        "larynx_uv_bounds": np.array([0.0, 0.2, 1.0, 0.9], np.float32),
        "larynx_vertices": sub, "larynx_coef_matrix": rng.standard_normal((2, s)).astype(np.float32),
        "larynx_coef_offset": np.array([1.0, 0.5], np.float32),
        "larynx_v_per_metre": np.asarray(5.0, np.float32),
    }
    for prefix, d in (("expr", e), ("pose", 9 * k)):
        arrays.update({
            f"{prefix}_pca_vertices": sub, f"{prefix}_pca_mean": (0.001 * rng.standard_normal((d, m, 3))).astype(np.float32),
            f"{prefix}_pca_components": (0.001 * rng.standard_normal((c, d, m, 3))).astype(np.float32),
            f"{prefix}_mlp_w0": (0.5 * rng.standard_normal((h, s))).astype(np.float32),
            f"{prefix}_mlp_b0": (0.1 * rng.standard_normal(h)).astype(np.float32),
            f"{prefix}_mlp_w1": (0.3 * rng.standard_normal((h, h))).astype(np.float32),
            f"{prefix}_mlp_b1": (0.1 * rng.standard_normal(h)).astype(np.float32),
            f"{prefix}_mlp_w2": (0.3 * rng.standard_normal((c, h))).astype(np.float32),
            f"{prefix}_mlp_b2": (0.1 * rng.standard_normal(c)).astype(np.float32),
        })
    return arrays


def landmark_view(model, beta=None, psi=None, angles_deg=(5.0, 0.0, 0.0), res: int = 256,
                  name: str = "view", mask: bool = False):
    """A photo-less view for the landmark stages: the true landmark vertices of
    ``model(beta, psi)`` with the head turned by ``angles_deg`` (pitch, yaw, roll, shared
    over the joints by the anatomical prior), projected by a frontal camera (110 mm
    equivalent, 1 m) onto a blank ``res`` px photo. Returns (Photo, Detection), and with
    ``mask`` also the true person mask: the skin triangles (face, scalp, neck, chest)
    rasterised at pixel centres."""
    import torch

    from hack_render.fit.fitter import R0
    from hack_render.fit.photo import Photo
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.vision.detection import Detection
    from scenes.cameras import Camera

    ang = torch.deg2rad(torch.tensor([float(a) for a in angles_deg]))
    with torch.no_grad():
        out = model(beta=beta, psi=psi, theta=distribute_head_rotation(ang)[None])
    f = 50.0 / 36.0 * res * 2.2
    K = np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1.0]])
    cam = Camera(K, R0.numpy().astype(np.float64), np.array([0.0, -0.03, 1.0]), res, res, "v")
    lm = cam.project(out.landmarks[0].numpy().astype(np.float64))
    photo = Photo(np.full((res, res, 3), 0.5, np.float32), name)
    det = Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth")
    if not mask:
        return photo, det
    from skimage.draw import polygon

    skin = [i for i, r in enumerate(model.region_names)
            if r in ("face", "scalp_and_ears", "neck", "chest_and_shoulders")]
    faces = model.faces.numpy()
    keep = np.isin(model.vertex_region.numpy()[faces], skin).all(1)
    uv = cam.project(out.vertices[0].numpy().astype(np.float64))
    m = np.zeros((res, res), bool)
    for tri in uv[faces[keep]]:
        rr, cc = polygon(tri[:, 1] - 0.5, tri[:, 0] - 0.5, (res, res))
        m[rr, cc] = True
    return photo, det, m


def synthetic_target(model, res=96, rig=None):
    """A render of known parameters (lit by ``rig``, default the ``light_stage`` preset) of
    the full model, by the path integrator: returns the photo (res, res, 3) linear RGB, its 68 landmarks (68, 2) in
    pixels and the truth (beta, head angles, vertices). Needs Mitsuba."""
    import torch

    from hack_render.fit.fitter import R0
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes.cameras import Camera
    from scenes.lights import preset

    g = torch.Generator().manual_seed(7)
    beta = torch.randn(1, 20, generator=g) * 1.0
    angles = torch.deg2rad(torch.tensor([8.0, 15.0, -4.0]))
    theta = distribute_head_rotation(angles)[None]
    with torch.no_grad():
        out = model(beta=beta, theta=theta)
    f = 50.0 / 36.0 * res * 2.2
    K = np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1.0]])
    t = np.array([0.0, -0.03, 1.0])
    cam = Camera(K, R0.numpy().astype(np.float64), t, res, res, "synthetic")
    # the path integrator: the fitter's prb (the same light transport) is what has to
    # reproduce this photo; volpath lights the skin under the lash cards that path's
    # shadow rays do not reach
    head = HeadScene(Topology.from_model(model), out.vertices[0].numpy(),
                     preset("light_stage") if rig is None else rig,
                     cam, RenderSettings(res, res, 16, 4, 0, integrator="path"))
    img = head.render()[..., :3]
    lm = cam.project(out.landmarks[0].numpy().astype(np.float64))
    return img, lm, {"beta": beta, "angles": angles, "vertices": out.vertices[0]}


def appearance_photo(model, app, alpha, res: int = 64, light: str = "light_stage",
                     spp: int = 32, angles_deg=(5.0, 15.0, 0.0), seed: int = 7):
    """A photo of known skin: ``model`` with a seeded identity (beta ~ N(0, I), 20
    components), the head turned by ``angles_deg``, the skin maps ``app.maps(alpha)``, lit
    by the ``light`` preset (default ``light_stage``: uniform grey light of unit
    radiance), rendered by the path tracer (``spp``, depth 4) through the frontal camera of
    :func:`landmark_view` over a grey backdrop. Returns (Photo (sRGB), Detection of the
    true landmark vertices, the truth: beta, alpha, vertices). Needs Mitsuba."""
    import colour
    import torch

    from hack_render.fit.fitter import R0
    from hack_render.fit.photo import Photo
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render.materials import SkinMaps
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.vision.detection import Detection
    from scenes.cameras import Camera
    from scenes.lights import preset

    alpha = torch.as_tensor(alpha, dtype=torch.float32).reshape(1, -1)
    beta = torch.randn(1, 20, generator=torch.Generator().manual_seed(seed))
    ang = torch.deg2rad(torch.tensor([float(a) for a in angles_deg]))
    with torch.no_grad():
        out = model(beta=beta, theta=distribute_head_rotation(ang)[None])
        maps = app.maps(alpha)
    f = 50.0 / 36.0 * res * 2.2
    K = np.array([[f, 0, res / 2], [0, f, res / 2], [0, 0, 1.0]])
    cam = Camera(K, R0.numpy().astype(np.float64), np.array([0.0, -0.03, 1.0]), res, res, "v")
    head = HeadScene(Topology.from_model(model), out.vertices[0].numpy(), preset(light), cam,
                     RenderSettings(res, res, spp, 4, 0), SkinMaps.from_appearance(maps))
    rgba = head.render(backdrop=False)
    rgb = rgba[..., :3] + (1.0 - rgba[..., 3:4]) * 0.5
    srgb = np.clip(colour.cctf_encoding(np.clip(rgb, 0, 1), function="sRGB"), 0, 1)
    lm = cam.project(out.landmarks[0].numpy().astype(np.float64))
    return (Photo(srgb.astype(np.float32), "skin"),
            Detection(lm, (*lm.min(0), *lm.max(0)), 1, "truth"),
            {"beta": beta, "alpha": alpha, "vertices": out.vertices[0]})


def texture_fitter(model, yaw=30.0, res=160):
    """A fitter whose state is the truth of a synthetic photo: the head turned by ``yaw``
    (one cheek away from the camera), lit by a uniform environment, the photo rendered
    from the state itself with a patterned diffuse map the appearance model lacks."""
    import dataclasses

    import torch

    from hack_render.fit import texture
    from hack_render.fit.config import load_config
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.lighting import Lighting

    photo, det = landmark_view(model, angles_deg=(0.0, yaw, 0.0), res=res)
    # silhouette off: the blank photo holds no person to segment (the views come out the
    # same, without the segmentation's ~10 s per fitter); the parts' bake off: its two
    # re-renders per final stage are tests/test_fit_part_bake.py's
    cfg = load_config(None, {"final": {"spp": 32, "atlas_height": 256, "max_side": res,
                                       "part_bake": 0},
                             "silhouette": {"mode": "off"}})
    f = Fitter([photo], [det], cfg, model=model, progress=False)
    v = f.state.views[0]
    with torch.no_grad():
        # the truth pose: landmark_view's head rotation, shared by the anatomical prior
        v.head_angles.copy_(torch.deg2rad(torch.tensor([0.0, yaw, 0.0])))
        v.transl.copy_(torch.tensor([0.0, -0.03, 1.0]))
        v.log_focal.fill_(float(np.log(50.0 / 36.0 * res * 2.2)))
    v.lighting = Lighting("env", 8)
    with torch.no_grad():
        v.lighting.log_texels.fill_(0.0)  # uniform unit radiance
    H = 256
    prior = texture._skin_maps(f.state, H)
    yy, xx = np.mgrid[0:H, 0:2 * H]
    pat = 1.0 + 0.3 * np.sign(np.sin(xx / 5.0) * np.sin(yy / 5.0))
    truth = np.clip(prior.diffuse * pat[..., None], 0, 1).astype(np.float32)
    true_maps = dataclasses.replace(prior, diffuse=truth)
    return f, cfg, true_maps, prior.diffuse, truth


def photo_of(rgb):
    """A fit Photo of linear RGB ``rgb`` (sRGB-encoded, clipped to 0..1)."""
    import colour

    from hack_render.fit.photo import Photo

    return Photo(np.asarray(colour.cctf_encoding(np.clip(rgb, 0, 1), function="sRGB"),
                            np.float32), "syn")


def frontal_truth_photo(model):
    """A frontal fitter whose photo is the render of its true maps (over grey): (fitter,
    cfg, that render, its height and width, the atlas's height)."""
    from hack_render.fit import texture

    fitter, cfg, true_maps, _, _ = texture_fitter(model, yaw=0.0)
    v = fitter.state.views[0]
    pr = texture.render_at_photo(fitter.state, cfg, v, maps=true_maps)
    v.photo = photo_of(pr.rgba[..., :3] + (1 - pr.rgba[..., 3:4]) * 0.5)
    h, w = pr.rgba.shape[:2]
    return fitter, cfg, pr, h, w, cfg.final.atlas_height
