"""`hack-render dataset` (render a labelled dataset) and `hack-render dataset preview`."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from hack_render import boundary
from hack_render import cli_options as opts
from hack_render.dataset.preview import contact_sheet
from hack_render.errors import HackError
from hack_render.threads import check_threads, command_threads

app = typer.Typer(help="Render labelled datasets (docs/datasets.md).",
                  invoke_without_command=True, no_args_is_help=False)


@app.callback(invoke_without_command=True)
def dataset(
    ctx: typer.Context,
    n: Optional[int] = typer.Option(None, "--n", help="Number of samples in the whole dataset."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Dataset folder."),
    config: Optional[Path] = typer.Option(None, "--config", help="YAML overriding the "
                                          "defaults (docs/datasets.md lists every key)."),
    shard: Optional[str] = typer.Option(None, "--shard", help="K/M: render only samples "
                                        "with index % M == K (0 <= K < M), e.g. one Slurm "
                                        "array task."),
    resume: bool = typer.Option(False, "--resume", help="Skip complete samples, redo "
                                "partial ones (without it, a folder that already holds "
                                "this shard's samples is refused)."),
    seed: int = typer.Option(0, "--seed", help="Dataset seed: sample i is a function of "
                             "(seed, i) alone."),
    executor: str = typer.Option("serial", "--executor", help="serial or ray."),
    address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster address "
                                          "(default: start a local Ray instance)."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Ray actors (default: "
                                          "one per CPU of the Ray instance)."),
    hair: Optional[str] = typer.Option(None, "--hair", help="The config's hair.style: "
                                       "sampled (default), none, or an archetype (bald, "
                                       "shaved, crew, short, bob, long, ponytail, bun, afro)."),
    quiet: opts.Quiet = False,
    threads: opts.Threads = None,
) -> None:
    """Render N sampled people (identity, expression, neck pose, larynx, skin, hair, light,
    cameras) with RGB, alpha, depth, normals, UV, segmentation, soft masks, landmarks
    and parameters; one JSONL manifest per shard.

    Example: hack-render dataset --n 1000 -o out/ds --config dataset.yaml --shard 0/8
    """
    if ctx.invoked_subcommand is not None:
        return
    from hack_render.dataset.config import load_config
    from hack_render.dataset.runner import Job, parse_shard, run

    if n is None or output is None:
        raise HackError("dataset: expected --n N and -o DIR (or the `preview` subcommand), "
                        "found them missing. Example: hack-render dataset --n 100 -o out/ds")

    boundary.number(workers, "--workers", 1, 4096, integer=True)
    if threads is not None:  # this process's engines (serial); each Ray actor: one thread
        check_threads(threads)
    command_threads(threads)
    overrides = {"hair": {"style": hair}} if hair is not None else None
    job = Job(output, n, seed, load_config(config, overrides), parse_shard(shard), resume)
    summary = run(job, executor, address, workers, progress=not quiet)
    typer.echo(f"{summary['rendered']} rendered, {summary['skipped']} already complete, "
               f"{summary['total']} in this shard; manifest {summary['manifest']}")


@app.command("preview")
def preview(
    folder: Path = typer.Argument(..., help="Dataset folder."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="PNG to write "
                                          "(default DIR/preview.png)."),
    count: int = typer.Option(16, "--count", help="Number of views."),
    columns: int = typer.Option(4, "--columns", help="Tiles per row."),
) -> None:
    """Contact sheet of the first samples with segmentation and landmarks overlaid."""

    boundary.input_dir(folder, "FOLDER", "dataset folder")
    boundary.output_file(output or folder / "preview.png", "-o/--output", (".png",))
    boundary.number(count, "--count", 1, 4096, integer=True)
    boundary.number(columns, "--columns", 1, 256, integer=True)
    typer.echo(f"wrote {contact_sheet(folder, output, count, columns).resolve()}")


def register(app_: typer.Typer) -> None:
    """Add `dataset` (with `dataset preview`) to the main app."""
    app_.add_typer(app, name="dataset")
