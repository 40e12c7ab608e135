"""`hack-render render`, and the checks and options it shares with `hack-render turntable`
(:mod:`hack_render.render.turntable_cli`).

The options the two commands share (pose, skin, lighting, image) are declared once in
:mod:`hack_render.cli_options`. numpy and everything heavier are imported inside the
commands, so `--help` stays fast.
"""

from __future__ import annotations

import dataclasses
import json
import re
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import typer

from hack_render import boundary, interrupts
from hack_render import boundary as b
from hack_render import cli_options as opts
from hack_render.boundary import numbers
from hack_render.errors import HackError
from hack_render.geometry.limits import limit_policy
from hack_render.geometry.model_file import default_model_path, load_model_file
from hack_render.geometry.params import load_params
from hack_render.geometry.posing import posed_vertices
from hack_render.io.image import rgb_channels, tone_map, write_exr, write_png
from hack_render.render import denoise as dn
from hack_render.render import posed_cache
from hack_render.render.hair_options import HairColorOpt, groom_of, hair_option, hair_style
from hack_render.render.parts import Topology
from hack_render.render.skin_maps import skin_maps
from hack_render.threads import check_threads, command_threads
from scenes import cameras as cams
from scenes import lights

if TYPE_CHECKING:
    import numpy as np

_AOVS = ("depth", "normal", "albedo", "uv", "segmentation")

SamplerOpt = typer.Option("auto", "--sampler", help="Mitsuba sampler: auto (orthogonal "
                          "arrays at 25, 49, 121... spp and a little under, else "
                          "multijitter), multijitter, stratified, orthogonal, ldsampler or "
                          "independent. All but independent round --spp up, never down (said "
                          "when they do); see docs/render.md.")
IntegratorOpt = typer.Option("hack_path", "--integrator", help="Integrator: hack_path or "
                             "volpath (shadow rays see through the lashes' transparent parts: "
                             "less noise around the eyes; the same image, hack_path 1.3-2.9x "
                             "faster at equal noise on a head) or path (faster per sample, grainy under the "
                             "lashes); see docs/render.md.")
DenoiseOpt = typer.Option("auto", "--denoise", help="Intel Open Image Denoise with albedo "
                          "and normal AOVs: auto (if the 'denoise' extra is installed, else "
                          "the noisy image with a warning), on (refuse without it), off.")
SssOpt = typer.Option(True, "--sss/--no-sss", help="Subsurface scattering in the skin "
                      "(the skin profile diffuses its light in screen space; twice the "
                      "render time; JIT variants): see docs/render.md.")
KeepNoisyOpt = typer.Option(False, "--keep-noisy", help="Also keep the image before "
                            "denoising (render: <name>.noisy.<ext>; turntable: noisy/).")


def check_denoise(denoise: str) -> bool:
    """--denoise resolved to yes/no (HackError naming the extra when 'on' cannot run; a
    one-line warning on stderr when 'auto' falls back to the noisy image)."""

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.DenoiserWarning)
        use = named("--denoise", dn.resolve, denoise)
    for w in caught:
        typer.echo(f"warning: {w.message}", err=True)
    return use


def denoise_settings(settings, use_denoise: bool):
    """The render settings for a denoised image: a box pixel filter, each sample in one
    pixel. Mitsuba's Gaussian filter spreads samples over neighbours, and OIDN keeps the
    noise that is correlated between pixels: on the studio portrait at 128 px, 4 / 8 spp
    denoised reach 35.7 / 36.6 dB from a box-filtered render against 33.3 / 31.5 dB
    (``bench_render.py --only quality``, each against its own filter's reference)."""
    return dataclasses.replace(settings, pixel_filter="box") if use_denoise else settings


def rendered(settings) -> dict:
    """What a render's metadata records of its sampling (the cameras JSON's ``render``):
    the sampler and samples per pixel rendered, and the count asked for."""
    return {"sampler": settings.mitsuba_sampler, "spp": settings.effective_spp,
            "spp_requested": settings.spp}


#: 'W' or 'WxH' (also 'W,H', as before)
_RESOLUTION = re.compile(r"(\d+)\s*(?:[xX,]\s*(\d+))?")


def parse_resolution(text: str) -> tuple[int, int]:
    """``--resolution`` 'W' or 'WxH' as (width, height), checked: whole numbers only, one
    or two of them ('64x', 'x64' and '64x64x' are refused, not read as a square)."""
    from hack_render.render.scene import MAX_SIDE

    match = _RESOLUTION.fullmatch(text.strip())
    if match is None:
        raise HackError(f"--resolution: expected 'W' or 'WxH' in whole pixels (e.g. 512 or "
                        f"640x480), found {text!r}.")
    parts = [int(x) for x in match.groups() if x is not None]

    if not all(1 <= p <= MAX_SIDE for p in parts):
        raise HackError(f"--resolution: expected sides of 1..{MAX_SIDE} pixels, found "
                        f"{text!r}. Pass e.g. --resolution 512.")
    return (parts[0], parts[-1])


def named(option: str, fn, *args, **kwargs):
    """``fn(*args)``, its HackError prefixed with the option it came from."""
    try:
        return fn(*args, **kwargs)
    except HackError as err:
        if str(err).startswith(option):
            raise
        raise HackError(f"{option}: {err}") from err


def _floats(text: str | None, name: str, n: int | None = None, lo: float = -1e3,
            hi: float = 1e3) -> list[float] | None:
    return numbers(text, f"--{name}", n, lo, hi)


def check_look(env_rotation: float, exposure: float, focal_mm: float | None,
               alpha: str | None, appearance_seed: int | None) -> list[float] | None:
    """The lighting, lens and skin options that `render` and `turntable` share, checked
    (finite, in range) before anything heavy; returns alpha as numbers."""
    b.number(env_rotation, "--env-rotation", -3600.0, 3600.0, unit=" degrees")
    b.number(exposure, "--exposure", -20.0, 20.0, unit=" stops",
             fix="Each stop doubles the light; -3..3 covers most uses.")
    b.number(focal_mm, "--focal-mm", 5.0, 2000.0, unit=" mm (36 mm sensor)")
    b.number(appearance_seed, "--appearance-seed", 0, 2 ** 31 - 1, integer=True)
    return b.numbers(alpha, "--alpha", None, -10.0, 10.0, unit=" (standard deviations)",
                     example="0.8,-0.6,0.4")


def _aov_list(text: str | None) -> list[str]:
    if not text:
        return []
    names = list(_AOVS) if text.strip() == "all" else [s.strip() for s in text.split(",") if s.strip()]
    bad = [n for n in names if n not in _AOVS]
    if bad:
        raise HackError(f"--aov: expected names from {', '.join(_AOVS)} or 'all', found {bad}.")
    return names


def exr_channels(image: np.ndarray, aovs: dict[str, np.ndarray], names: list[str]) -> dict:
    """EXR channel dict: R, G, B, A then the requested AOV layers."""

    ch = rgb_channels(image[..., :3])
    ch["A"] = image[..., 3]
    layout = {"depth": ("Z",), "normal": ("X", "Y", "Z"), "albedo": ("R", "G", "B"),
              "uv": ("U", "V"), "segmentation": ("I",)}
    for name in names:
        a = aovs[name]
        a = a[..., None] if a.ndim == 2 else a
        for k, c in enumerate(layout[name]):
            ch[f"{name}.{c}"] = a[..., k].astype(np.float32)
    return ch


def _model_vertices(params_file, beta, expression, head_rotation, eta, tau, limits, model_path):
    """(topology, posed vertices) of the pose flags, posed with NumPy (no torch import)."""
    model, verts = posed_vertices(params_file, beta, expression, head_rotation, eta, tau,
                                  limits, model_path)
    return Topology.from_model(model), verts


def render(
    output: Path = typer.Option(Path("out/render.png"), "-o", "--output",
                                help="Image to write: .png (sRGB, tone mapped) or .exr (linear "
                                     "float32 with optional AOV channels)."),
    exr: Path | None = typer.Option(None, "--exr", help="Also write a linear EXR here."),
    aov: str | None = typer.Option(None, "--aov", help="AOV channels for the EXR: "
                                      "depth,normal,albedo,uv,segmentation or 'all'."),
    params: opts.Params = None,
    beta: opts.Beta = None,
    expression: opts.Expression = None,
    head_rotation: opts.HeadRotation = None,
    eta: opts.Eta = None,
    tau: opts.Tau = None,
    limits: opts.Limits = "warn",
    model_path: opts.ModelPath = None,
    alpha: opts.Alpha = None,
    appearance_seed: opts.AppearanceSeed = None,
    textures: opts.Textures = None,
    lighting: opts.Lighting = "studio",
    env_rotation: opts.EnvRotation = 0.0,
    exposure: opts.Exposure = 0.0,
    camera: str = typer.Option("portrait", help="portrait, three_quarter, profile or ring."),
    focal_mm: float | None = typer.Option(None, "--focal-mm", help="Focal length (36 mm "
                                             "sensor width); default 85 (ring: 50)."),
    views: int = typer.Option(8, help="Number of cameras of the ring preset."),
    resolution: opts.Resolution = "512",
    spp: opts.Spp = 49,
    seed: opts.Seed = 0,
    max_depth: int = typer.Option(8, help="Maximum path length."),
    iris_color: str | None = typer.Option(None, help="Iris linear RGB, e.g. '0.1,0.2,0.3'."),
    tonemap: opts.Tonemap = "aces",
    variant: opts.Variant = None,
    quiet: opts.Quiet = False,
    threads: opts.Threads = None,
    sampler: str = SamplerOpt,
    integrator: str = IntegratorOpt,
    denoise: str = DenoiseOpt,
    keep_noisy: bool = KeepNoisyOpt,
    sss: bool = SssOpt,
    hair: str | None = hair_option("none"),
    hair_color: str | None = HairColorOpt,
) -> None:
    """Render the head model to a PNG and/or an EXR with AOVs; cameras go to a JSON (OpenCV).

    Example: hack-render render -o out/head.png --exr out/head.exr --aov all --spp 121

    With hair: hack-render render -o out/head.png --hair long --hair-color auburn
    """
    from hack_render.render.scene import MAX_SPP, HeadScene, RenderSettings

    # every cheap check before anything heavy is loaded or allocated
    w, h = parse_resolution(resolution)
    boundary.number(spp, "--spp", 1, MAX_SPP, integer=True)
    boundary.number(seed, "--seed", 0, 2 ** 31 - 1, integer=True)
    boundary.number(max_depth, "--max-depth", 1, 64, integer=True)
    boundary.number(views, "--views", 1, 1024, integer=True)
    named("--integrator", RenderSettings, integrator=integrator)
    settings = named("--sampler", RenderSettings, w, h, spp, max_depth, seed,
                     sampler=sampler, integrator=integrator)
    use_denoise = check_denoise(denoise)
    settings = denoise_settings(settings, use_denoise)
    aov_names = _aov_list(aov)
    boundary.output_file(output, "-o/--output", (".png", ".exr"))
    if exr is not None:
        boundary.output_file(exr, "--exr", (".exr",))
    if aov_names and exr is None and output.suffix.lower() != ".exr":
        raise HackError("--aov: expected an EXR output to hold the AOV channels (-o x.exr or "
                        "--exr x.exr), found only a PNG.")
    named("--tonemap", tone_map, np.zeros(3), 0.0, tonemap)
    alpha_ = check_look(env_rotation, exposure, focal_mm, alpha, appearance_seed)
    rig = named("--lighting", lights.preset, lighting, env_rotation, exposure)
    views_ = named("--camera", cams.preset, camera, w, h, focal_mm, n=views)
    iris = _floats(iris_color, "iris-color", 3, 0.0, 1.0)
    policy = limit_policy(limits)
    style = hair_style(hair, hair_color, _params_hair(params))
    if threads is not None:
        check_threads(threads)
    command_threads(threads)

    # a repeated pose comes from the disk cache: no torch import, no model evaluation
    topo, verts = posed_cache.posed(
        {"params_file": params, "beta": beta, "expression": expression,
         "head_rotation": head_rotation, "eta": eta, "tau": tau, "limits": limits},
        model_path, lambda: _model_vertices(params, beta, expression, head_rotation, eta,
                                            tau, policy, model_path))

    maps = skin_maps(alpha_, appearance_seed, textures)
    if style is not None and maps.brows_baked and style.brow_density > 0:
        # a fit's textures that hold the photo's brows: no strand brows drawn over them
        style = dataclasses.replace(style, brow_density=0.0)
        typer.echo("render: the textures hold the brows (skin.json): no brow strands",
                   err=True)
    groom = groom_of(style, _model_arrays(model_path)) if style is not None else None
    head = HeadScene(topo, verts, rig, views_[0], settings, maps, iris, variant, hair=groom)
    if settings.spp_note():
        typer.echo(settings.spp_note(), err=True)
    outputs = []
    if len(views_) > 1:
        typer.echo(f"render: {len(views_)} views of {w}x{h} at {settings.effective_spp} spp",
                   err=True)
    with interrupts.on_interrupt(lambda: f"kept {len(outputs)} finished image(s) of "
                               f"{len(views_) * (1 + (exr is not None))}; run the command "
                               "again to render them all"):
        _render_views(head, views_, output, exr, aov_names, tonemap, quiet, outputs,
                      use_denoise, keep_noisy, sss)
    cam_json = output.with_name(f"{output.stem}.cameras.json")
    cams.save_cameras(cam_json, views_, rendered(head.settings))
    for target in outputs + [cam_json]:
        typer.echo(f"wrote {target.resolve()}")


def _params_hair(params_file):
    """The parameter file's ``hair`` section (None without a file or a section)."""
    if params_file is None:
        return None
    return load_params(params_file).get("hair")


def _model_arrays(model_path) -> dict:
    """The model file's arrays (the hair grows on its mean rest mesh), without torch."""
    return load_model_file(model_path if model_path is not None else default_model_path())[0]


def _render_views(head, views_, output, exr, aov_names, tonemap, quiet, outputs,
                  use_denoise: bool = False, keep_noisy: bool = False,
                  sss: bool = False) -> None:
    """Render each camera of ``views_`` to ``output`` (and ``exr``), appending the paths
    written to ``outputs``; denoised when ``use_denoise`` (the noisy image kept as
    ``<name>.noisy.<ext>`` with ``keep_noisy``)."""

    for cam in views_:
        head.set_camera(cam)
        t0 = time.perf_counter()
        bare = head.render(progress=not quiet, backdrop=False, sss=sss)
        images = {"": head.composite(bare)}
        if use_denoise:
            images = {"": head.composite(head.denoise(bare)),
                      **({".noisy": images[""]} if keep_noisy else {})}
        dt = time.perf_counter() - t0
        suffix = "" if len(views_) == 1 else f"_{cam.name}"
        aovs = head.aovs() if aov_names else {}
        for tag, image in images.items():
            for path in [output] + ([exr] if exr else []):
                target = path.with_name(f"{path.stem}{suffix}{tag}{path.suffix}")
                if target.suffix.lower() == ".png":
                    write_png(target, image[..., :3], operator=tonemap)
                else:
                    meta = {"hack_camera": json.dumps(cam.to_dict()),
                            "hack_regions": ",".join(head.region_names),
                            "hack_variant": head.variant,
                            "hack_denoised": "yes" if use_denoise and not tag else "no",
                            "hack_sss": "yes" if sss else "no",
                            "hack_pixel_filter": head.settings.pixel_filter,
                            "hack_integrator": head.integrator_name,
                            "hack_sampler": head.settings.mitsuba_sampler,
                            "hack_spp": str(head.settings.effective_spp)}
                    write_exr(target, exr_channels(image, aovs, aov_names), meta)
                outputs.append(target)
        st = head.settings
        extras = (", denoised" if use_denoise else "") + (", sss" if sss else "")
        typer.echo(f"{cam.name}: {st.width}x{st.height}, {st.effective_spp} spp "
                   f"({st.sampler_label}{extras}), {dt:.1f} s ({head.variant})")


def register(app: typer.Typer) -> None:
    """Add `render` to the main app (`turntable`: :mod:`hack_render.render.turntable_cli`)."""
    app.command("render")(render)
