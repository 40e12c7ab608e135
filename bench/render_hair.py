"""Render benchmarks of a full head of hair (a section of bench/bench_render.py).

(j) Hair (``--only hair``, issue 61): the ``render`` command's defaults (256 px, 49 spp
    asked, auto sampler, hack_path, screen-space SSS, OIDN denoised, box filter) on the
    portrait camera and the studio rig, with a full head of hair (a groom of ``--h-styles``
    at lod 1: >= 50k scalp strands, brows, lashes; posed once, outside the timing) against
    the same render bald: CPU and wall seconds of ``render(sss=True)`` + ``denoise`` (median
    of ``--repeats`` after a warm-up that compiles the kernels; one scene alive at a time:
    per style the hair, the hair as before (4 melanin buckets in every group, no roulette
    on hair) and bald again, each ratio against the mean of the bald runs around it)
    and their ratios (target <= 2.0x); also the groom's growing and the scene's
    building (posing) once; ``bench/results/render_hair.json``. ``--h-quality``: the short
    groom's image before the roulette on hair, with it, and with a budget of one hair event,
    dark brown and blonde, against a 512-spp reference (PSNR and mean over the hair
    pixels, :func:`hair_quality`); ``bench/results/render_hair_quality.json``.

Run through ``bench/bench_render.py`` (``--only hair [--h-quality]``), which imports this module.
"""

from __future__ import annotations

import gc
import os
import statistics
import time

import numpy as np


def hair_benchmark(size: int = 256, spp: int = 49, styles=("short", "long"),
                   repeats: int = 2) -> None:
    """(j): see the module's notes."""
    from hack_render.geometry import default_model_path
    from hack_render.geometry.posing import PosingModel
    from hack_render.hair.groom import grow
    from hack_render.hair.regions import HeadSurface
    from hack_render.hair.style import HairStyle
    from hack_render.render import hair_shapes
    from hack_render.render.parts import Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    posing = PosingModel.from_file(default_model_path())
    v = posing.vertices().astype(np.float64)
    topo, surf = Topology.from_model(posing), HeadSurface.from_model(posing)
    rig = lights.preset("studio")
    cam = cameras.preset("portrait", size, size)[0]
    settings = RenderSettings(size, size, spp, pixel_filter="box")  # the command's, denoised
    maps = skin_maps(None, None, None)

    def measure(groom, before=False) -> tuple[float, float, float]:
        """Build the scene, render once (compiling), then the median CPU and wall seconds
        of ``repeats`` renders + denoise, and the build's seconds; the scene is alone in
        the process (Dr.Jit traces a BSDF call over every BSDF alive, so another scene's
        materials would slow this one). ``before``: as the renderer was before (4 melanin
        buckets in every group, no roulette on hair)."""
        saved = hair_shapes.GROUP_BUCKETS
        if before:
            hair_shapes.GROUP_BUCKETS = {g.name: 4
                                         for g in groom.groups}
        try:
            w0 = time.perf_counter()
            head = HeadScene(topo, v, rig, cam, settings, maps, hair=groom)
            built = time.perf_counter() - w0
        finally:
            hair_shapes.GROUP_BUCKETS = saved
        if before:  # read by the first render(sss=True)
            head.integrator_extra.pop("hair_rr", None)
        head.denoise(head.render(backdrop=False, sss=True))  # compiles the kernels
        cpu, wall = [], []
        for i in range(repeats):
            c0, w0 = time.process_time(), time.perf_counter()
            head.denoise(head.render(seed=i + 1, backdrop=False, sss=True))
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        del head
        gc.collect()
        return statistics.median(cpu), statistics.median(wall), built

    print(f"(j) hair: {size} px, {settings.effective_spp} spp ({settings.sampler_label}), "
          f"{settings.integrator}, SSS, denoised; median of {repeats} after a warm-up, one "
          f"scene at a time, bald before and after each style; load average (1 min) "
          f"{os.getloadavg()[0]:.1f}")
    bald_cpu, bald_wall, bald_build = measure(None)
    print(f"  bald: {bald_cpu:.2f} CPU s, {bald_wall:.2f} s wall (scene {bald_build:.2f} s)")
    for name in styles:
        t0 = time.perf_counter()
        groom = grow(surf, HairStyle.archetype_style(name, lod=1.0))
        grown = time.perf_counter() - t0
        cpu, wall, built = measure(groom)
        cpu0, wall0, _ = measure(groom, before=True)
        b_cpu, b_wall, _ = measure(None)
        bc, bw = (bald_cpu + b_cpu) / 2, (bald_wall + b_wall) / 2  # the bald runs around it
        bald_cpu, bald_wall = b_cpu, b_wall
        counts = ", ".join(f"{g.name} {g.num_strands} x {g.points_per_strand}"
                           for g in groom.groups)
        print(f"  {name} ({counts}): {cpu:.2f} CPU s, {wall:.2f} s wall: "
              f"{cpu / bc:.2f}x CPU, {wall / bw:.2f}x wall the bald render "
              f"({bc:.2f} CPU s, the mean of the bald runs before and after; target <= "
              f"2.0x); as before (4 melanin buckets in every group, no roulette on hair): "
              f"{cpu0:.2f} CPU s, {cpu0 / bc:.2f}x CPU, {wall0 / bw:.2f}x wall; grown in "
              f"{grown:.1f} s, scene built (posed) in {built:.1f} s")
    print(f"  load average (1 min) {os.getloadavg()[0]:.1f} after")


def hair_quality(size: int = 256, spp: int = 49, ref_spp: int = 512,
                 colours=("dark-brown", "blonde")) -> None:
    """(j) ``--h-quality``: the short groom (lod 1) in each colour, rendered as the bench
    renders it (``render(sss=True)`` + denoise) as before (4 melanin buckets in every group,
    no roulette on hair), now, and with a budget of one hair event (``hair_depth`` 1: a path ends at its first
    strand), against a ``ref_spp`` render before it (not denoised): PSNR (linear RGB, peak 1)
    over the pixels whose centre sees hair and the mean there, relative to the reference."""
    from hack_render.geometry import default_model_path
    from hack_render.geometry.posing import PosingModel
    from hack_render.hair.groom import grow
    from hack_render.hair.regions import HeadSurface
    from hack_render.hair.style import HairStyle
    from hack_render.render import hair_shapes
    from hack_render.render.parts import REGIONS, Topology
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from scenes import cameras, lights

    posing = PosingModel.from_file(default_model_path())
    v = posing.vertices().astype(np.float64)
    topo, surf = Topology.from_model(posing), HeadSurface.from_model(posing)
    rig = lights.preset("studio")
    cam = cameras.preset("portrait", size, size)[0]
    maps = skin_maps(None, None, None)
    variants = {"before": {"hair_rr": False},
                "now": {},
                "budget of 1 hair event": {"hair_rr": False, "hair_depth": 1}}

    def head_of(groom, n, extra):
        saved = hair_shapes.GROUP_BUCKETS
        if extra.get("hair_rr") is False:  # as before: 4 buckets in every group
            hair_shapes.GROUP_BUCKETS = {g.name: 4
                                         for g in groom.groups}
        try:
            head = HeadScene(topo, v, rig, cam,
                             RenderSettings(size, size, n, pixel_filter="box"), maps, hair=groom)
        finally:
            hair_shapes.GROUP_BUCKETS = saved
        head.integrator_extra.update(extra)  # read by the first render(sss=True)
        return head

    print(f"(j) hair quality: {size} px, {spp} spp, denoised, against {ref_spp} spp as "
          f"before; load average (1 min) {os.getloadavg()[0]:.1f}")
    for colour in colours:
        groom = grow(surf, HairStyle.archetype_style("short", lod=1.0).with_colour(colour))
        ref_head = head_of(groom, ref_spp, {"hair_rr": False})
        ref = ref_head.render(seed=99, backdrop=False, sss=True)[..., :3]
        hair = ref_head.aovs()["segmentation"] == REGIONS.index("hair")
        del ref_head
        for name, extra in variants.items():
            head = head_of(groom, spp, extra)
            raw = head.render(seed=1, backdrop=False, sss=True)
            den = head.denoise(raw)[..., :3]
            del head

            def psnr(img, hair=hair, ref=ref):
                return 10 * np.log10(1.0 / np.mean((img[hair] - ref[hair]) ** 2))

            print(f"  {colour}, {name}: hair PSNR {psnr(raw[..., :3]):.2f} dB noisy, "
                  f"{psnr(den):.2f} dB denoised; hair mean "
                  f"{den[hair].mean() / ref[hair].mean():.3f}"
                  f"x the reference's ({hair.sum()} hair pixels)")
