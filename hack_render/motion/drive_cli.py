"""`hack-render drive CAPTURE -o anim.npz`: face-capture files to a parameter sequence."""

from __future__ import annotations

from pathlib import Path

import typer

from hack_render import boundary
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.geometry import load_model
from hack_render.geometry.params import save_sequence
from hack_render.motion.drive import drive


def drive_cmd(
    capture: Path = typer.Argument(..., help="Live Link Face / ARKit CSV (52 blendshapes and "
                                   "head yaw/pitch/roll), or a head rotation CSV (yaw, pitch, "
                                   "roll[, time]) or NPY (T, 3)."),
    output: Path = typer.Option(..., "-o", "--output", help="Parameter sequence to write "
                                "(.npz or .jsonl), for `hack-render export --sequence`."),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (default: from the "
                                     "timecodes or the time column)."),
    degrees: bool = typer.Option(False, "--degrees", help="Head rotations of a plain "
                                 "rotation file are in degrees (default radians)."),
    limits: opts.Limits = "clamp",
    model_path: opts.ModelPath = None,
) -> None:
    """Turn a face capture into HACK motion: expressions from ARKit blendshapes (psi), the
    head's rotation shared over the 8 neck joints (theta).

    Example: hack-render drive take.csv -o out/take.npz && hack-render export --sequence
    out/take.npz -o out/take.glb
    """


    boundary.output_file(output, suffixes=(".npz", ".jsonl"))
    if limits not in ("warn", "clamp", "error"):
        raise HackError(f"--limits: expected warn, clamp or error, found {limits!r}.")
    model = load_model(model_path)
    seq, report = drive(capture, fps, degrees, model.expression_names, limits)
    save_sequence(output, seq)
    if report["head_beyond_range"] and limits == "warn":
        typer.secho(f"warning: {report['head_beyond_range']} frame(s) turn the head beyond the "
                    "neck's range; the joints were clamped to their limits.", err=True,
                    fg=typer.colors.YELLOW)
    typer.echo(f"wrote {output} ({report['frames']} frames at {report['fps']:g} fps, "
               f"{report['kind']})")
    for note in report["notes"]:
        typer.echo(f"note: {note}")
    if "dropped" in report:
        t = report["dropped"]["TongueOut"]
        typer.echo(f"note: TongueOut dropped ({t['why']}; used in {t['frames_used']} frames); "
                   f"BrowInnerUp and CheekPuff drive both halves of the model's shapes")



def register(app: typer.Typer) -> None:
    app.command("drive")(drive_cmd)
