"""Hair against Blender Cycles at equal noise (issue 61): the same posed strands.

The Cycles comparison of ``bench_render.py --only cycles`` (the default head, ``--alpha
0.8,-0.6,0.4``, portrait camera, studio rig, depth 8, Gaussian pixel filter) with a full
head of hair: the ``short`` archetype grown at lod 1 (>= 50k scalp strands, brows and
lashes; the strand lashes replace the lash cards in both renderers), posed on the head
by ``HeadScene``. Ours renders it as ``HeadScene(hair=groom)`` does (Mitsuba
``linearcurve`` shapes, one per strand group and melanin bucket, ``hair`` BSDF); Cycles
gets the very control points of each of those shapes as a Curves object
(``cycles_scene.import_hair``: round curves through the same points, Principled Hair BSDF,
Chiang model) and the same melanin as an absorption coefficient: Mitsuba's
``sigma_a = eumelanin x (0.419, 0.697, 1.37) + pheomelanin x (0.187, 0.4, 1.05)``
(``hair.style.EUMELANIN_SIGMA_A``, ``PHEOMELANIN_SIGMA_A``) given to Cycles' *absorption*
parametrisation, not Cycles' own melanin inputs (whose pigment spectra, (0.506, 0.841,
1.653) and (0.343, 0.733, 1.924), differ from Mitsuba's); both read it per unit of fibre
radius (Chiang et al. 2016 / pbrt's ``2 cos(gamma_t) / cos(theta_t)`` path), roughness
0.3 / 0.3, IOR 1.55, 2 deg scale tilt in both.

Equal noise as in the bald comparison: each renderer against its own high-spp reference
(``--ref-spp``), a ladder of spp, PSNR on linear RGB (peak 1) over the whole image and
over the hair region (pixel centres whose first hit is a strand, ``HeadScene.aovs``),
CPU seconds of the render call (process time, all threads), rungs interleaved (ours,
Cycles); time at equal PSNR interpolated on each ladder's PSNR-log(time) curve
(``bench_render.compare_curves``): both noisy, both denoised (OIDN), each at its best.
Ours denoised renders from the box pixel filter, as ``render --denoise`` does
(``cli.denoise_settings``: OIDN keeps the noise Mitsuba's Gaussian filter correlates
between pixels), and is scored against a box-filter reference of its own (``ours_box``).
Writes ``bench/results/render_hair_cycles.json`` and ``docs/images/hair_vs_cycles.png``
(ours | Cycles at equal noise: noisy, denoised, references).

    python bench/bench_hair_cycles.py --blender-python /work/bpy-venv/bin/python \\
        [--ref-spp 1024] [--ladder 4,8,16,32,64,128] [--denoise-ladder 2,4,8,16,32,64]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np
from bench_render import (  # bench/ is sys.path[0] when run as a script
    blender_python,
    compare_curves,
    cycles_comparison_scene,
    lower_envelope,
    rung_row,
    side_by_side,
    start_cycles,
    transcript,
    write_cycles_scene,
)
from provenance import write_result


def write_cycles_hair(folder: Path, head, vertices: np.ndarray,
                      melanin: str = "absorption") -> list[dict]:
    """Each hair shape of ``head`` (its ``hair_shapes``) for ``cycles_scene.import_hair``:
    the control points ``HeadScene`` renders (posed on ``vertices``) in ``<id>.npz`` and
    the shape's melanin as Mitsuba's absorption coefficient; added to ``scene.json``."""
    import json

    from hack_render.hair.style import EUMELANIN_SIGMA_A, PHEOMELANIN_SIGMA_A
    from hack_render.render.hair_shapes import control_points

    posed = head.pose_hair(vertices)
    specs = []
    for sh in head.hair_shapes:
        cp = control_points(posed[sh.group][sh.strands], head.hair.group(sh.group).radius)
        np.savez(folder / f"{sh.id}.npz", points=cp[..., :3], radius=cp[..., 3])
        sigma = sh.eumelanin * EUMELANIN_SIGMA_A + sh.pheomelanin * PHEOMELANIN_SIGMA_A
        spec = {"name": sh.id, "npz": f"{sh.id}.npz", "sigma_a": sigma.tolist(),
                "eumelanin": sh.eumelanin, "pheomelanin": sh.pheomelanin,
                "strands": int(cp.shape[0]), "points": int(cp.shape[1])}
        if melanin == "concentration":  # Cycles' melanin inputs of the same concentrations
            total = sh.eumelanin + sh.pheomelanin
            spec["melanin"] = float(1.0 - np.exp(-total))
            spec["melanin_redness"] = float(sh.pheomelanin / total) if total > 0 else 0.0
        specs.append(spec)
    path = folder / "scene.json"
    desc = json.loads(path.read_text())
    desc["hair"] = specs
    path.write_text(json.dumps(desc, indent=1))
    return specs


def psnr(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (img - ref) ** 2
    mse = float(d[mask].mean() if mask is not None else d.mean())
    return 10.0 * np.log10(1.0 / max(mse, 1e-20))


def feature_variants(head, k: int = 4) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """OIDN's (albedo, normal) for the ablation (``--ablation``): ``features`` as
    ``HeadScene.denoise`` gives them (``footprint.denoise_features``), ``bsdf`` the hair
    BSDF's diffuse reflectance and the curves' shading normal (before issue 61 section 3),
    ``turned`` the calibrated colour with the strand's normal turned to face the camera
    (perpendicular to its tangent), ``white`` an albedo of 1 with the camera direction."""
    import drjit as dr
    import mitsuba as mi

    from hack_render.render import footprint

    hair = [(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(b)), rgb)
            for b, rgb in footprint.hair_albedos(head)]

    def variant(kind):
        def values(layer):
            hit, ok, w, ray = layer.hit, layer.ok, layer.weight, layer.ray
            b = hit.bsdf(ray)
            albedo, normal = b.eval_diffuse_reflectance(hit, ok), hit.sh_frame.n
            ids = dr.reinterpret_array(mi.UInt32, b)
            for hid, rgb in hair if kind != "bsdf" else ():
                on = ok & (ids == hid)
                a = mi.Color3f(1.0) if kind == "white" else mi.Color3f(*map(float, rgb))
                albedo = dr.select(on, a, albedo)
                t = dr.normalize(hit.dp_du)
                turned = dr.normalize(-ray.d + dr.dot(ray.d, t) * t)
                normal = dr.select(on, turned if kind == "turned" else -ray.d, normal)
            albedo, normal = dr.select(ok, albedo * w, 0.0), dr.select(ok, normal * w, 0.0)
            return [albedo[c] for c in range(3)] + [normal[c] for c in range(3)]
        m = footprint.footprint_means(head, k, head.see_through_cards, values)
        return np.stack(m[:3], -1), np.stack(m[3:], -1)

    out = {"features": footprint.denoise_features(head, k, head.see_through_cards)}
    out.update({kind: variant(kind) for kind in ("bsdf", "turned", "white")})
    return out


def benchmark(bpy_python: str, bpy_version: str, size: int, style: str, ladder, dn_ladder,
              ref_spp: int, repeats: int, still: Path | None, out: str | None,
              melanin: str = "concentration", ablation=()) -> dict:
    from hack_render.hair.groom import grow_cached
    from hack_render.hair.regions import HeadSurface
    from hack_render.hair.style import HairStyle
    from hack_render.io.image import to_srgb8
    from hack_render.render.cli import denoise_settings
    from hack_render.render.parts import REGIONS
    from hack_render.render.scene import HeadScene, RenderSettings, composite

    say, printed = transcript()
    sc = cycles_comparison_scene(size)
    v, topo, maps, rig, cam = sc.v, sc.topo, sc.maps, sc.rig, sc.cam
    t0 = time.perf_counter()
    groom = grow_cached(HeadSurface.from_model(sc.model), HairStyle.archetype_style(style,
                                                                                    lod=1.0))
    counts = ", ".join(f"{g.name} {g.num_strands} x {g.points_per_strand}"
                       for g in groom.groups)

    def ours(spp: int, denoise: bool = False) -> HeadScene:
        # denoised: the box pixel filter `render --denoise` uses (cli.denoise_settings)
        return HeadScene(topo, v, rig, cam,
                         denoise_settings(RenderSettings(size, size, spp), denoise), maps,
                         hair=groom)

    say(f"scene: default head, alpha 0.8,-0.6,0.4, portrait, studio, {size} px, depth 8, "
        f"ours {RenderSettings().integrator}, gaussian filter; {os.cpu_count()} CPUs "
        f"(load average {os.getloadavg()[0]:.1f}); Cycles {bpy_version} (CPU) in {bpy_python}")
    say(f"groom: {style} at lod 1 ({counts}), grown in {time.perf_counter() - t0:.1f} s")
    rows: list[dict] = []
    images: dict[tuple, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        head = ours(1)
        bg = head.backdrop()
        seg = head.aovs()["segmentation"]
        mask = seg == REGIONS.index("hair")
        say(f"hair region: {int(mask.sum())} of {mask.size} pixels "
            f"({100.0 * mask.mean():.1f} %; pixel centres whose first hit is a strand)")
        if ablation:
            ablate(ours, head, bg, mask, ablation, ref_spp, say)
            return {}
        write_cycles_scene(tmp, head, v, maps)
        specs = write_cycles_hair(tmp, head, v, melanin)
        say(f"shapes: {len(specs)} ({sum(s['strands'] for s in specs)} strands, "
            f"<= {max(s['points'] for s in specs)} points each); melanin mapping "
            f"'{melanin}': " + ("Cycles' Melanin = 1 - exp(-(eu + pheo)), Redness = pheo / "
                                "(eu + pheo), its own pigment spectra"
                                if melanin == "concentration" else
                                "Cycles' Absorption Coefficient = Mitsuba's sigma_a"))
        say("  " + "; ".join(f"{s['name']} (eu {s['eumelanin']:.2f}, pheo "
                             f"{s['pheomelanin']:.2f})" for s in specs[:3]) + "; ...")
        del head
        worker = start_cycles(bpy_python, tmp, say)
        try:
            refs, ref_info = {}, {}
            for name in ("ours", "ours_box", "cycles"):
                c0 = time.process_time()
                if name == "cycles":
                    rep, img = worker.render(ref_spp, 12345, False, tmp / "ref.exr")
                    cpu, spp = rep["cpu_s"], rep["spp"]
                else:
                    h = ours(ref_spp, name == "ours_box")
                    img = h.render(seed=12345, backdrop=False)
                    cpu, spp = time.process_time() - c0, h.settings.effective_spp
                    del h
                refs[name] = composite(img, bg)[..., :3]
                images[(name, "ref")] = refs[name]
                ref_info[name] = {"spp": spp, "cpu_s": cpu,
                                  "mean_rgb": refs[name].mean((0, 1)).tolist(),
                                  "hair_mean_rgb": refs[name][mask].mean(0).tolist()}
                say(f"reference {name}: {spp} spp, {cpu:.0f} CPU s; mean linear RGB "
                    f"{np.round(refs[name].mean((0, 1)), 4).tolist()}, hair region "
                    f"{np.round(refs[name][mask].mean(0), 4).tolist()}")
            ro, rc = refs["ours"][mask].mean(0), refs["cycles"][mask].mean(0)
            colour_ratio = (rc / ro).tolist()
            rest = refs["cycles"][~mask].mean(0) / refs["ours"][~mask].mean(0)
            say(f"hair colour, Cycles / ours (references, hair region): "
                f"{np.round(rc / ro, 3).tolist()}; the rest {np.round(rest, 3).tolist()}; "
                f"whole-image PSNR of one reference against the other "
                f"{psnr(refs['cycles'], refs['ours']):.1f} dB")

            def score(ref: np.ndarray, img: np.ndarray) -> dict[str, float]:
                rgb = composite(img, bg)[..., :3]
                return {"psnr": psnr(rgb, ref), "psnr_hair": psnr(rgb, ref, mask)}

            say("renderer  denoise   spp   CPU s  wall s  PSNR dB  hair dB")
            for denoise, spps in ((False, ladder), (True, dn_ladder)):
                for spp in spps:  # interleaved: our rung, then Cycles' rung
                    for name in ("ours", "cycles"):
                        # ours denoised: box filter, against the box filter's reference
                        ref = refs["ours_box" if name == "ours" and denoise else name]
                        if name == "ours":
                            h = ours(spp, denoise)
                            for seed in (1000, 1001):  # Dr.Jit's compiles, before timing
                                h.render(seed=seed, backdrop=False, denoise=denoise)
                        row, img = rung_row(name, h, worker, spp, denoise, repeats,
                                            tmp / "img.exr", partial(score, ref))
                        eff = row["spp"]
                        images[(name, eff, denoise)] = composite(img, bg)[..., :3]
                        rows.append(row)
                        say(f"{name:9s} {'OIDN' if denoise else '-':7s} {eff:5d} "
                            f"{row['cpu_s']:7.2f} {row['wall_s']:7.2f} {row['psnr']:8.2f} "
                            f"{row['psnr_hair']:8.2f}")
                        h = None
        finally:
            worker.close()
    say(f"load average (1 min) {os.getloadavg()[0]:.1f} after")

    def ladder_of(name: str, denoise: bool, region: str = "image") -> list[dict]:
        key = "psnr" if region == "image" else "psnr_hair"
        return [{**r, "psnr": r[key]} for r in rows
                if r["renderer"] == name and r["denoise"] == denoise]

    summary: dict = {}
    for region in ("image", "hair"):
        for tag, what in (("noisy", "both noisy"), ("oidn", "both denoised by OIDN"),
                          ("best", "each at its best, noisy or denoised, at each time")):
            if tag == "best":
                o = lower_envelope(ladder_of("ours", False, region),
                                   ladder_of("ours", True, region))
                c = lower_envelope(ladder_of("cycles", False, region),
                                   ladder_of("cycles", True, region))
            else:
                o = ladder_of("ours", tag == "oidn", region)
                c = ladder_of("cycles", tag == "oidn", region)
            if not o or not c:  # e.g. no denoised ladder
                continue
            say(f"{region} / {tag}: {what} (PSNR over the "
                f"{'whole image' if region == 'image' else 'hair region'})")
            summary[f"{region}_{tag}"] = compare_curves(o, c, say)
    say("ours / Cycles CPU time at equal PSNR, geometric mean (target <= 0.5x):")
    for key, s in summary.items():
        if "ratio_geomean" in s:
            say(f"  {key:12s} {s['ratio_geomean']:.2f}x (range {s['ratio_range'][0]:.2f}-"
                f"{s['ratio_range'][1]:.2f}x)")

    if still is not None:
        def caption(r):
            return (f"{'ours' if r['renderer'] == 'ours' else 'Cycles'} {r['spp']} spp"
                    f"{' + OIDN' if r['denoise'] else ''}, {r['cpu_s']:.2f} CPU s\n"
                    f"{r['psnr']:.1f} dB, hair {r['psnr_hair']:.1f} dB")

        grid = []
        for denoise, cyc_spp in ((False, 16), (True, 16)):
            cands = [r for r in rows if r["renderer"] == "cycles" and r["denoise"] == denoise]
            rc = min(cands, key=lambda r: abs(r["spp"] - cyc_spp))
            ro = min((r for r in rows if r["renderer"] == "ours" and r["denoise"] == denoise),
                     key=lambda r: abs(r["psnr"] - rc["psnr"]))  # equal noise
            grid.append([(to_srgb8(images[(r["renderer"], r["spp"], denoise)], 0.0, "aces"),
                          caption(r)) for r in (ro, rc)])
        grid.append([(to_srgb8(images[(name, "ref")], 0.0, "aces"),
                      f"{'ours' if name == 'ours' else 'Cycles'} reference\n{ref_spp} spp")
                     for name in ("ours", "cycles")])
        side_by_side(still, grid)
        say(f"wrote {still}")
    result = {"title": "Rendering: hair against Blender Cycles at equal noise (issue 61)",
              "settings": {"size": size, "style": style, "groom": counts, "ref_spp": ref_spp,
                           "repeats": repeats, "ladder": list(ladder),
                           "denoise_ladder": list(dn_ladder), "bpy": bpy_version,
                           "hair_pixels": int(mask.sum()), "melanin_mapping": melanin},
              "hair_colour_ratio_cycles_over_ours": colour_ratio,
              "references": ref_info, "rows": rows, "summary": summary, "printed": printed}
    if out:
        write_result(out, result)
    return result


def ablate(ours, head, bg, mask, spps, ref_spp, say) -> None:
    """Ours alone, denoised from each pixel filter with each set of features
    (:func:`feature_variants`), against each filter's ``ref_spp`` reference: PSNR over
    the image and over the hair region (seed 1, one render per rung)."""
    from hack_render.render import denoise as dn
    from hack_render.render.scene import composite

    refs = {}
    for box in (False, True):
        refs[box] = composite(ours(ref_spp, box).render(seed=12345, backdrop=False),
                              bg)[..., :3]
    say(f"ablation: ours + OIDN against {ref_spp}-spp references of the same filter; "
        "PSNR dB, image / hair")
    for spp in spps:
        for box in (False, True):
            h = ours(spp, box)
            img = h.render(seed=1, backdrop=False)
            line = [f"{spp:4d} spp {'box' if box else 'gaussian':8s}"]
            noisy = composite(img, bg)[..., :3]
            line.append(f"noisy {psnr(noisy, refs[box]):.2f} / "
                        f"{psnr(noisy, refs[box], mask):.2f}")
            for kind, (albedo, normal) in feature_variants(h).items():
                out = img.copy()
                den = dn.denoise(img[..., :3], albedo, normal)
                out[..., :3] = np.where(img[..., 3:4] > 0, den, 0.0)
                rgb = composite(out, bg)[..., :3]
                line.append(f"{kind} {psnr(rgb, refs[box]):.2f} / "
                            f"{psnr(rgb, refs[box], mask):.2f}")
            say("  " + "; ".join(line))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blender-python", default=None, help="a Python with bpy "
                    "(default $HACK_RENDER_BPY_PYTHON)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--style", default="short", help="hair archetype, grown at lod 1")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--ladder", default="4,8,16,32,64,128")
    ap.add_argument("--denoise-ladder", default="2,4,8,16,32,64")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--melanin", choices=("concentration", "absorption"),
                    default="concentration", help="how Cycles gets our melanin: its own "
                    "Melanin inputs of the same concentrations, or Mitsuba's sigma_a")
    ap.add_argument("--still", default="docs/images/hair_vs_cycles.png",
                    help="the side-by-side still ('' for none)")
    ap.add_argument("--out", default="bench/results/render_hair_cycles.json",
                    help="the result file ('' for none)")
    ap.add_argument("--ablation", default="", help="spp list: only ours, denoised from "
                    "each pixel filter with each set of hair features (no Cycles, no files)")
    args = ap.parse_args()
    exe, version = blender_python(args.blender_python)  # exits 2 without bpy
    from hack_render.render.engine import ensure_variant

    print(f"variant: {ensure_variant(None)}")
    benchmark(exe, version, args.size, args.style, [int(x) for x in args.ladder.split(",")],
              [int(x) for x in args.denoise_ladder.split(",") if x], args.ref_spp,
              args.repeats, Path(args.still) if args.still else None, args.out or None,
              args.melanin, [int(x) for x in args.ablation.split(",") if x])


if __name__ == "__main__":
    main()
