"""bench/render_cycles.py, bench_render.py's Cycles section: its arithmetic and refusals
(fast, no Blender), and, where a Python with bpy is set ($HACK_RENDER_BPY_PYTHON, opt-in,
slow), the same scene rendered by both renderers at equal brightness and framing."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(ROOT / "bench"))  # render_cycles imports bench/provenance.py
    try:
        spec = importlib.util.spec_from_file_location("render_cycles",
                                                      ROOT / "bench" / "render_cycles.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(ROOT / "bench"))


def test_time_at_psnr_interpolates_log_time_on_the_first_rise(bench):
    rows = [{"cpu_s": 1.0, "psnr": 30.0}, {"cpu_s": 4.0, "psnr": 34.0},
            {"cpu_s": 2.0, "psnr": 29.0}, {"cpu_s": 8.0, "psnr": 36.0}]
    # time order: (1, 30), (2, 29), (4, 34), (8, 36): 32 dB lies 3/5 of the way 2 -> 4 s
    assert bench.time_at_psnr(rows, 32.0) == pytest.approx(2.0 * 2.0 ** 0.6)
    assert bench.time_at_psnr(rows, 35.0) == pytest.approx(4.0 * 2.0 ** 0.5)
    assert bench.time_at_psnr(rows, 30.0) is None  # the cheapest rung is already there
    assert bench.time_at_psnr(rows, 37.0) is None  # no rung reaches it
    assert bench.psnr_at_time(rows, 2.0 ** 2.5) == pytest.approx(35.0)
    assert bench.psnr_at_time(rows, 0.5) is None


def test_lower_envelope_keeps_the_rungs_no_cheaper_one_beats(bench):
    noisy = [{"cpu_s": 1.0, "psnr": 30.0}, {"cpu_s": 3.0, "psnr": 36.0}]
    denoised = [{"cpu_s": 1.5, "psnr": 34.0}, {"cpu_s": 2.5, "psnr": 35.0}]
    best = bench.lower_envelope(noisy, denoised)
    assert [r["cpu_s"] for r in best] == [1.0, 1.5, 2.5, 3.0]
    assert bench.lower_envelope(noisy, [{"cpu_s": 2.0, "psnr": 29.0}]) == noisy


def test_part_materials_carry_the_renderer_numbers(bench):
    from hack_render.render import materials

    fixed = materials.fixed_bsdfs()
    teeth = bench._cycles_material(fixed["teeth"])
    assert teeth["kind"] == "principled" and teeth["roughness"] == pytest.approx(0.15 ** 0.5)
    assert teeth["ior"] == 1.5 and teeth["base"] == [0.78, 0.72, 0.60]
    lashes = bench._cycles_material(fixed["eyelashes"])
    assert lashes["opacity"] == materials.EYELASH_OPACITY
    assert bench._cycles_material(fixed["bust_cap"])["kind"] == "diffuse"
    iris = bench._cycles_material(materials.iris_bsdf())
    f0 = ((iris["ior"] - 1) / (iris["ior"] + 1)) ** 2
    assert f0 == pytest.approx(0.08 * 0.3) and iris["vertex_color"] == "vertex_color"


def test_missing_blender_python_exits_2_with_the_fix(bench, monkeypatch, capsys, tmp_path):
    monkeypatch.delenv(bench.BPY_ENV, raising=False)
    with pytest.raises(SystemExit) as err:
        bench.blender_python(None)
    assert err.value.code == 2
    assert "pip install 'bpy" in capsys.readouterr().err
    with pytest.raises(SystemExit) as err:
        bench.blender_python(str(tmp_path / "no-python"))
    assert err.value.code == 2 and "missing" in capsys.readouterr().err


def test_both_comparisons_render_one_scene(bench, capsys):
    """``cycles_comparison_scene`` (bench_render's ``--only cycles`` and
    bench_hair_cycles.py): ``render --alpha 0.8,-0.6,0.4`` of the default head at rest,
    the portrait camera at the size asked, the studio rig; ``transcript`` prints and keeps
    each line."""
    pytest.importorskip("mitsuba")
    from hack_render.geometry.limits import LimitPolicy
    from hack_render.geometry.loading import posed_model
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    sc = bench.cycles_comparison_scene(40)
    _, _, v = posed_model(None, None, None, None, None, None, LimitPolicy("warn"), None)
    assert sc.v.dtype == np.float64 and np.array_equal(sc.v, v)
    assert sc.topo.faces.shape[0] == sc.model.faces.shape[0]
    cam = cameras.preset("portrait", 40, 40)[0]
    assert (sc.cam.width, sc.cam.height, sc.cam.name) == (40, 40, cam.name)
    np.testing.assert_array_equal(sc.cam.K, cam.K)
    np.testing.assert_array_equal(sc.cam.t, cam.t)
    assert (sc.rig.name, sc.rig.exposure) == ("studio", lights.preset("studio").exposure)
    np.testing.assert_array_equal(sc.maps.diffuse, skin_maps([0.8, -0.6, 0.4]).diffuse)
    say, printed = bench.transcript()
    say("one\ntwo")
    say("three")
    assert printed == ["one", "two", "three"]
    assert capsys.readouterr().out == "one\ntwo\nthree\n"


def test_a_rung_is_timed_by_the_renderer_that_renders_it(bench, tmp_path):
    """``timed_render``: Cycles' times are the worker's own report (its process's), ours
    the render call's (process and wall time), each with the effective spp."""
    import time
    from types import SimpleNamespace

    img = np.zeros((2, 2, 4), np.float32)

    class Worker:
        def render(self, spp, seed, denoise, out):
            self.asked = (spp, seed, denoise, out)
            return {"cpu_s": 7.0, "wall_s": 3.0, "spp": spp + 1}, img

    class Head:
        settings = SimpleNamespace(effective_spp=16)

        def render(self, seed, backdrop, denoise):
            self.asked = (seed, backdrop, denoise)
            time.sleep(0.05)
            return img + seed

    w, h = Worker(), Head()
    got = bench.timed_render("cycles", None, w, 8, 2, True, tmp_path / "i.exr")
    assert got[0] is img and got[1:] == (7.0, 3.0, 9)
    assert w.asked == (8, 2, True, tmp_path / "i.exr")
    out, cpu, wall, spp = bench.timed_render("ours", h, None, 8, 3, False, tmp_path / "i.exr")
    assert h.asked == (3, False, False) and out[0, 0, 0] == 3 and spp == 16
    assert 0.04 <= wall < 1.0 and 0 <= cpu < wall
    # ``rung_row``: seeds 1..repeats, the medians, each CPU time and each score's mean
    row, last = bench.rung_row("cycles", None, w, 8, True, 3, tmp_path / "i.exr",
                               lambda im: {"psnr": 30.0 + w.asked[1], "ssim": 0.5})
    assert w.asked[1] == 3 and last is img
    assert row == {"renderer": "cycles", "denoise": True, "spp": 9, "cpu_s": 7.0,
                   "cpu_each_s": [7.0] * 3, "wall_s": 3.0, "psnr": 32.0, "ssim": 0.5}
    assert list(row)[-2:] == ["psnr", "ssim"]   # the result file's key order
    row, last = bench.rung_row("ours", h, None, 8, False, 2, tmp_path / "i.exr",
                               lambda im: {"psnr_hair": float(im[0, 0, 0])})
    assert last[0, 0, 0] == 2 and row["psnr_hair"] == 1.5 and row["spp"] == 16
    assert len(row["cpu_each_s"]) == 2 and row["wall_s"] >= 0.04


BPY = os.environ.get("HACK_RENDER_BPY_PYTHON")


@pytest.mark.slow
@pytest.mark.skipif(not BPY or not Path(BPY).is_file(),
                    reason="set HACK_RENDER_BPY_PYTHON to a Python with bpy")
def test_cycles_renders_the_same_scene(bench, tmp_path):
    """At 64 px and 64 spp both see the head in the same pixels with the same brightness
    (lights, camera and materials carried over; the materials differ in detail)."""
    from hack_render.render.scene import HeadScene, RenderSettings

    sc = bench.cycles_comparison_scene(64)
    v, maps = sc.v, sc.maps
    head = HeadScene(sc.topo, v, sc.rig, sc.cam, RenderSettings(64, 64, 64), maps)
    ours = head.render(seed=1, backdrop=False)
    exe, _ = bench.blender_python(BPY)
    bench.write_cycles_scene(tmp_path, head, v, maps)
    worker = bench.CyclesWorker(exe, tmp_path, tmp_path / "cycles.log")
    try:
        reply, theirs = worker.render(64, 1, False, tmp_path / "c.exr")
    finally:
        worker.close()
    assert reply["spp"] == 64 and reply["cpu_s"] > 0
    cover_o, cover_c = ours[..., 3] > 0.5, theirs[..., 3] > 0.5
    assert (cover_o == cover_c).mean() > 0.98  # same framing
    mean_o, mean_c = ours[..., :3].mean((0, 1)), theirs[..., :3].mean((0, 1))
    assert np.all(np.abs(mean_c / mean_o - 1) < 0.1), (mean_o, mean_c)
