"""Stage 4 (and 5): photometric refinement through Mitsuba, coarse to fine.

Per view and resolution level: a virtual camera looking at the face (the fitted camera
rotated by Rv; same centre), the photo resampled into it through the homography
K' Rv K^-1 after an anti-aliasing blur, a skin mask (the landmark face polygon without
eyes and mouth opening, intersected with the rendered face region, eroded), and a
:class:`~hack_render.render.bridge.DiffRenderer` over a scene lit only by the learnable
environment. The loss is a Charbonnier (robust L1) over the masked linear-RGB pixels
plus the landmark term and the priors, among them a grey light's (the skin's colour and
the light's are one ambiguity: :func:`balance_albedo`). Stage 5 adds a per-texel albedo delta with
smoothness (neighbour differences), symmetry (mirror-vertex pairs in UV) and magnitude
penalties.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from hack_render.fit import terms
from hack_render.fit.config import FitConfig
from hack_render.fit.lighting import Lighting, candidate_directions
from hack_render.fit.robust import charbonnier
from hack_render.fit.stages import StageLog, StageReport
from hack_render.fit.state import FitState, Level, View
from hack_render.fit.virtual_view import face_mask, virtual_camera, warp_photo
from hack_render.geometry.larynx import larynx_limit_penalty
from hack_render.render.bridge import DiffRenderer
from hack_render.render.materials import SkinMaps
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from scenes.lights import LightRig

#: Rec.709 luminance of linear RGB (a grey photo's term compares luminance only)
LUMA = torch.tensor([0.2126, 0.7152, 0.0722])
#: the differentiable renderer's integrator (Mitsuba prb: direct light with shadows)
INTEGRATOR = "prb"
#: the photo term's skin mask eroded by this many pixels at each level
MASK_ERODE_PX = 1
#: the photo term's robust (Charbonnier) scale, linear RGB
CHARBONNIER_EPS = 0.01
#: render each level with the coarsest mip of the skin maps that still has a texel per
#: pixel (:func:`level_map_height`: 128 rows at 128 px); the torch maps' forward and
#: backward cost falls with the texel count (CHANGELOG.md, the bridge's overhead)
COARSE_MAPS = True
#: refine beta, psi, theta, eta and tau in this stage (else lighting and alpha only, the
#: geometry as the landmark stages left it)
REFINE_GEOMETRY = True
#: Adam steps of alpha (the constant albedo's, without an appearance model, 0.2 x)
LR_ALPHA = 0.05
#: the expressions' step relative to photometric.lr_geometry; 0 holds them where the
#: landmark stages left them (random-preset benchmark: median 1.73 vs 1.71 mm, mean 1.66
#: vs 1.69 mm on neutral subjects; CHANGELOG.md)
PSI_LR_SCALE = 1.0
#: alpha's N(0, I) prior (with photometric.light_cast_sigma, the light's colour prior:
#: :func:`balance_albedo`)
W_ALPHA = 1e-3
#: start the stage at the two priors' optimum along the skin-light colour ambiguity, which
#: Adam's noisy steps barely move along (:func:`balance_albedo`)
BALANCE_ALBEDO = True
#: the silhouette term's scale in this stage (the shape stage's weights times this)
W_SILHOUETTE = 0.001
#: the texel stage's magnitude penalty on the per-texel albedo delta
TEXEL_W_MAGNITUDE = 0.1


def level_map_height(state: FitState, cfg: FitConfig, res: int) -> int | None:
    """Atlas height for a level of ``res`` px: with :data:`COARSE_MAPS`, the
    coarsest mip of the appearance model (its height / 2^k, at least 32) with at least
    ``res`` rows, so a texel never spans more than a pixel of the face (the face takes
    about half of the level's width, the face tile's whole height); None: full size."""
    app = state.appearance
    if app is None or not COARSE_MAPS:
        return None
    h = app.height
    while h % 2 == 0 and h // 2 >= max(int(res), 32):
        h //= 2
    return None if h == app.height else h


def level_maps(state: FitState, view: View, with_delta: bool = True) -> dict:
    """The skin maps at the atlas size of the view's current level (see
    :func:`level_map_height`)."""
    return state.maps(with_delta, height=view.level.map_height)


def setup_level(state: FitState, cfg: FitConfig, view: View, res: int,
                full_maps: bool = False) -> Level:
    """Build the view's scene, renderer, target and masks for one resolution
    (``full_maps``: the appearance model's own atlas size, e.g. for per-texel work)."""
    pc = cfg.photometric
    cam, H, scale = virtual_camera(view, res)
    target = warp_photo(view.photo.linear(), H, res, scale)
    Hi = np.linalg.inv(H)
    p = np.c_[view.detection.points, np.ones(68)] @ Hi.T
    pts_v = p[:, :2] / p[:, 2:3]
    if view.lighting is None:
        view.lighting = Lighting(pc.lighting, pc.sg_height if pc.lighting == "sg"
                                 else pc.env_height, pc.lobes)
    map_height = None if full_maps else level_map_height(state, cfg, res)
    with torch.no_grad():
        verts = state.forward(view).vertices[0]
        maps = {k: (x.detach().numpy() if x is not None else None)
                for k, x in state.maps(height=map_height).items()}
        env = view.lighting.env_map().numpy()
    sm = SkinMaps(maps["albedo"], maps["specular"], maps["roughness"], maps["normal"])
    rig = LightRig(name="fit", env_map=env.astype(np.float32))
    head = HeadScene(Topology.from_model(state.model), verts.numpy(), rig, cam,
                     RenderSettings(res, res, pc.spp, 8, cfg.seed), sm)
    renderer = DiffRenderer(head, INTEGRATOR, max_depth=2, spp=pc.spp)
    photo_mask = face_mask(pts_v, res)
    if pc.occluders and view.occluder is not None:  # hair, hands: not the model's to explain
        occ = warp_photo(view.occluder.astype(np.float32)[..., None], H, res, scale)[..., 0]
        photo_mask &= occ < 0.5
    view.level = Level(res, cam, H, torch.from_numpy(target), photo_mask, pts_v,
                       map_height, renderer, erode=MASK_ERODE_PX)
    update_mask(view)
    return view.level


def update_mask(view) -> None:
    """Skin mask = photo face polygon AND rendered face region, eroded."""
    from scipy.ndimage import binary_erosion

    lv = view.level
    gb = lv.renderer.head.aovs()
    seg, lv.uv = gb["segmentation"], gb["uv"]
    m = lv.photo_mask & (seg == 1)
    if lv.erode > 0:
        m = binary_erosion(m, iterations=lv.erode)
    lv.mask = torch.from_numpy(m)
    if view.lighting is not None and m.any():
        n = gb["normal"][m][:: max(1, int(m.sum()) // 2000)] @ lv.camera.R  # world frame
        d = view.lighting.dirs.reshape(-1, 3).numpy()
        reach = np.clip(n @ d.T, 0.0, None).mean(0)
        lv.reach = torch.from_numpy(reach.reshape(view.lighting.dirs.shape[:2]).astype(
            np.float32))


def render_view(view: View, maps: dict, verts: torch.Tensor, seed: int,
                light_grad: bool = True) -> torch.Tensor:
    """Render the view's current level (differentiable in the vertices, the maps and,
    with ``light_grad``, the lighting)."""
    env = view.lighting.env_map()
    return view.renderer.render(seed=seed, vertices=verts, albedo=maps["albedo"],
                                specular=maps["specular"], roughness=maps["roughness"],
                                normal=maps["normal"], env=env if light_grad else env.detach())


def match_exposure(state: FitState, view: View) -> None:
    """Scale the lighting so the first render's masked mean matches the photo's."""
    with torch.no_grad():
        maps = level_maps(state, view)
        verts = state.forward(view).vertices[0]
        img = render_view(view, maps, verts, 0)[..., :3]
        m = view.level.mask
        if int(m.sum()) < 4:
            return
        ratio = (view.level.target[m].mean(0) / img[m].mean(0).clamp_min(1e-4)).numpy()
        if view.photo.is_grey:   # a grey photo: a grey light, scaled to its luminance
            ratio = np.full(3, float((view.level.target[m] @ LUMA).mean()
                                     / (img[m] @ LUMA).mean().clamp_min(1e-4)))
        view.lighting.scale_(np.clip(ratio, 1e-3, 1e3))


def init_lobes(state: FitState, cfg: FitConfig, view: View,
               sharpness: float = 10.0) -> list[dict]:
    """Start an "sg" lighting from the photo (in place of :func:`match_exposure`).

    Rendering is linear in the emitted radiance, so with the geometry and maps fixed the
    masked photo is fitted as ``b B + sum_j a_j A_j`` per colour channel by non-negative
    least squares: B renders a uniform unit environment, A_j a unit lobe of the given
    sharpness around candidate direction j (:func:`~hack_render.fit.lighting.
    candidate_directions`, 32 over the sphere). The lobes are chosen greedily, each the
    candidate that lowers the residual most with the earlier ones kept; the SH starts
    as the uniform b, each lobe at its a_j. Costs 33 renders at the first level's size.
    Returns, per lobe, the chosen direction and the residual before and after it.
    """
    from scipy.optimize import nnls

    L = view.lighting
    m = view.level.mask.numpy()
    if int(m.sum()) < 8:
        match_exposure(state, view)
        return []
    seed = cfg.seed * 1000 + 777
    with torch.no_grad():
        maps = level_maps(state, view)
        verts = state.forward(view).vertices[0]

        def shot(env):
            img = view.renderer.render(seed=seed, vertices=verts, albedo=maps["albedo"],
                                       specular=maps["specular"], roughness=maps["roughness"],
                                       normal=maps["normal"], env=env)
            return img[..., :3].numpy()[m].astype(np.float64)  # (n, 3)

        one = torch.ones(L.height, 2 * L.height, 3)
        B = shot(one)
        dirs = candidate_directions(32)
        lam = torch.tensor(float(sharpness))
        A = [shot(one * L.lobe_map(torch.as_tensor(d, dtype=torch.float32), lam)[..., None])
             for d in dirs]
    T = view.level.target.numpy()[m].astype(np.float64)
    grey = view.photo.is_grey
    luma = LUMA.numpy().astype(np.float64)

    def solve(cols):
        """Per channel NNLS; (coefficients (len(cols), 3), residual norm). A grey photo:
        one NNLS on luminance, the same coefficients for every channel (a grey light)."""
        x, r = np.zeros((len(cols), 3)), 0.0
        if grey:
            x[:, 0], r = nnls(np.stack([col @ luma for col in cols], 1), T @ luma)
            x[:] = x[:, :1]
            return x, float(r)
        for c in range(3):
            x[:, c], rc = nnls(np.stack([col[:, c] for col in cols], 1), T[:, c])
            r += rc * rc
        return x, float(np.sqrt(r))

    chosen, report = [], []
    x, res0 = solve([B])
    for _ in range(L.lobe_dir.shape[0]):
        best = None
        for j in range(len(dirs)):
            if j in chosen:
                continue
            xj, rj = solve([B] + [A[i] for i in chosen] + [A[j]])
            if best is None or rj < best[2]:
                best = (j, xj, rj)
        chosen.append(best[0])
        report.append({"direction": dirs[best[0]].tolist(), "residual_before": res0,
                       "residual_after": best[2]})
        x, res0 = best[1], best[2]
    with torch.no_grad():
        L.coeffs.zero_()
        L.coeffs[0] = torch.as_tensor(np.maximum(x[0], 1e-4) / 0.282095, dtype=torch.float32)
        for k, j in enumerate(chosen):
            L.lobe_dir[k] = torch.as_tensor(dirs[j], dtype=torch.float32)
            L.lobe_log_sharpness[k] = math.log(sharpness)
            L.lobe_log_amplitude[k] = torch.as_tensor(np.log(np.maximum(x[1 + k], 1e-6)),
                                                      dtype=torch.float32)
    return report


def balance_albedo(state: FitState, cfg: FitConfig, spp: int = 16) -> dict:
    """Move the skin's colour from the lighting into alpha where the photo cannot tell the
    two apart (after the lighting's start; returns what it did).

    The skin's diffuse light is linear in the albedo and in the light, so a factor g per
    channel on the light and 1 / g on the albedo leave the photo unchanged; and the
    appearance model's leading components nearly are such factors (the shipped model's
    first three: 99.6-99.8 % of their diffuse variance over the face is a per-channel
    scale of the mean skin). The lighting's start (:func:`init_lobes`,
    :func:`match_exposure`) fits the photo with the current alpha, so the skin's colour
    starts in the light, and Adam's noisy steps barely move along that valley (the
    photo term is flat along it). This solves the objective's own priors along it: alpha
    minimising ``W_ALPHA |alpha|^2 + W_ALPHA / light_cast_sigma^2 sum_v cast_v(g_v)``,
    where ``g_v`` keeps the view's mean render over the photo term's pixels as it was:
    per channel, ``g = F / (D m(alpha) / m + S s(alpha) / s)``, with F the mean render, S
    its specular share (a render with no albedo; it takes the light's colour, not the
    skin's), D = F - S, and m, s the mean albedo and specular maps over the pixels'
    texels. Alpha and each view's light (scaled by its g) are then set."""
    pc = cfg.photometric
    if (state.appearance is None or not state.alpha.shape[1] or pc.light_cast_sigma <= 0
            or not BALANCE_ALBEDO):
        return {}
    views = [v for v in state.views if v.level is not None and v.level.uv is not None
             and int(v.level.mask.sum()) >= 8]
    if not views:
        return {}
    height = views[0].level.map_height
    h = height or state.appearance.height

    def texels(v):
        """Atlas (row, column) of the view's photo-term pixels at the level's atlas size."""
        uv = v.level.uv[v.level.mask.numpy()]
        x = np.clip((uv[:, 0] * h).astype(int), 0, 2 * h - 1)
        y = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
        return torch.from_numpy(y), torch.from_numpy(x)

    idx = [texels(v) for v in views]

    def means(alpha):
        """Per view: (mean albedo (3,), mean specular map (1,)) over its pixels' texels."""
        mp = state.maps(with_delta=False, height=height, alpha=alpha)
        return [(mp["albedo"][y, x].mean(0).clamp_min(1e-4),
                 mp["specular"][y, x].mean(0).clamp_min(1e-4)) for y, x in idx]

    a0 = state.alpha.detach().clone()
    shares = []
    with torch.no_grad():
        m0 = means(a0)
        maps = level_maps(state, views[0], with_delta=False)
        for v in views:
            verts = state.forward(v).vertices[0]
            env = v.lighting.env_map()
            kw = {"seed": cfg.seed * 1000 + 555, "spp": spp, "vertices": verts,
                  "specular": maps["specular"], "roughness": maps["roughness"],
                  "normal": maps["normal"], "env": env}
            m = v.level.mask
            full = v.renderer.render(albedo=maps["albedo"], **kw)[..., :3][m].mean(0)
            spec = v.renderer.render(albedo=torch.zeros_like(maps["albedo"]),
                                     **kw)[..., :3][m].mean(0)
            spec = torch.minimum(spec, 0.9 * full)
            shares.append((full, full - spec, spec))

    def gains(ms):
        return [f / (d * mv / mv0 + sp * sv / sv0)
                for (f, d, sp), (mv, sv), (mv0, sv0) in zip(shares, ms, m0)]

    w_cast = W_ALPHA / pc.light_cast_sigma ** 2
    a = a0.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([a], lr=1.0, max_iter=100, line_search_fn="strong_wolfe")

    def objective():
        return W_ALPHA * (a ** 2).sum() + w_cast * sum(
            v.lighting.colour_cast(g, v.level.reach) for v, g in zip(views, gains(means(a))))

    def closure():
        opt.zero_grad()
        loss = objective()
        loss.backward()
        return loss

    with torch.no_grad():
        before = float(objective())
    opt.step(closure)
    with torch.no_grad():
        after = float(objective())
        if not (math.isfinite(after) and after < before):
            return {"applied": False, "objective": [before, after]}
        g = [x.numpy() for x in gains(means(a))]
        state.alpha.copy_(a.detach())
        for v, gv in zip(views, g):
            v.lighting.scale_(gv)
    return {"applied": True, "objective": [before, after],
            "specular_share": [round(float((sp / f).mean()), 4) for f, _, sp in shares],
            "light_gain": [gv.round(4).tolist() for gv in g]}


def symmetry_pairs(model) -> tuple[torch.Tensor, torch.Tensor]:
    """Grid coordinates (P, 2) of mirror-vertex pairs (x -> -x) of the face, in [-1, 1]."""
    from scipy.spatial import cKDTree

    v = model.template.numpy()[:9409]
    uv = model.vertex_uv.numpy()[:9409]
    right = np.flatnonzero(v[:, 0] > 0.004)
    d, j = cKDTree(v).query(v[right] * np.array([-1.0, 1.0, 1.0]))
    ok = d < 0.002
    a, b = uv[right[ok]], uv[j[ok]]

    def grid(u):
        return torch.tensor(np.c_[u[:, 0] - 1.0, 1.0 - 2.0 * u[:, 1]], dtype=torch.float32)

    return grid(a), grid(b)


def texel_regularisers(delta: torch.Tensor, pairs) -> dict[str, torch.Tensor]:
    smooth = ((delta[1:] - delta[:-1]) ** 2).mean() + ((delta[:, 1:] - delta[:, :-1]) ** 2).mean()
    img = delta.permute(2, 0, 1)[None]
    sa = torch.nn.functional.grid_sample(img, pairs[0][None, None], align_corners=False)
    sb = torch.nn.functional.grid_sample(img, pairs[1][None, None], align_corners=False)
    return {"smooth": smooth, "symmetry": ((sa - sb) ** 2).mean(),
            "magnitude": (delta ** 2).mean()}


def level_objective(state: FitState, cfg: FitConfig, texel: bool = False, pairs=None):
    """(Adam parameter groups, loss) of one photometric level (``texel``: of the per-texel
    albedo stage, with the symmetry ``pairs``) over the views' current levels (set up by
    :func:`setup_level`): ``loss(it)`` -> (total, {term: float}), the objective the stage
    minimises (``bench/bench_fit.py --overhead`` times it as the stage's iteration)."""
    pc, tcfg = cfg.photometric, cfg.texel
    groups = _groups(state, cfg, texel)
    # Geometry is frozen in the texel stage and when REFINE_GEOMETRY is off: evaluate it
    # once per level (no model forward/backward per iteration; the bridge then uploads
    # the unchanged vertices once instead of rebuilding the scene every iteration), and
    # drop the terms that are constant then (landmarks, pose priors, mask refresh).
    refine = REFINE_GEOMETRY and not texel
    fixed = {}
    if not refine:
        with torch.no_grad():
            fixed = {id(v): state.forward(v).vertices[0] for v in state.views}
    pca = None
    if texel:
        with torch.no_grad():
            pca = {k: (x.detach() if x is not None else None)
                   for k, x in state.maps(with_delta=False).items()}  # full atlas

    def loss(it):
        if pca is not None:
            maps = dict(pca, albedo=(pca["albedo"] + state.albedo_delta).clamp(0.0, 1.0))
        else:  # the views of a level share its atlas size
            maps = level_maps(state, state.views[0])
        total, parts_sum = 0.0, {}
        for v in state.views:
            if refine and it and it % 10 == 0:
                update_mask(v)
            verts = state.forward(v).vertices[0] if refine else fixed[id(v)]
            img = render_view(v, maps, verts, cfg.seed * 1000 + it, light_grad=not texel)[..., :3]
            m = v.level.mask
            n = m.sum().clamp_min(1)
            diff = img - v.level.target
            if v.photo.is_grey:  # no colour in the photo: compare luminance only
                diff = (diff @ LUMA).unsqueeze(-1).expand_as(diff)
            ph = charbonnier(diff, CHARBONNIER_EPS)
            parts = {"photo": (ph * m[..., None]).sum() / (3 * n)}
            if not texel:
                parts["light_smooth"] = 1e-3 * v.lighting.smoothness()
            if refine:
                # the shape stage's objective (landmarks and its priors), scaled as a
                # whole by w_landmarks: the priors keep their balance with the landmarks
                # (an unscaled prior against the scaled landmarks would pull beta and
                # psi toward zero while the photo term's gradients are small)
                wl = terms.landmark_scale(cfg, v)
                parts.update({k: (W_SILHOUETTE if k == "silhouette" else wl)
                              * x for k, x in terms.shape_terms(state, cfg, v, verts,
                                                                it).items()})
            for k, x in parts.items():
                total = total + x
                parts_sum[k] = parts_sum.get(k, 0.0) + float(x.detach())
        extra = {} if texel else {"alpha_prior": W_ALPHA * (state.alpha ** 2).sum()}
        if not texel and pc.light_cast_sigma > 0:
            extra["light_cast"] = W_ALPHA / pc.light_cast_sigma ** 2 * sum(
                v.lighting.colour_cast(reach=v.level.reach) for v in state.views)
        if refine:
            extra["beta_prior"] = (sum(terms.landmark_scale(cfg, v) for v in state.views)
                                   / len(state.views) * terms.beta_prior(state, cfg))
            extra["larynx_prior"] = 1e-3 * (state.eta ** 2).sum() + 10.0 * (state.tau ** 2).sum()
            # E_larynx: eta and tau beyond their anatomical ranges, as E_rot for the joints
            extra["E_larynx"] = terms.W_ROT * larynx_limit_penalty(state.eta,
                                                                  state.tau).sum()
        if texel:
            for k, x in texel_regularisers(state.albedo_delta, pairs).items():
                w = {"smooth": tcfg.w_smooth, "symmetry": tcfg.w_symmetry,
                     "magnitude": TEXEL_W_MAGNITUDE}[k]
                extra[f"texel_{k}"] = w * x
        for k, x in extra.items():
            total = total + x
            parts_sum[k] = float(x.detach())
        return total, parts_sum

    return groups, loss


def levels(state: FitState, cfg: FitConfig) -> list[tuple[int, int]]:
    """(resolution, iterations) of the photometric levels: ``photometric.resolutions``,
    then each of ``fine_resolutions`` that every view's face crop (twice the landmarks'
    size, see :func:`virtual_camera`) has at least as many photo pixels as."""
    pc = cfg.photometric
    out = [(int(r), int(n)) for r, n in zip(pc.resolutions, pc.iterations)]
    crop = min(2.0 * v.detection.size for v in state.views)
    top = max((r for r, _ in out), default=0)
    for r, n in zip(pc.fine_resolutions, pc.fine_iterations):
        if int(r) > top and crop >= int(r) and int(n) > 0:
            out.append((int(r), int(n)))
            top = int(r)
    return out


def run(state: FitState, cfg: FitConfig, log: StageLog, texel: bool = False
        ) -> list[StageReport]:
    """The photometric stage, one report per level (:func:`levels`; or, with ``texel``,
    the per-texel albedo stage at the last level's resolution)."""
    pc, tcfg = cfg.photometric, cfg.texel
    reports = []
    lv = levels(state, cfg)
    levels_ = lv
    if texel:
        levels_ = [(lv[-1][0], tcfg.iterations)]
        h = state.appearance.height
        state.albedo_delta = torch.zeros(h, 2 * h, 3, requires_grad=True)
    pairs = symmetry_pairs(state.model) if texel else None
    started = False  # the lighting started at the first level: balance the albedo
    threads = torch.get_num_threads()
    torch.set_num_threads(pc.torch_threads)
    try:
        for res, iters in levels_:
            for v in state.views:
                want = None if texel else level_map_height(state, cfg, int(res))
                if v.level is None or v.level.res != res or v.level.map_height != want:
                    setup_level(state, cfg, v, int(res), full_maps=texel)
                    if not texel and res == levels_[0][0]:
                        if v.lighting.mode == "sg":
                            v.lighting_init = init_lobes(state, cfg, v)
                        else:
                            match_exposure(state, v)
                        started = True
            if not texel and started:
                state.albedo_balance = balance_albedo(state, cfg)
                started = False
            groups, loss = level_objective(state, cfg, texel, pairs)
            name = f"texel@{res}" if texel else f"photometric@{res}"
            reports.append(log.run(name, groups, loss, int(iters), after_step=state.clamp_,
                                   keep="last" if texel else "best"))
    finally:
        torch.set_num_threads(threads)
    return reports


def _groups(state: FitState, cfg: FitConfig, texel: bool) -> list[dict]:
    pc = cfg.photometric
    if texel:
        return [{"params": [state.albedo_delta], "lr": cfg.texel.lr}]
    groups = [{"params": list(v.lighting.parameters()), "lr": pc.lr_light}
              for v in state.views]
    if state.appearance is not None and state.alpha.shape[1]:
        groups.append({"params": [state.alpha], "lr": LR_ALPHA})
    elif state.appearance is None:
        groups.append({"params": [state.const_albedo], "lr": LR_ALPHA * 0.2})
    if REFINE_GEOMETRY:
        lr = pc.lr_geometry
        groups += [{"params": [state.beta, state.eta], "lr": lr},
                   {"params": [state.psi], "lr": lr * PSI_LR_SCALE},
                   {"params": [state.tau], "lr": lr * 0.01}]
        for v in state.views:
            # the camera (translation, focal) stays as the landmark stages left it: the
            # level's scene camera is built from it; the head moves instead
            groups.append({"params": [v.dtheta, v.head_angles], "lr": lr * 0.2})
            if v.psi is not None:
                groups.append({"params": [v.psi], "lr": lr * PSI_LR_SCALE})
    return groups
