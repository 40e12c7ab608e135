"""Datasets at render speed (issue 65): the projected skin path keeps the generator's skin
tones, is a pure function of the subject, and its caches (the albedo table, the photos'
sRGB decoding) give the values they stand for."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from appearance.generator import generate_subject, representative_albedo
from appearance.projected import SubjectProjector, supports_height
from hack_render.dataset.config import load_config
from hack_render.dataset.runner import Job, check_job
from hack_render.errors import HackError

H = 64  # the tests' atlas height (the generator at 64: ~50 ms a subject)


@pytest.fixture(scope="module")
def projector():
    return SubjectProjector()


def _lab(rgb):
    from appearance.colour_space import linear_srgb_to_lab

    lab = linear_srgb_to_lab(np.asarray(rgb))
    return lab, np.degrees(np.arctan2(lab[..., 0] - 50.0, lab[..., 2]))


def test_projected_skin_tones_match_the_generators(projector):
    """Forehead albedo (the measurement site) of 12 subjects: ITA within a few degrees per
    subject, the population's mean and spread of ITA, L* and b* alike."""
    seeds = [3, 17, 101, 2024, 4096, 9999, 12345, 31337, 40000, 55555, 77777, 99998]
    gen, proj = [], []
    for s in seeds:
        gen.append(representative_albedo(generate_subject(s, H), H))
        m = projector.maps(s, H)
        assert m.diffuse.shape == (1, H, 2 * H, 3)
        proj.append(representative_albedo(type("T", (), {"diffuse": m.diffuse[0].numpy()}), H))
    (lab_g, ita_g), (lab_p, ita_p) = _lab(gen), _lab(proj)
    d = np.abs(ita_g - ita_p)
    assert np.median(d) < 3.0 and d.max() < 8.0, d
    assert abs(ita_g.mean() - ita_p.mean()) < 2.0 and abs(ita_g.std() - ita_p.std()) < 3.0
    for k in (0, 2):  # L*, b*
        assert abs(lab_g[:, k].mean() - lab_p[:, k].mean()) < 1.5
    assert np.corrcoef(ita_g, ita_p)[0, 1] > 0.97


def test_projected_maps_are_a_pure_function_of_the_subject(projector):
    a, b = projector.alpha(42), projector.alpha(42)
    assert a.dtype.is_floating_point and a.shape == (1, projector.model.n_components)
    assert np.array_equal(a.numpy(), b.numpy())
    assert not np.array_equal(a.numpy(), projector.alpha(43).numpy())
    fresh = SubjectProjector(projector.model)
    m1, m2 = projector.maps(42, 32), fresh.maps(42, 32)
    for name in ("diffuse", "specular", "roughness", "normal"):
        assert np.array_equal(getattr(m1, name).numpy(), getattr(m2, name).numpy()), name


def test_projected_heights():
    assert all(supports_height(h, 256) for h in (256, 128, 64, 32, 16))
    assert not any(supports_height(h, 256) for h in (0, 96, 300, 512))


def test_projected_height_not_a_mip_level_is_refused(projector, tmp_path):
    with pytest.raises(HackError, match="appearance height"):
        projector.maps(1, 96)
    cfg = load_config(overrides={"appearance": {"height": 96}})
    with pytest.raises(HackError, match="appearance.height.*appearance.maps: generated"):
        check_job(Job(tmp_path / "ds", 2, 0, cfg))
    check_job(Job(tmp_path / "ok", 2, 0, load_config(overrides={"appearance": {
        "height": 96, "maps": "generated"}})))


def test_maps_key_is_checked():
    assert load_config()["appearance"]["maps"] == "projected"
    with pytest.raises(HackError, match="appearance.maps"):
        load_config(overrides={"appearance": {"maps": "fast"}})


def test_albedo_table_cache(tmp_path, monkeypatch):
    from appearance import population as pop
    from appearance.skin_optics import AlbedoLUT

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    pop.albedo_lut.cache_clear()
    optics = pop.load_calibration().optics
    try:
        built = pop.albedo_lut(optics)  # computed, then written
        path = pop.lut_cache_path(optics)
        assert path.is_file() and path.parent == tmp_path / "hack-render"
        pop.albedo_lut.cache_clear()
        cached = pop.albedo_lut(optics)  # read back
        ref = AlbedoLUT.build(optics)
        for lut in (built, cached):
            assert np.array_equal(lut.rgb, ref.rgb) and lut.rgb.dtype == np.float32
            assert np.array_equal(lut.sqrt_cm, ref.sqrt_cm) and np.array_equal(lut.bm, ref.bm)
        path.write_bytes(b"not a table")
        pop.albedo_lut.cache_clear()
        assert np.array_equal(pop.albedo_lut(optics).rgb, ref.rgb)  # rebuilt
    finally:
        pop.albedo_lut.cache_clear()


def test_photo_decoding_table(tmp_path, monkeypatch):
    import colour

    from hack_render.dataset import backgrounds as bg

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    bg.srgb_decode8.cache_clear()
    try:
        ref = np.asarray(colour.cctf_decoding(np.arange(256) / 255.0, function="sRGB"))
        assert np.array_equal(bg.srgb_decode8(), ref)
        path = tmp_path / "hack-render" / bg.SRGB_DECODE_CACHE
        assert path.is_file()
        np.save(path, np.zeros(256))  # malformed: recomputed
        bg.srgb_decode8.cache_clear()
        assert np.array_equal(bg.srgb_decode8(), ref)
    finally:
        bg.srgb_decode8.cache_clear()


def test_a_subject_needs_no_colour_science_once_cached(tmp_path):
    """The generator imports colour-science (1.3-2.8 s) only to build its albedo table; with
    the table on disk a fresh process generates a subject without it."""
    code = ("import json, sys\nfrom appearance.projected import SubjectProjector\n"
            "SubjectProjector().maps(5, 32)\nprint(json.dumps('colour' in sys.modules))")
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path))
    runs = [subprocess.run([sys.executable, "-c", code], env=env, check=False,
                           capture_output=True, text=True, timeout=600) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr[-2000:]
    assert [json.loads(r.stdout.strip().splitlines()[-1]) for r in runs] == [True, False]
    assert any(Path(tmp_path, "hack-render").glob("albedo_lut-*.npz"))


def test_a_dataset_made_before_maps_resumes_with_the_generator(tmp_path):
    """A config.json without appearance.maps was made with the generator's maps: the same
    config with `maps: generated` resumes it; the projected default is refused, saying so."""
    from hack_render.dataset.runner import run_info

    old_cfg = load_config(overrides={"appearance": {"maps": "generated"}})
    info = json.loads(json.dumps(run_info(Job(tmp_path, 2, 0, old_cfg))))
    del info["config"]["appearance"]["maps"]
    (tmp_path / "config.json").write_text(json.dumps(info))
    check_job(Job(tmp_path, 2, 0, old_cfg))
    with pytest.raises(HackError, match="maps: generated"):
        check_job(Job(tmp_path, 2, 0, load_config()))
