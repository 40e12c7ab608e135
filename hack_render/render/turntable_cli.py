"""`hack-render turntable`: a seamless looping turntable of the head (MP4, GIF, PNG frames).

Its options and checks are `render`'s (:mod:`hack_render.render.cli`,
:mod:`hack_render.cli_options`); numpy and everything heavier are imported inside the
command, so `--help` stays fast. Frames are written on a thread of their own while the
next frame renders.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import imageio.v3 as iio
import numpy as np
import typer
from tqdm import tqdm

from hack_render import boundary, interrupts
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.geometry.limits import apply_limit_policy, limit_policy
from hack_render.geometry.params import gather_params, model_inputs, save_sequence
from hack_render.io import atomic_path
from hack_render.io.image import to_srgb8
from hack_render.render.cli import (
    DenoiseOpt,
    IntegratorOpt,
    KeepNoisyOpt,
    SamplerOpt,
    SssOpt,
    check_denoise,
    check_look,
    denoise_settings,
    named,
    parse_resolution,
    rendered,
)
from hack_render.render.hair_options import HairColorOpt, groom_of, hair_option, hair_style
from hack_render.render.parts import Topology
from hack_render.render.skin_maps import skin_maps
from hack_render.render.video import write_gif, write_mp4
from hack_render.threads import check_threads, command_threads
from scenes import cameras as cams
from scenes import lights

if TYPE_CHECKING:
    import numpy as np


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
    spp: opts.Spp = 25,
    seed: opts.Seed = 0,
    tonemap: opts.Tonemap = "aces",
    variant: opts.Variant = None,
    quiet: opts.Quiet = False,
    threads: opts.Threads = None,
    sampler: str = SamplerOpt,
    integrator: str = IntegratorOpt,
    denoise: str = DenoiseOpt,
    keep_noisy: bool = KeepNoisyOpt,
    sss: bool = SssOpt,
    hair: str | None = hair_option("none (bald: no strands)"),
    hair_color: str | None = HairColorOpt,
) -> None:
    """Render a seamless looping turntable of the head to MP4 (H.264) / GIF / PNG frames.

    Example: hack-render turntable -o out/turntable --frames 48 --hair short --look-around
    """
    import torch

    from hack_render.geometry import load_model
    from hack_render.geometry.skeleton import distribute_head_rotation
    from hack_render.render import turntable as tt
    from hack_render.render.scene import MAX_SPP, HeadScene, RenderSettings

    spec = tt.TurntableSpec(frames, mode, 360.0, look_around, swallow, fps)

    w, h = parse_resolution(resolution)
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
    if threads is not None:
        check_threads(threads)
    command_threads(threads)

    policy = limit_policy(limits)
    p = gather_params(params, beta, expression, head_rotation, eta, tau)
    style = hair_style(hair, hair_color, p.get("hair"))
    model = load_model(model_path)
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
        "rendered": rendered(settings),
        "look_around": look_around,
        "swallow": swallow, "hair": None if style is None else style.to_dict()},
        name="turntable.json")

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

    with boundary.folder_lock(output), interrupts.on_interrupt(kept):
        record.check_resume(resume, tt.frames_on_disk(output) > 0)
        if not resume:  # frames of another run must not be taken for this one's later
            for old in (output / "frames").glob("frame_*.png"):
                old.unlink()
        record.write(complete=False)
        if sequence is not None:
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
                             skin_maps(alpha_, appearance_seed, textures), None, variant,
                             hair=groom_of(style, model))
            times, animated = [], look_around or swallow or mode == "subject"
            pending, bar = set(todo), tqdm(total=len(todo), desc="turntable", unit="frame",
                                           disable=quiet)
            # frames are encoded and written on one thread while the next one renders (in
            # order; a failed write raises from its future at the end, or at the next frame),
            # and an animated frame's successor is posed there too
            writer, writes = ThreadPoolExecutor(1, thread_name_prefix="turntable-writer"), []
            # The scene goes through every frame's changes from frame 0, rendering only the
            # pending frames: Mitsuba's state after an update (the acceleration structure,
            # the environment's bounds) depends on the updates before it, so a resumed
            # run replays the skipped frames' updates to render the same bytes as an
            # uninterrupted one (one started at its first pending frame differed in a few
            # pixels of later frames by up to 6/255).
            upcoming = None  # the next frame's vertices (and hair), posed on the writer thread

            def posed_at(j: int):
                v = vertices_at(j)
                return v, head.pose_hair(v)

            for i in range(max(todo) + 1):
                t0 = time.perf_counter()
                if animated:
                    v, hair_v = upcoming.result() if upcoming is not None else posed_at(i)
                    upcoming = writer.submit(posed_at, i + 1) if i < max(todo) else None
                    head.set_vertices(v, update=False, hair_posed=hair_v)
                head.set_camera(camera_at(i))
                if animated:
                    head.sync_environment()
                if i not in pending:
                    continue
                bare = head.render(seed=seed + i, backdrop=False, sss=sss)
                img = head.composite(head.denoise(bare) if use_denoise else bare)
                while writes and writes[0].done():
                    writes.pop(0).result()  # a failed write stops the run here
                if use_denoise and keep_noisy:
                    writes.append(writer.submit(_write_frame, tt.frame_path(output, i, "noisy"),
                                                head.composite(bare)[..., :3], tonemap))
                writes.append(writer.submit(_write_frame, tt.frame_path(output, i),
                                            img[..., :3], tonemap))
                times.append(time.perf_counter() - t0)
                bar.update()
                if len(times) == 2 and len(todo) > 2:  # the first frame compiles: no rate
                    typer.echo(boundary.estimate_line("turntable", times[1], len(todo) - 2,
                                                      "frame"), err=True)
            writer.shutdown(wait=True)
            for fut in writes:
                fut.result()
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
        cams.save_cameras(output / "cameras.json", [camera_at(i) for i in range(frames)],
                          rendered(settings))
        record.write(complete=True)  # the completion marker, last
    for path in written + [output / "cameras.json"]:
        typer.echo(f"wrote {path.resolve()}")


def _write_frame(path: Path, linear, tonemap: str) -> None:
    """Tone map, encode and write one frame's PNG atomically (the writer thread's job)."""
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, to_srgb8(linear, 0.0, tonemap), extension=".png")


def register(app: typer.Typer) -> None:
    """Add `turntable` to the main app."""
    app.command("turntable")(turntable)
