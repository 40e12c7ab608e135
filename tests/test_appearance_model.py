"""PCA model: reconstruction, variance, maps() contract, file validation, held-out report."""

import numpy as np
import pytest
import torch

from appearance.builder import build_model, encode_subject
from appearance.generator import generate_subject
from appearance.model import AppearanceModel, load_model_arrays, save_model
from appearance.texture_io import read_texture_set, write_texture_set
from hack_render.errors import HackError

H = 32
N_SUBJECTS = 12


@pytest.fixture(scope="module")
def population(tmp_path_factory):
    root = tmp_path_factory.mktemp("pop")
    for s in range(N_SUBJECTS):
        ts = generate_subject(s, H)
        write_texture_set(root / f"s{s:03d}", {"diffuse": ts.diffuse, "specular": ts.specular,
                                               "roughness": ts.roughness, "normal": ts.normal})
    return root


@pytest.fixture(scope="module")
def built(population, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "m.npz"
    rep = build_model(population, out, height=H, progress=False, holdout=0.2)
    return out, rep


def test_all_components_reproduce_training_maps(population, built):
    out, _ = built
    m = AppearanceModel.load(out).to(dtype=torch.float64)
    valid = np.flatnonzero(m.mask_np)
    for s in (0, 7):
        maps = read_texture_set(population / f"s{s:03d}")
        x = torch.from_numpy(encode_subject(maps, H, valid)).double().view(1, -1, 7)
        rec = m.maps(m.project(x))
        d = rec.diffuse[0].numpy()[m.mask_np] - maps["diffuse"][m.mask_np]
        assert np.abs(d).max() < 1e-5
        n_true = maps["normal"][m.mask_np]
        cos = (rec.normal[0].numpy()[m.mask_np] * n_true).sum(-1) / np.linalg.norm(n_true, axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.05
        np.testing.assert_allclose(rec.specular[0].numpy()[m.mask_np],
                                   maps["specular"][m.mask_np], atol=1e-5)


def test_explained_variance_monotone_sums_to_one(built):
    _, rep = built
    evr = np.asarray(rep["explained_variance_ratio"])
    assert len(evr) == N_SUBJECTS - 1
    assert np.all(np.diff(evr) <= 1e-9) and np.all(evr >= 0)
    assert abs(evr.sum() - 1.0) < 1e-6


def test_heldout_errors_drop_with_components(built):
    _, rep = built
    ho = rep["heldout"]
    assert ho["k"][0] == 0 and ho["n_test"] >= 2
    assert ho["rmse_linear_rgb"][-1] < ho["rmse_linear_rgb"][0]
    assert ho["mean_ciede2000"][-1] < ho["mean_ciede2000"][0]
    assert out_png(built).is_file()


def out_png(built):
    return built[0].with_suffix(".report.png")


def test_maps_contract_shapes_units_and_dilation(built):
    m = AppearanceModel.load(built[0])
    alpha = m.sample_alpha(3, seed=1)
    mp = m.maps(alpha)
    assert mp.diffuse.shape == (3, H, 2 * H, 3) and mp.specular.shape == (3, H, 2 * H, 1)
    assert mp.roughness.shape == (3, H, 2 * H, 1) and mp.normal.shape == (3, H, 2 * H, 3)
    assert mp.mask.dtype == torch.bool and mp.mask.shape == (H, 2 * H)
    assert torch.allclose(mp.normal.norm(dim=-1), torch.ones(()), atol=1e-6)
    assert (mp.normal[..., 2] > 0).all()
    assert (mp.diffuse >= 0).all() and (mp.diffuse <= 1).all()
    # invalid texels copy a valid texel of the same tile (no bleeding between tiles)
    from appearance.uv import fill_index

    fill = fill_index(m.mask_np)
    flat = mp.diffuse[0].reshape(-1, 3)
    assert torch.equal(flat, flat[torch.from_numpy(fill)])
    cols = fill % (2 * H)
    own = np.arange(fill.size) % (2 * H)
    assert np.all((cols < H) == (own < H))


def test_component_count_is_a_call_time_choice(built):
    m = AppearanceModel.load(built[0])
    a = m.sample_alpha(2, n_components=3, seed=2)
    padded = torch.cat([a, torch.zeros(2, m.n_components - 3)], 1)
    assert torch.allclose(m.maps(a).diffuse, m.maps(padded).diffuse, atol=1e-6)
    with pytest.raises(HackError, match="k <="):
        m.maps(torch.zeros(1, m.n_components + 1))


def test_mean_at_zero_alpha_and_gradients_float64(built):
    m = AppearanceModel.load(built[0]).to(dtype=torch.float64)
    a = torch.zeros(1, 4, dtype=torch.float64, requires_grad=True)
    mp = m.maps(a)
    assert mp.diffuse.dtype == torch.float64
    # the map is linear in alpha before clamping: gradient check on an interior functional
    sel = m.mask.reshape(-1).nonzero()[:50, 0]

    def f(x):
        return m.maps(x).normal.reshape(1, -1, 3)[:, sel].sum(-1)

    assert torch.autograd.gradcheck(f, (0.1 * torch.randn(1, 4, dtype=torch.float64,
                                                          requires_grad=True),))


def test_int8_storage_close_to_float32(built, tmp_path):
    arr = load_model_arrays(built[0])
    save_model(tmp_path / "q.npz", basis_dtype="int8",
               **{k: arr[k] for k in ("height", "mask", "mean", "basis", "stddev",
                                      "explained_variance_ratio", "metadata")})
    a = AppearanceModel.load(built[0])
    q = AppearanceModel.load(tmp_path / "q.npz")
    alpha = a.sample_alpha(2, seed=3)
    assert (a.maps(alpha).diffuse - q.maps(alpha).diffuse).abs().max() < 0.01


@pytest.mark.parametrize("corrupt,match", [
    (lambda d: d.pop("mean"), "missing"),
    (lambda d: d.update(version=np.array(99)), "version"),
    (lambda d: d.update(mean=np.full_like(d["mean"], np.nan)), "finite"),
    (lambda d: d.update(basis=d["basis"][:, :-7]), "basis"),
])
def test_load_validates(built, tmp_path, corrupt, match):
    d = dict(np.load(built[0]))
    corrupt(d)
    np.savez(tmp_path / "bad.npz", **d)
    with pytest.raises(HackError, match=match):
        AppearanceModel.load(tmp_path / "bad.npz")


def test_builder_rejects_inconsistent_subjects(population, tmp_path):
    import shutil

    root = tmp_path / "mixed"
    for s in range(3):
        shutil.copytree(population / f"s{s:03d}", root / f"s{s:03d}")
    (root / "s001" / "roughness.exr").unlink()
    with pytest.raises(HackError, match="s001.*roughness"):
        build_model(root, tmp_path / "x.npz", height=H, progress=False)
    assert not (tmp_path / "x.npz").exists()


def test_appearance_package_never_imports_mitsuba():
    import subprocess
    import sys

    code = ("import sys, appearance, appearance.cli, appearance.builder, appearance.generator, "
            "appearance.detail, appearance.calibrate, appearance.build_default; "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('mitsuba', 'drjit')]; "
            "sys.exit(1 if bad else 0)")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_downsampled_is_the_box_filtered_atlas(built):
    """The coarse model's linear channels equal the f x f box filter of the fine model's
    dilated atlas for any alpha (the basis is filtered, not the maps), its mask marks the
    blocks with any valid texel, and its nonlinear maps follow from those channels."""
    out, _ = built
    m = AppearanceModel.load(out).to(dtype=torch.float64)
    c = m.downsampled(H // 4, n_components=5)
    assert (c.height, c.n_components) == (H // 4, 5)
    np.testing.assert_array_equal(c.mask_np, m.mask_np.reshape(H // 4, 4, H // 2, 4).any((1, 3)))
    alpha = torch.randn(2, 5, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    fine = m.compact(alpha)[:, m.gather].view(2, H, 2 * H, 7)
    box = torch.nn.functional.avg_pool2d(fine.permute(0, 3, 1, 2), 4).permute(0, 2, 3, 1)
    coarse = c.compact(alpha)[:, c.gather].view(2, H // 4, H // 2, 7)
    valid = torch.from_numpy(c.mask_np)
    torch.testing.assert_close(coarse[:, valid], box[:, valid])
    maps = c.maps(alpha)
    assert maps.diffuse.shape == (2, H // 4, H // 2, 3)
    torch.testing.assert_close(maps.diffuse[:, valid], box[:, valid][..., :3].clamp(0, 1))
    assert m.downsampled(H) is m
    for bad in (H // 3, 0, 2 * H):
        with pytest.raises(HackError, match="downsampled"):
            m.downsampled(bad)
