"""`hack-render render` and `hack-render turntable`.

The options the two commands share (pose, skin, lighting, image) are declared once in
:mod:`hack_render.cli_options`. numpy and everything heavier are imported inside the
commands, so `--help` stays fast.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from hack_render import cli_options as opts
from hack_render.errors import HackError

if TYPE_CHECKING:
    import numpy as np

_AOVS = ("depth", "normal", "albedo", "uv", "segmentation")

SamplerOpt = typer.Option("auto", "--sampler", help="Mitsuba sampler: auto (orthogonal "
                          "arrays near 25, 49, 121... spp, else multijitter), multijitter, "
                          "stratified, orthogonal, ldsampler or independent. All but "
                          "independent round --spp (said when they do); see docs/render.md.")
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
    import warnings

    from hack_render.render import denoise as dn

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
    import dataclasses

    return dataclasses.replace(settings, pixel_filter="box") if use_denoise else settings


def _resolution(text: str) -> tuple[int, int]:
    try:
        parts = [int(x) for x in text.lower().replace("x", ",").split(",") if x.strip()]
    except ValueError as err:
        raise HackError(f"--resolution: expected 'W' or 'WxH' in pixels, found {text!r}.") from err
    if len(parts) not in (1, 2):
        raise HackError(f"--resolution: expected 'W' or 'WxH', found {text!r}.")
    from hack_render.render.scene import MAX_SIDE

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
    from hack_render.boundary import numbers

    return numbers(text, f"--{name}", n, lo, hi)


def check_look(env_rotation: float, exposure: float, focal_mm: float | None,
               alpha: str | None, appearance_seed: int | None) -> list[float] | None:
    """The lighting, lens and skin options that `render` and `turntable` share, checked
    (finite, in range) before anything heavy; returns alpha as numbers."""
    from hack_render import boundary as b

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
    import numpy as np

    from hack_render.render.image_io import rgb_channels

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
    from hack_render.geometry.posing import posed_vertices
    from hack_render.render.parts import Topology

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
    spp: opts.Spp = 64,
    seed: opts.Seed = 0,
    max_depth: int = typer.Option(8, help="Maximum path length."),
    iris_color: str | None = typer.Option(None, help="Iris linear RGB, e.g. '0.1,0.2,0.3'."),
    tonemap: opts.Tonemap = "aces",
    variant: opts.Variant = None,
    quiet: opts.Quiet = False,
    sampler: str = SamplerOpt,
    integrator: str = IntegratorOpt,
    denoise: str = DenoiseOpt,
    keep_noisy: bool = KeepNoisyOpt,
    sss: bool = SssOpt,
) -> None:
    """Render the head model to a PNG and/or an EXR with AOVs; cameras go to a JSON (OpenCV).

    Example: hack-render render -o out/head.png --exr out/head.exr --aov all --spp 64
    """
    import numpy as np

    from hack_render import boundary
    from hack_render.geometry.cli import LimitPolicy
    from hack_render.render.image_io import tone_map
    from hack_render.render.scene import MAX_SPP, RenderSettings
    from scenes import cameras as cams
    from scenes import lights

    # every cheap check before anything heavy is loaded or allocated
    w, h = _resolution(resolution)
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
    try:
        policy = LimitPolicy(limits)
    except ValueError as err:
        raise HackError(f"--limits: expected warn, clamp or error, found {limits!r}.") from err

    from hack_render.render import posed_cache

    # a repeated pose comes from the disk cache: no torch import, no model evaluation
    topo, verts = posed_cache.posed(
        {"params_file": params, "beta": beta, "expression": expression,
         "head_rotation": head_rotation, "eta": eta, "tau": tau, "limits": limits},
        model_path, lambda: _model_vertices(params, beta, expression, head_rotation, eta,
                                            tau, policy, model_path))
    from hack_render.render.scene import HeadScene
    from hack_render.render.skin_maps import skin_maps

    maps = skin_maps(alpha_, appearance_seed, textures)
    head = HeadScene(topo, verts, rig, views_[0], settings, maps, iris, variant)
    if settings.spp_note():
        typer.echo(settings.spp_note(), err=True)
    outputs = []
    if len(views_) > 1:
        typer.echo(f"render: {len(views_)} views of {w}x{h} at {spp} spp", err=True)
    with boundary.on_interrupt(lambda: f"kept {len(outputs)} finished image(s) of "
                               f"{len(views_) * (1 + (exr is not None))}; run the command "
                               "again to render them all"):
        _render_views(head, views_, output, exr, aov_names, tonemap, quiet, outputs,
                      use_denoise, keep_noisy, sss)
    cam_json = output.with_name(f"{output.stem}.cameras.json")
    cams.save_cameras(cam_json, views_)
    for target in outputs + [cam_json]:
        typer.echo(f"wrote {target.resolve()}")


def _render_views(head, views_, output, exr, aov_names, tonemap, quiet, outputs,
                  use_denoise: bool = False, keep_noisy: bool = False,
                  sss: bool = False) -> None:
    """Render each camera of ``views_`` to ``output`` (and ``exr``), appending the paths
    written to ``outputs``; denoised when ``use_denoise`` (the noisy image kept as
    ``<name>.noisy.<ext>`` with ``keep_noisy``)."""
    import json

    from hack_render.render.image_io import write_exr, write_png

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


def turntable(
    output: Path = typer.Option(Path("out/turntable"), "-o", "--output",
                                help="Output folder: turntable.mp4, turntable.gif, frames/."),
    frames: int = typer.Option(48, help="Number of frames in the loop (no duplicated end frame)."),
    mode: str = typer.Option("orbit", help="orbit (camera circles) or subject (head turns)."),
    look_around: bool = typer.Option(False, "--look-around", help="Animate the neck: a "
                                     "look-around shared over the 8 joints within their limits."),
    swallow: bool = typer.Option(False, "--swallow", help="Animate a swallow: the larynx "
                                 "tau curve averaged from aligned swallows (it says which)."),
    formats: str = typer.Option("mp4,gif", help="Any of mp4, gif, frames (PNG frames are "
                                "always kept in <out>/frames for --resume)."),
    fps: int = typer.Option(24, help="Frames per second."),
    resume: bool = typer.Option(False, "--resume", help="Skip frames already in <out>/frames "
                                "(refused when the arguments differ from theirs: "
                                "<out>/turntable.json)."),
    sequence: Path | None = typer.Option(None, "--sequence", help="Also write the head "
                                            "motion (look-around, swallow) as a parameter "
                                            "sequence, .npz or .jsonl, for `hack-render export "
                                            "--sequence`."),
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
    focal_mm: float = typer.Option(85.0, "--focal-mm", help="Focal length, mm."),
    pitch: float = typer.Option(5.0, help="Camera elevation, degrees."),
    resolution: opts.Resolution = "256",
    spp: opts.Spp = 32,
    seed: opts.Seed = 0,
    tonemap: opts.Tonemap = "aces",
    variant: opts.Variant = None,
    quiet: opts.Quiet = False,
    sampler: str = SamplerOpt,
    integrator: str = IntegratorOpt,
    denoise: str = DenoiseOpt,
    keep_noisy: bool = KeepNoisyOpt,
    sss: bool = SssOpt,
) -> None:
    """Render a seamless looping turntable of the head to MP4 (H.264) / GIF / PNG frames.

    Example: hack-render turntable -o out/turntable --frames 48 --look-around --swallow
    """
    import imageio.v3 as iio
    import numpy as np
    import torch
    from tqdm import tqdm

    from hack_render import boundary
    from hack_render.geometry.cli import gather_params
    from hack_render.geometry.params import model_inputs
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render import turntable as tt
    from hack_render.render.image_io import atomic_path, to_srgb8
    from hack_render.render.scene import HeadScene, RenderSettings
    from hack_render.render.skin_maps import skin_maps
    from hack_render.render.video import write_gif, write_mp4
    from scenes import cameras as cams
    from scenes import lights

    spec = tt.TurntableSpec(frames, mode, 360.0, look_around, swallow, fps)
    from hack_render.render.scene import MAX_SPP

    w, h = _resolution(resolution)
    boundary.number(spp, "--spp", 1, MAX_SPP, integer=True)
    boundary.number(seed, "--seed", 0, 2 ** 31 - 1 - frames, integer=True)
    named("--integrator", RenderSettings, integrator=integrator)
    settings = named("--sampler", RenderSettings, w, h, spp, 8, seed, sampler=sampler,
                     integrator=integrator)
    use_denoise = check_denoise(denoise)
    settings = denoise_settings(settings, use_denoise)
    fmt = [f.strip() for f in formats.split(",") if f.strip()]
    bad = [f for f in fmt if f not in tt.FORMATS]
    if bad or not fmt:
        raise HackError(f"--formats: expected some of {', '.join(tt.FORMATS)}, found {formats!r}.")
    if "mp4" in fmt and (w % 2 or h % 2):
        raise HackError(f"--resolution: expected even width and height for MP4 (yuv420p), "
                        f"found {w}x{h}.")
    boundary.output_dir(output)
    if sequence is not None:
        boundary.output_file(sequence, "--sequence", (".npz", ".jsonl", ".ndjson"))
    named("--tonemap", to_srgb8, np.zeros((1, 1, 3)), 0.0, tonemap)
    boundary.number(pitch, "--pitch", -89.0, 89.0, unit=" degrees")
    alpha_ = check_look(env_rotation, exposure, focal_mm, alpha, appearance_seed)
    rig = named("--lighting", lights.preset, lighting, env_rotation, exposure)

    from hack_render.geometry import load_model
    from hack_render.geometry.cli import LimitPolicy, apply_limit_policy
    from hack_render.render.parts import Topology

    try:
        policy = LimitPolicy(limits)
    except ValueError as err:
        raise HackError(f"--limits: expected warn, clamp or error, found {limits!r}.") from err
    model = load_model(model_path)
    p = gather_params(params, beta, expression, head_rotation, eta, tau)
    base = apply_limit_policy(model_inputs(model, p), policy, p.get("head_rotation_deg"))
    topo = Topology.from_model(model)
    # everything that decides the frames' pixels: a resume with anything else is refused
    record = boundary.RunRecord(output, "turntable", {
        **p, "model": boundary.file_identity(model_path) or "built-in",
        "alpha": alpha_, "appearance_seed": appearance_seed,
        "textures": boundary.file_identity(textures), "lighting": lighting,
        "env_map": boundary.file_identity(rig.env_file) if lighting.startswith("env:") else None,
        "env_rotation": env_rotation, "exposure": exposure, "focal_mm": focal_mm,
        "pitch": pitch, "resolution": [w, h], "spp": spp, "seed": seed, "tonemap": tonemap,
        "variant": variant, "limits": limits, "frames": frames, "mode": mode,
        "sampler": sampler, "integrator": integrator, "denoise": use_denoise, "sss": sss,
        "look_around": look_around,
        "swallow": swallow}, name="turntable.json")

    def vertices_at(i: int) -> np.ndarray:
        kw = dict(base)
        t = spec.phase(i)
        if look_around:
            ang = torch.deg2rad(torch.tensor(tt.head_angles_deg(t), dtype=base["theta"].dtype))
            kw["theta"] = base["theta"] + distribute_head_rotation(ang)[None]
        if swallow:
            kw["tau"] = torch.tensor([tt.swallow_tau(t)], dtype=base["theta"].dtype)
        with torch.no_grad():
            v = model(**kw).vertices[0].double().numpy()
        if mode == "subject":
            v = tt.rotate_about_y(v, spec.yaw_deg(i), cams.DEFAULT_TARGET)
        return v

    def camera_at(i: int):
        yaw = spec.yaw_deg(i) if mode == "orbit" else 0.0
        return cams.orbit(w, h, focal_mm, yaw, pitch, name=f"frame_{i:04d}")

    def kept() -> str:
        return (f"kept {tt.frames_on_disk(output)} of {frames} frames in {output / 'frames'}; "
                "run the same command with --resume to finish")

    with boundary.folder_lock(output), boundary.on_interrupt(kept):
        record.check_resume(resume, tt.frames_on_disk(output) > 0)
        if not resume:  # frames of another run must not be taken for this one's later
            for old in (output / "frames").glob("frame_*.png"):
                old.unlink()
        record.write(complete=False)
        if sequence is not None:
            from hack_render.geometry.params import save_sequence

            tau0 = float(base["tau"][0]) if "tau" in base else 0.0
            motion = tt.motion_sequence(spec, base["theta"][0].numpy(), base["psi"][0].numpy(),
                                        tau0)
            typer.echo(f"wrote {save_sequence(sequence, motion).resolve()}")
        if swallow:
            typer.echo(tt.swallow_source())
        todo = tt.pending_frames(output, frames, resume)
        if todo:
            typer.echo(f"turntable: {len(todo)} of {frames} frames to render, {w}x{h}, "
                       f"{settings.effective_spp} spp ({settings.sampler_label}"
                       f"{', denoised' if use_denoise else ''}{', sss' if sss else ''})")
            if settings.spp_note():
                typer.echo(settings.spp_note(), err=True)
            head = HeadScene(topo, vertices_at(0), rig, camera_at(0), settings,
                             skin_maps(alpha_, appearance_seed, textures), None, variant)
            times, animated = [], look_around or swallow or mode == "subject"
            pending, bar = set(todo), tqdm(total=len(todo), desc="turntable", unit="frame",
                                           disable=quiet)
            # The scene goes through every frame's changes from frame 0, rendering only the
            # pending frames: Mitsuba's state after an update (the acceleration structure,
            # the environment's bounds) depends on the updates before it, so a resumed
            # run replays the skipped frames' updates to render the same bytes as an
            # uninterrupted one (one started at its first pending frame differed in a few
            # pixels of later frames by up to 6/255).
            for i in range(max(todo) + 1):
                t0 = time.perf_counter()
                if animated:
                    head.set_vertices(vertices_at(i), update=False)
                head.set_camera(camera_at(i))
                if animated:
                    head.sync_environment()
                if i not in pending:
                    continue
                bare = head.render(seed=seed + i, backdrop=False, sss=sss)
                img = head.composite(head.denoise(bare) if use_denoise else bare)
                if use_denoise and keep_noisy:
                    noisy = tt.frame_path(output, i, "noisy")
                    with atomic_path(noisy) as tmp:
                        iio.imwrite(tmp, to_srgb8(head.composite(bare)[..., :3], 0.0,
                                                  tonemap), extension=".png")
                with atomic_path(tt.frame_path(output, i)) as tmp:
                    iio.imwrite(tmp, to_srgb8(img[..., :3], 0.0, tonemap), extension=".png")
                times.append(time.perf_counter() - t0)
                bar.update()
                if len(times) == 2 and len(todo) > 2:  # the first frame compiles: no rate
                    typer.echo(boundary.estimate_line("turntable", times[1], len(todo) - 2,
                                                      "frame"), err=True)
            bar.close()
            if len(times) > 1:
                typer.echo(f"frame times: first {times[0]:.2f} s, later mean "
                           f"{np.mean(times[1:]):.2f} s ({head.variant})")
        else:
            typer.echo(f"all {frames} frames already in {output / 'frames'} (--resume)")
        seq = [iio.imread(tt.frame_path(output, i)) for i in range(frames)]
        written = []
        if "mp4" in fmt:
            written.append(write_mp4(output / "turntable.mp4", seq, fps))
        if "gif" in fmt:
            written.append(write_gif(output / "turntable.gif", seq, fps))
        cams.save_cameras(output / "cameras.json", [camera_at(i) for i in range(frames)])
        record.write(complete=True)  # the completion marker, last
    for path in written + [output / "cameras.json"]:
        typer.echo(f"wrote {path.resolve()}")


def register(app: typer.Typer) -> None:
    """Add `render` and `turntable` to the main app."""
    app.command("render")(render)
    app.command("turntable")(turntable)
