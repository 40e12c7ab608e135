"""Finite-difference checks of the torch <-> Dr.Jit bridge (hack_render/render/bridge.py).

Each test compares the bridge's reverse-mode gradient of a weighted sum of interior face
pixels (eroded face mask: no silhouettes) with a central difference of the same
deterministic render (fixed seed; the adjoint pass uses its own decorrelated seed). ``prb`` differentiates shading but
not visibility (shadow boundaries), so geometry and light tolerances are looser than the
albedo one; the focal length needs a projective integrator (camera rays are detached in
``prb``) and is checked with ``direct_projective`` (slow).
"""

import numpy as np
import pytest
import torch

mi = pytest.importorskip("mitsuba")

RES = 40


@pytest.fixture(scope="module")
def setup():
    from scipy.ndimage import binary_erosion

    from hack_render.geometry import load_default_model
    from hack_render.render.bridge import DiffRenderer
    from hack_render.render.engine import ensure_variant, is_jit
    from hack_render.render.materials import SkinMaps
    from hack_render.render.parts import Topology, vertex_normals
    from hack_render.render.scene import HeadScene, RenderSettings
    from scenes import cameras as cams
    from scenes import lights

    ensure_variant()
    if not is_jit():
        pytest.skip("needs a JIT Mitsuba variant")
    torch.set_num_threads(1)
    model = load_default_model()
    with torch.no_grad():
        v0 = model().vertices[0].double()
    topo = Topology.from_model(model)
    cam = cams.orbit(RES, RES, 85.0, 20.0, 5.0, target=(0, 0.02, 0.05), extent=0.22)
    d = lights.latlong_directions(16)
    sky = (1.0 + 0.8 * d[..., 0:1] + 0.5 * d[..., 1:2]).clip(0.1) * np.ones(3)
    rig = lights.LightRig(name="t", env_map=sky.astype(np.float32))
    maps = SkinMaps.constant(16)
    head = HeadScene(topo, v0.numpy(), rig, cam, RenderSettings(RES, RES, 32, 8, 0), maps)
    inner = binary_erosion(head.aovs()["segmentation"] == 1, iterations=2)
    w = torch.rand(RES, RES, 3, generator=torch.Generator().manual_seed(0))
    w = w * torch.from_numpy(inner)[..., None]
    n = vertex_normals(v0.numpy(), topo.faces)
    return dict(model=model, v0=v0, head=head, maps=maps, w=w, inner=inner, n=n,
                prb=DiffRenderer(head, "prb", spp=32), DiffRenderer=DiffRenderer)


def loss(img, w):
    return (img[..., :3] * w).sum()


def check(setup, renderer, name, base, direction, h, rtol, w=None):
    """AD directional derivative vs central difference along ``direction``."""
    w = setup["w"] if w is None else w
    x = torch.zeros(1, dtype=torch.float64, requires_grad=True)
    kw = dict(setup.get("kw", {}))
    loss(renderer.render(seed=3, **{name: base + x * direction}, **kw), w).backward()
    ad = float(x.grad)
    f = lambda s: float(loss(renderer.render(seed=3, **{name: base + s * direction}, **kw), w))
    fd = (f(h) - f(-h)) / (2 * h)
    assert ad != 0.0 and np.isfinite(ad)
    assert abs(ad - fd) <= rtol * abs(fd), f"{name}: AD {ad:.5g} vs FD {fd:.5g}"
    return ad, fd


def test_01_albedo_texel_block(setup):
    a = torch.tensor(setup["maps"].diffuse, dtype=torch.float64)
    d = torch.zeros_like(a)
    d[4:8, 4:10] = 1.0  # a block of texels inside the face tile
    setup["kw"] = {"vertices": setup["v0"]}
    check(setup, setup["prb"], "albedo", a, d, 0.05, 0.03)


def test_02_vertices_smooth_bump(setup):
    v0, n = setup["v0"], setup["n"]
    vv = v0.numpy()
    c = vv[np.argmin(np.linalg.norm(vv - [0.04, -0.015, 0.08], axis=1))]
    wgt = np.exp(-0.5 * (np.linalg.norm(vv - c, axis=1) / 0.012) ** 2)
    wgt[9409:] = 0.0
    setup["kw"] = {}
    ad, fd = check(setup, setup["prb"], "vertices", v0, torch.tensor(n * wgt[:, None]), 5e-4,
                   0.35)  # measured: AD within 10-30 % of FD (prb ignores shadow edges)
    # a wrong sign or a missing normal path would be far off; visibility terms are not
    assert np.sign(ad) == np.sign(fd)


def test_03_light_rotation(setup):
    fh = torch.from_numpy(setup["inner"]).clone()
    fh[RES // 3:] = False  # forehead: little self-shadowing, whose edges prb ignores
    w = torch.rand(RES, RES, 3, generator=torch.Generator().manual_seed(1)) * fh[..., None]
    setup["kw"] = {"vertices": setup["v0"]}
    check(setup, setup["prb"], "light_rotation_deg", torch.tensor([10.0], dtype=torch.float64),
          torch.ones(1, dtype=torch.float64), 1.0, 0.25, w)


@pytest.mark.slow
def test_05_focal_length_projective(setup):
    r = setup["DiffRenderer"](setup["head"], "direct_projective", spp=32)
    f0 = float(setup["head"].camera.K[0, 0])
    setup["kw"] = {"vertices": setup["v0"]}
    check(setup, r, "focal_px", torch.tensor([f0], dtype=torch.float64),
          torch.ones(1, dtype=torch.float64), 0.5, 0.3)
