"""`hack-render track VIDEO -o OUTDIR`: a clip to a HACK performance."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from hack_render import boundary, interrupts
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.fit.config import FitConfig, load_config
from hack_render.threads import check_threads, command_threads, requested
from hack_render.track.detect import FrameDetector, FrameLandmarks, detect_frames
from hack_render.track.video import open_clip


def track_video(video: Path, outdir: Path, keyframes: int = 5, max_side: int = 640,
                fps: float | None = None, config=None, overlay: bool = True,
                resume: bool = False, progress: bool = True,
                max_frames: int | None = None, truth: dict | None = None,
                larynx: bool = True, outline: bool = True):
    """Library entry point of the command: read, detect, fit, track, write. Returns
    (TrackResult, paths). With ``resume``, landmarks found by an interrupted run of the
    same command (``landmarks.npz``) are reused. ``larynx``: track tau per frame from the
    neck's shading (else the keyframe fit's tau throughout); ``outline``: place the neck
    on the person's outline in every frame (the outline stage)."""

    from hack_render.track.outputs import write_outputs
    from hack_render.track.pipeline import timed

    boundary.number(keyframes, "--keyframes", 1, 50)
    boundary.number(max_side, "--max-side", 64, 4096, unit=" px")
    if max_frames is not None:
        boundary.number(max_frames, "--max-frames", 3, 10_000_000)
    cfg = config or FitConfig()
    clip = open_clip(video, max_side, fps)
    if max_frames is not None and max_frames < clip.frames:
        clip = dataclasses.replace(clip, frames=int(max_frames))
    if clip.frames < 3:
        raise HackError(f"{video}: {clip.frames} frame(s); expected at least 3 to track.")
    boundary.output_dir(outdir)
    record = boundary.RunRecord(outdir, "track", {
        "video": boundary.file_identity(video) if Path(video).is_file() else str(video),
        "keyframes": keyframes, "max_side": max_side, "fps": clip.fps, "larynx": larynx,
        "outline": outline,
        "frames": clip.frames, "config": cfg.to_dict()}, name="track_run.json")
    lm_path = outdir / "landmarks.npz"
    old = record.check_resume(resume, lm_path.exists())
    if resume and old is not None and old.get("complete"):
        return None, []
    if requested() is None:  # the command's --threads, else torch's default for commands
        command_threads(None)

    landmarks, timings = None, {}
    if resume and lm_path.is_file():
        landmarks = FrameLandmarks.load(lm_path)
        if len(landmarks.found) != clip.frames:
            landmarks = None
    outdir.mkdir(parents=True, exist_ok=True)
    with boundary.folder_lock(outdir):
        record.write(complete=False)
        if landmarks is None:
            with interrupts.on_interrupt(f"nothing kept in {outdir} (interrupted while finding "
                                       "landmarks); run the same command again"), \
                    timed(timings, "landmarks"):
                landmarks = detect_frames(clip.read(), FrameDetector(
                    refiner=cfg.landmarks.refiner), progress, clip.frames)
            landmarks.save(lm_path)  # a resumed run starts after the landmarks
        with interrupts.on_interrupt(f"the landmarks of every frame are kept in {lm_path}; "
                                   "run the same command with --resume to go on from there"):
            result, fitter = _track(clip, cfg, keyframes, progress, landmarks, larynx,
                                    outline, outdir)
            result.timings.update(timings)  # the landmarks' time (none when resumed)

            paths = write_outputs(result, fitter, outdir, overlay, progress, truth)
        record.write(complete=True)  # the completion marker, last
    return result, paths + [record.path]


def _track(clip, cfg, keyframes, progress, landmarks, larynx=True, outline=True,
           outdir: Path | None = None):
    from hack_render.track.outputs import start_identity_files
    from hack_render.track.pipeline import track_clip

    # the keyframe fit's files are written in a thread from the moment the fit ends
    write = None if outdir is None else (
        lambda fit, timings: start_identity_files(fit, outdir, timings))
    result = track_clip(clip, cfg, keyframes=keyframes, progress=progress,
                        landmarks=landmarks, larynx=larynx, outline=outline,
                        on_identity=write)
    return result, result.fitter


def track(
    video: Path = typer.Argument(..., help="A clip (MP4, MOV, AVI, WebM, MKV) or a folder of "
                                 "frames (PNG/JPG, in name order)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    keyframes: int = typer.Option(5, "--keyframes", help="Frames the identity (shape, skin, "
                                  "focal length) is fitted on, spread over the clip."),
    max_side: int = typer.Option(640, "--max-side", help="Working size: frames are scaled so "
                                 "their long side is at most this (px)."),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (default: the "
                                        "video's; a folder of frames: 30)."),
    max_frames: int | None = typer.Option(None, "--max-frames", help="Track only the "
                                             "first N frames."),
    config: Path | None = typer.Option(None, "--config", help="Fit config (TOML/YAML/JSON) "
                                          "for the keyframe fit; see `hack-render fit`."),
    photometric: bool = typer.Option(False, "--photometric/--no-photometric",
                                     help="Also fit the skin on the keyframes (the fit's "
                                     "photometric stage: identity/ gets a skin texture; "
                                     "minutes per keyframe on a CPU). Off by default "
                                     "since issue 63: the keyframe fit from landmarks is "
                                     "the identity the tracking uses either way."),
    refine: bool = typer.Option(False, "--refine/--no-refine", help="Refine dlib's points "
                                "with the fit's landmark refiner (the config's "
                                "landmarks.refiner, default the shipped one). Off by "
                                "default: it was trained on renders, and on the ten real "
                                "clips of docs/motion.md it moved the tracked points about "
                                "1 % of the outer-eye distance further from the "
                                "hand-calibrated reference."),
    tau: str = typer.Option("fixed", "--tau", help="The larynx's slide per frame: "
                            "'fixed' (the default: the keyframe fit's value throughout) or "
                            "'photometric' (from the neck's shading: the mesh at a grid of "
                            "slides with the light refitted per frame, the least-cost smooth "
                            "path; on the benchmark's two rendered clips 5.5 and 11.5 mm mean "
                            "error, correlation 0.83 and 0.29 with the true slide, against "
                            "6.0 mm for 'fixed': it reads the slide where the tracked neck "
                            "lies, 5-22 px from the true one there; about 1 frame/s on 2 "
                            "cores, so opt-in; where the neck is not seen it keeps the fixed "
                            "value; see docs/motion.md)."),
    no_outline: bool = typer.Option(False, "--no-outline", help="Skip the outline stage "
                                    "(the face's and neck's outline placed on the "
                                    "head-and-neck mask, the face mesh's oval and the "
                                    "neck's skin, in every third frame); the neck then "
                                    "follows the landmarks alone."),
    no_overlay: bool = typer.Option(False, "--no-overlay", help="Skip overlay.mp4."),
    resume: bool = typer.Option(False, "--resume", help="Go on from an interrupted run "
                                "(same arguments): its landmarks are reused."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    threads: opts.Threads = None,
) -> None:
    """Track a video into HACK parameters: one identity for the clip, and per frame the
    8 neck joints (from the head's rotation), the torso, the expression and the larynx's
    slide tau (the keyframe fit's; --tau photometric: per frame from the neck's shading). The
    neck is placed on the head-and-neck outline (the face mesh's oval and the neck's
    skin, no hair; --no-outline: landmarks alone). A track whose points lie far from the
    detected ones is reported on stderr and as the report's status "poor".

    Writes sequence.npz (per-frame theta, psi, tau, global_orient, transl: `hack-render
    export --params OUT/person.json --sequence OUT/sequence.npz -o anim.glb`),
    person.json (beta, eta), identity/ (the keyframe fit: skin textures, meshes),
    camera.json, landmarks.npz, overlay.mp4 and report.json (per-frame landmark error,
    jitter, lost frames: marked and interpolated, never dropped).

    Example: hack-render track clip.mp4 -o out/clip
    """
    if tau not in ("photometric", "fixed"):
        raise HackError(f"--tau {tau!r}: expected 'photometric' or 'fixed'.")
    over: dict = {}
    if not photometric:
        over["photometric"] = {"enabled": False}
    if not refine:   # dlib's own points (the config's refiner applies with --refine)
        over["landmarks"] = {"refiner": "off"}
    if config is not None:
        boundary.input_file(config, "--config", (".toml", ".yaml", ".yml", ".json"),
                            "config file")
    cfg = load_config(config, over)
    if threads is not None:
        check_threads(threads)
    command_threads(threads)
    result, paths = track_video(video, output, keyframes, max_side, fps, cfg,
                                not no_overlay, resume, not quiet, max_frames,
                                larynx=tau == "photometric", outline=not no_outline)
    if result is None:
        typer.echo(f"{output}: already complete (--resume); nothing to do")
        return
    lm = result.landmarks
    typer.echo(f"tracked {result.clip.frames} frames at {result.clip.fps:g} fps "
               f"({int((~lm.found).sum())} without a face, interpolated); keyframes "
               f"{result.keyframes}")
    for note in result.notes:
        typer.echo(f"note: {note}")
    for warning in result.warnings:   # a poor track: said, not only written
        typer.secho(f"warning: {warning}", err=True, fg=typer.colors.YELLOW)
    for p in paths:
        if p.name in ("sequence.npz", "person.json", "overlay.mp4", "report.json"):
            typer.echo(f"wrote {p.resolve()}")


def register(app: typer.Typer) -> None:
    app.command("track")(track)
