"""The hair layer's model (issue 61): styles, grooms rooted on the skin, posing that follows
every input of the geometry model, torch twin, collisions over poses within the limits."""

from __future__ import annotations

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.geometry.anatomy import distribute_head_rotation
from hack_render.geometry.model_file import default_model_path
from hack_render.geometry.nearest import PointTree
from hack_render.geometry.params import check_params
from hack_render.geometry.posing import PosingModel
from hack_render.hair.groom import grow_cached
from hack_render.hair.pose import (
    MARGIN,
    Body,
    pose_groom,
    pose_group,
    pose_group_torch,
    push_out,
    signed_distance,
)
from hack_render.hair.regions import HeadSurface
from hack_render.hair.strands import root_points
from hack_render.hair.style import ARCHETYPES, HairStyle, parse_colour, sample_style


@pytest.fixture(scope="module")
def posing():
    return PosingModel.from_file(default_model_path())


@pytest.fixture(scope="module")
def surface(posing):
    return HeadSurface.from_model(posing)


def _small(archetype: str, **kw) -> HairStyle:
    return HairStyle.archetype_style(archetype, lod=0.05, **kw)


def test_style_validation_and_colours():
    with pytest.raises(HackError, match="hair.curl"):
        HairStyle(curl=1.5)
    with pytest.raises(HackError, match="archetype"):
        HairStyle.from_dict({"archetype": "mohawk"})
    with pytest.raises(HackError, match="unknown key"):
        HairStyle.from_dict({"lenght": 0.1})
    with pytest.raises(HackError, match="hair colour"):
        parse_colour("green")
    with pytest.raises(HackError):
        HairStyle(length=True)
    style = HairStyle.from_dict({"archetype": "long", "color": "black", "beard": "full"})
    assert (style.eumelanin, style.pheomelanin) == (8.0, 0.0)
    assert style.length == pytest.approx(0.30) and style.beard == "full"
    assert HairStyle.from_dict(None).bald and HairStyle.from_dict("bob").archetype == "bob"
    assert parse_colour("1.5,0.2") == (1.5, 0.2)
    # the params file carries the section through its own checks
    assert check_params({"hair": {"archetype": "afro"}})["hair"] == {"archetype": "afro"}
    with pytest.raises(HackError, match="hair"):
        check_params({"hair": [1, 2]})


def test_sampler_covers_the_archetypes_and_is_deterministic():
    rng = np.random.default_rng(0)
    styles = [sample_style(rng) for _ in range(400)]
    seen = {s.archetype for s in styles}
    assert seen == set(ARCHETYPES)
    assert {s.beard for s in styles} == {"none", "stubble", "goatee", "full"}
    black = np.mean([s.eumelanin > 5 for s in styles])
    assert 0.35 < black < 0.65  # COLOUR_FREQUENCIES: black 0.5
    again = [sample_style(np.random.default_rng(0)) for _ in range(1)]
    assert again[0] == styles[0]


def test_roots_are_skin_points_under_identity_expression_and_pose(posing, surface):
    groom = grow_cached(surface, _small("short", beard="full"))
    rng = np.random.default_rng(3)
    beta = rng.normal(size=posing.num_shape).astype(np.float32)
    psi = posing.expression_vector({"AU1": 1.0, "AU2": 1.0, "jawOpen": 0.8})
    theta = distribute_head_rotation(np.deg2rad([25.0, 40.0, -15.0])).astype(np.float32)
    v = posing.vertices(beta=beta, psi=psi, theta=theta, tau=np.float32(0.01))
    posed = pose_groom(groom, v, collide=False)
    for g in groom.groups:
        root = root_points(v.astype(np.float64), surface.faces, g.tri, g.bary)
        np.testing.assert_allclose(posed[g.name][:, 0], root, atol=1e-7)
        # the strand's shape is kept: lengths of each segment unchanged up to the
        # triangle's own strain (a few percent)
        rest = pose_group(g, surface.vertices, surface.faces)
        seg_rest = np.linalg.norm(np.diff(rest, axis=1), axis=-1)
        seg = np.linalg.norm(np.diff(posed[g.name], axis=1), axis=-1)
        np.testing.assert_allclose(seg, seg_rest, rtol=1e-5, atol=1e-9)
    # brows rise with AU1/AU2 relative to the eyes' landmarks
    lm = surface.landmarks
    rest_v = posing.vertices(beta=beta, theta=theta)
    up = posing.vertices(beta=beta, theta=theta, psi=psi)
    brow_rest = pose_group(groom.group("brows"), rest_v, surface.faces)[:, 0, 1]
    brow_up = pose_group(groom.group("brows"), up, surface.faces)[:, 0, 1]
    eye_shift = (up[lm[36:48], 1] - rest_v[lm[36:48], 1]).mean()
    assert (brow_up - brow_rest).mean() > eye_shift + 0.001
    # the beard on the chin moves down with the jaw
    chin = groom.group("beard")
    low = pose_group(chin, rest_v, surface.faces)[:, 0, 1] < rest_v[lm[8], 1] + 0.01
    moved = pose_group(chin, up, surface.faces)[low, 0, 1] - \
        pose_group(chin, rest_v, surface.faces)[low, 0, 1]
    assert moved.mean() < -0.005


def test_torch_twin_matches_and_has_gradients(posing, surface):
    torch = pytest.importorskip("torch")
    groom = grow_cached(surface, _small("bob"))
    v = posing.vertices(beta=np.ones(posing.num_shape, np.float32) * 0.5)
    vt = torch.tensor(v[None], dtype=torch.float64, requires_grad=True)
    faces = torch.as_tensor(surface.faces)
    g = groom.group("scalp")
    out = pose_group_torch(g, vt, faces)
    np.testing.assert_allclose(out[0].detach().numpy(), pose_group(g, v, surface.faces),
                               atol=1e-9)
    out[..., 1].sum().backward()
    assert torch.isfinite(vt.grad).all() and vt.grad.abs().sum() > 0


@pytest.mark.parametrize("archetype", ["long", "ponytail",
                                       pytest.param("afro", marks=pytest.mark.slow),
                                       pytest.param("bob", marks=pytest.mark.slow)])
def test_no_strand_inside_the_body_in_poses_within_the_limits(posing, surface, archetype):
    """Every control point keeps outside the skin (signed distance to the nearest skin
    vertex's tangent plane >= -0.5 mm, the strands' own radius tenfold) in random poses
    with all three axes of every joint drawn within their limits, and in the extremes, for
    random identities. The lashes are left out: they emerge under the lid's fold, where
    the nearest vertex's plane is not the skin's side (they are checked against the
    eyeballs below)."""
    groom = grow_cached(surface, _small(archetype, beard="full"))
    lim = np.deg2rad(np.asarray(posing.arrays["rotation_limits_deg"], np.float64))
    rng = np.random.default_rng(11)
    poses = [rng.uniform(lim[..., 0], lim[..., 1]) for _ in range(6)]
    poses += [lim[..., 0].copy(), lim[..., 1].copy()]
    skin = surface.faces[surface.skin]
    for theta in poses:
        beta = rng.normal(size=posing.num_shape).astype(np.float32)
        v = posing.vertices(beta=beta, theta=theta.astype(np.float32))
        for name, pts in pose_groom(groom, v).items():
            if name == "lashes":
                continue
            sd = signed_distance(pts[:, 1:], v.astype(np.float64), skin)
            assert sd.min() > -5e-4, (archetype, name, float(sd.min()))


def test_levels_of_detail_scale_counts(surface):
    full = grow_cached(surface, HairStyle.archetype_style("crew", lod=1.0))
    tenth = grow_cached(surface, HairStyle.archetype_style("crew", lod=0.1))
    assert full.group("scalp").num_strands >= 50_000
    assert tenth.group("scalp").num_strands == pytest.approx(
        full.group("scalp").num_strands / 10, rel=0.02)
    receded = grow_cached(surface, HairStyle.archetype_style("crew", lod=0.1, hairline=1.0))
    assert receded.group("scalp").num_strands < 0.85 * tenth.group("scalp").num_strands
    bald = grow_cached(surface, HairStyle.archetype_style("bald", lod=0.1))
    assert bald.group("scalp") is None and bald.group("brows") is not None


def test_regions_on_the_mean_mesh(surface):
    """hair/regions.py on the default model's mean mesh: the scalp's and beard's skin
    triangles (counts measured before the regions left groom.py, so a change shows), the
    hairline's knots, its recession (front and temples up, the back kept) and widow's peak
    (the front only), and no beard triangle on the scalp."""
    from hack_render.hair.regions import beard_mask, hairline_height, scalp_mask

    assert len(surface.skin) == 28068
    az = np.array([0.0, 25.0, -45.0, 180.0])
    np.testing.assert_allclose(hairline_height(az, HairStyle()), [0.118, 0.115, 0.097, -0.045])
    up = hairline_height(np.array([0.0, 48.0, 180.0]), HairStyle(hairline=1.0)) - \
        hairline_height(np.array([0.0, 48.0, 180.0]), HairStyle())
    np.testing.assert_allclose(up, [0.035, 0.055, 0.0], atol=1e-6)
    peak = hairline_height(np.array([0.0, 30.0]), HairStyle(widows_peak=1.0)) - \
        hairline_height(np.array([0.0, 30.0]), HairStyle())
    np.testing.assert_allclose(peak, [-0.014, 0.0], atol=1e-6)
    scalp, weight = scalp_mask(surface, HairStyle())
    assert len(scalp) == 2607 and float(weight.sum()) == pytest.approx(2481.631, abs=1e-3)
    assert np.all((weight > 0) & (weight <= 1)) and np.isin(scalp, surface.skin).all()
    receded, _ = scalp_mask(surface, HairStyle(hairline=1.0))
    peaked, _ = scalp_mask(surface, HairStyle(widows_peak=1.0))
    assert len(receded) == 1677 and np.isin(receded, scalp).all() and len(peaked) == 2648
    beards = {b: beard_mask(surface, b) for b in ("stubble", "goatee", "full")}
    assert {b: len(m) for b, m in beards.items()} == {"stubble": 5192, "goatee": 2154,
                                                       "full": 5192}
    assert not any(np.isin(m, scalp).any() for m in beards.values())


def test_anchors_reuse_the_last_push_out_exactly(surface):
    """A group's anchors (each point's nearest body vertex at rest) taken from the last
    push out's search where the points are unchanged, and searched again elsewhere (the
    roots, the points it moved, strands changed after it, as a cut changes them), are
    the ones a full search finds."""
    from hack_render.hair.groom import _group
    from hack_render.hair.strands import BodyProxy

    g = grow_cached(surface, _small("long")).group("scalp")
    proxy = BodyProxy(surface.vertices, surface.faces, surface.skin)
    pts = pose_group(g, surface.vertices, surface.faces)
    pts[:, 1:], known = proxy.push_out(pts[:, 1:], 0.006, index=True)
    assert (known.index < 0).any() and (known.index >= 0).mean() > 0.3
    pts[:7, 2:] += 0.002   # strands changed after the push out
    args = ("scalp", surface, g.tri, g.bary, pts, g.radius, g.melanin)
    full, reused = _group(*args), _group(*args, known)
    np.testing.assert_array_equal(reused.anchor, full.anchor)
    np.testing.assert_array_equal(reused.anchor_local, full.anchor_local)
    # the index a push out reports is the nearest skin vertex of the point it returns
    _, _, i = proxy.nearest(pts[7:, 1:], index=True)
    ok = known.index[7:] >= 0
    np.testing.assert_array_equal(i[ok], known.index[7:][ok])


def test_fast_forms_give_numpys_bits(surface):
    """The groom's and the posing's hand-written forms of NumPy calls (for speed: the
    dataset grows and poses a groom per sample) give the same bits as the calls: the
    open-edge vertices (an edge as one integer key) as the rows' unique, the posing's
    frame products as ``np.einsum``, the curl's tangent as ``np.gradient``, the collision
    proxy built from the surface's cached arrays as the one built afresh. The local
    frames' product sums in the order ``np.einsum`` takes on the development machine;
    elsewhere it may differ in the last bit, so that one is compared to 1e-15."""
    from hack_render.hair.groom import _gradient, _to_local
    from hack_render.hair.pose import from_frames
    from hack_render.hair.strands import BodyProxy, open_edge_vertices, triangle_frames

    def rows_unique(faces):  # the reference: unique edge rows, counted
        e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
        uniq, count = np.unique(e, axis=0, return_counts=True)
        return np.unique(uniq[count == 1])

    rng = np.random.default_rng(7)
    skin = surface.faces[surface.skin]
    for faces in (skin, surface.faces, skin[rng.permutation(len(skin))[:500]],
                  skin.astype(np.int32), skin[:0]):
        got = open_edge_vertices(faces)
        np.testing.assert_array_equal(got, rows_unique(faces))
        assert got.dtype == faces.dtype
    tri = rng.choice(surface.skin, 300)
    frames = triangle_frames(surface.vertices, surface.faces[tri])
    local = rng.normal(size=(300, 6, 3))
    np.testing.assert_array_equal(from_frames(frames, local),
                                  np.einsum("sij,ski->skj", frames, local))
    bary = rng.dirichlet(np.ones(3), 300)
    root = root_points(surface.vertices, surface.faces, tri, bary)
    pts = root[:, None] + 0.01 * local
    want = np.einsum("sij,skj->ski", frames, pts - root[:, None])
    want[:, 0] = 0.0
    np.testing.assert_allclose(_to_local(surface.vertices, surface.faces, tri, bary, pts),
                               want, rtol=0, atol=1e-15)
    for k in (2, 3, 9):
        np.testing.assert_array_equal(_gradient(local[:, :k]), np.gradient(local[:, :k], axis=1))
    fresh, cached = BodyProxy(surface.vertices, surface.faces, surface.skin), \
        BodyProxy.of(surface)
    for name in ("index", "points", "normals"):
        np.testing.assert_array_equal(getattr(cached, name), getattr(fresh, name))
    q = surface.vertices[::50] + rng.normal(0, 0.01, (len(surface.vertices[::50]), 3))
    for a, b in zip(cached.nearest(q, index=True), fresh.nearest(q, index=True)):
        np.testing.assert_array_equal(a, b)


def test_a_recoloured_groom_is_the_one_grown_in_that_colour(surface, monkeypatch):
    """Colour is the last thing a groom's draws make: a groom grown once and recoloured
    (``GroomCache``, the datasets' pooled grooms) is bit for bit what ``grow`` makes of
    the recoloured style, with no growing; another shape is refused."""
    from dataclasses import fields, replace

    from hack_render.hair import groom as gm

    a = _small("long", beard="full", greying=0.0, eumelanin=3.0, seed=7)
    b = replace(a, eumelanin=0.4, pheomelanin=1.5, greying=0.5, variation=0.3)
    cache = gm.GroomCache(2)
    first = cache.get(surface, a)
    grown, real = [], gm.grow
    monkeypatch.setattr(gm, "grow", lambda *args: grown.append(1) or real(*args))
    got = cache.get(surface, b)
    assert not grown
    monkeypatch.undo()
    want = gm.grow(surface, b)
    assert [g.name for g in got.groups] == ["scalp", "brows", "lashes", "beard"]
    for g, w, f0 in zip(got.groups, want.groups, first.groups):
        for f in fields(w):
            x, y = getattr(g, f.name), getattr(w, f.name)
            if isinstance(y, np.ndarray):
                np.testing.assert_array_equal(x, y, err_msg=f"{g.name}.{f.name}")
            else:
                assert x == y
        assert not np.array_equal(g.melanin, f0.melanin)  # recoloured, not reused
        assert (g.melanin[:, 0] < 0.05 * 0.4 * g.darker).any()  # greying now
    assert got.style == b
    with pytest.raises(ValueError, match="colour"):
        gm.recolour(first, replace(a, length=0.2))


def test_push_out_searches_an_open_edge_point_once():
    """``pose.push_out``: a point nearest to a vertex without a normal (an open edge's) is
    beyond the surface and stays where it is, and it is searched once, not in every round;
    a point inside the surface is moved to the margin along its vertex's normal."""
    grid = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij"), -1).reshape(-1, 2)
    verts = np.concatenate([grid * 0.01, np.zeros((25, 1))], 1)  # a 4 x 4 cm sheet, z = 0
    normals = np.tile([0.0, 0.0, 1.0], (25, 1))
    normals[:5] = 0.0  # the sheet's edge x = 0: open
    sizes = []

    class Counting(PointTree):
        def query(self, x, *a, **k):
            sizes.append(len(x))
            return super().query(x, *a, **k)

    body = Body(Counting(verts), np.arange(25), verts, normals)
    pts = np.array([[0.0, 0.02, -0.002],     # nearest to the open edge: beyond, not moved
                    [0.02, 0.02, -0.003]])   # under the sheet's middle: pushed out
    out = push_out(pts, body)
    assert np.array_equal(out[0], pts[0])
    assert np.allclose(out[1], [0.02, 0.02, MARGIN])
    assert sizes[0] == 2 and all(n <= 1 for n in sizes[1:]), sizes
