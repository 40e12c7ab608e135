"""The motion learners' commands, registered under `hack-render learn` by
:func:`hack_render.learn.cli.register`: `head-to-neck` (head orientation -> the 8 neck
joints, :mod:`hack_render.motion.head_to_neck`) and `larynx-motion` (expressions -> the
larynx slide, :mod:`hack_render.motion.larynx_motion`)."""

from __future__ import annotations

from pathlib import Path

import typer

from hack_render import boundary
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.geometry.params import load_sequence


def _split_held_out(paths: list[Path], held_out: str) -> tuple[list[Path], list[Path]]:
    """Training and held-out files: ``held_out`` is a count ('2') or file names ('a.npz,b.npz')."""
    if held_out.strip().isdigit():
        k = int(held_out)
        if not 1 <= k < len(paths):
            raise HackError(f"--held-out: expected 1..{len(paths) - 1} sequences (of "
                            f"{len(paths)} given), found {k}; held-out sequences measure the "
                            "mapping against distribute_head_rotation.")
        return paths[:-k], paths[-k:]
    names = [s.strip() for s in held_out.split(",") if s.strip()]
    test = [p for p in paths if p.name in names or str(p) in names]
    if len(test) != len(names) or len(test) == len(paths):
        raise HackError(f"--held-out: expected names of some (not all) given sequences, found "
                        f"{names}.")
    return [p for p in paths if p not in test], test


def learn_head_to_neck(
    sequences: list[Path] = typer.Argument(..., help="Parameter sequences (.npz/.jsonl) with "
                                           "measured per-frame neck joints (theta)."),
    output: Path = typer.Option(..., "-o", "--output", help="The mapping to write (.npz)."),
    held_out: str = typer.Option("1", "--held-out", help="Sequences kept out of training to "
                                 "compare with distribute_head_rotation: a count (the last "
                                 "ones) or comma-separated file names."),
    steps: int = typer.Option(3000, help="Adam steps (batches of 256 frames)."),
    seed: opts.Seed = 0,
    quiet: opts.Quiet = False,
) -> None:
    """Learn head orientation -> the 8 neck joints (the paper's 2-layer, 512-unit MLP) and
    report its per-joint angle error against distribute_head_rotation on held-out sequences.

    Example: hack-render learn head-to-neck takes/*.npz --held-out 2 -o head_to_neck.npz
    """
    from hack_render.motion import head_to_neck as H

    boundary.output_file(output, "-o/--output", (".npz",))
    if len(sequences) < 2:
        raise HackError(f"SEQUENCES: expected at least 2 files (training and held-out), found "
                        f"{len(sequences)}.")
    if steps < 1:
        raise HackError(f"--steps: expected >= 1, found {steps}.")
    train_p, test_p = _split_held_out(list(sequences), held_out)
    train_t, test_t = H.load_thetas(train_p), H.load_thetas(test_p)  # all checked first
    mapping = H.train(train_t, steps=steps, seed=seed, progress=not quiet,
                      sources=[str(p) for p in train_p])
    rep = H.compare(mapping, test_t)
    mapping.meta["held_out"] = {"sequences": [str(p) for p in test_p], **rep}
    mapping.save(output)
    typer.echo(f"wrote {output.resolve()} ({mapping.meta['training_frames']} training frames, "
               f"{mapping.meta['seconds']:.0f} s)")
    typer.echo(f"held-out ({rep['frames']} frames), mean angle error per joint, degrees:")
    typer.echo("  joint    " + " ".join(f"{j:>7}" for j in rep["joints"]))
    typer.echo("  MLP      " + " ".join(f"{e:7.3f}" for e in rep["mlp_deg"]))
    typer.echo("  rule     " + " ".join(f"{e:7.3f}" for e in rep["distribute_deg"]))
    verdict = ("the MLP is better" if rep["mlp_mean_deg"] < rep["distribute_mean_deg"]
               else "the fixed rule is better: keep distribute_head_rotation")
    typer.echo(f"  mean: MLP {rep['mlp_mean_deg']:.3f}, distribute_head_rotation "
               f"{rep['distribute_mean_deg']:.3f} ({verdict})")


def _larynx_pairs(paths: list[Path]):
    pairs = []
    for p in paths:
        seq = load_sequence(p)
        if seq.psi is None or seq.tau is None:
            raise HackError(f"{p}: expected per-frame 'psi' and 'tau' (expressions and the "
                            "tracked larynx slide); found keys "
                            f"{sorted(seq.arrays())}.")
        pairs.append((seq.psi, seq.tau))
    return pairs


def learn_larynx_motion(
    sequences: list[Path] = typer.Argument(..., help="Parameter sequences with per-frame psi "
                                           "and tau (e.g. tau tracked by Eq. 13)."),
    output: Path = typer.Option(..., "-o", "--output", help="Weights and checkpoint (.npz)."),
    held_out: int = typer.Option(1, "--held-out", help="Last sequences kept out of training "
                                 "and used to report the error (0: none)."),
    steps: int = typer.Option(1500, help="Adam steps."),
    d_model: int = typer.Option(64, "--d-model", help="Transformer width."),
    layers: int = typer.Option(2, help="Decoder layers."),
    window: int = typer.Option(12, help="Frames of expression history each frame reads."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the checkpoint at -o."),
    seed: opts.Seed = 0,
    quiet: opts.Quiet = False,
) -> None:
    """Learn expressions -> larynx slide: a FaceFormer-style autoregressive transformer
    (past tau fed back), checkpointed to -o every 100 steps (--resume continues).

    Example: hack-render learn larynx-motion talks/*.npz --held-out 2 -o larynx_motion.npz
    """
    from hack_render.motion import larynx_motion as L

    boundary.output_file(output, "-o/--output", (".npz",))
    if not 0 <= held_out < len(sequences):
        raise HackError(f"--held-out: expected 0..{len(sequences) - 1}, found {held_out}.")
    for name, value, lo in (("--steps", steps, 1), ("--d-model", d_model, 4),
                            ("--layers", layers, 1), ("--window", window, 1)):
        boundary.number(value, name, lo, 1e6, integer=True)
    pairs = _larynx_pairs(list(sequences))
    train_pairs = pairs[:len(pairs) - held_out]
    cfg = L.LarynxConfig(num_expressions=pairs[0][0].shape[1], d_model=d_model, layers=layers,
                         window=window, steps=steps, seed=seed)
    model, meta = L.train(train_pairs, cfg, output, resume=resume, progress=not quiet,
                          sources=[str(p) for p in sequences[:len(pairs) - held_out]])
    typer.echo(f"wrote {output.resolve()} ({steps} steps, {meta['seconds']:.0f} s)")
    if held_out:
        rep = L.evaluate(model, pairs[-held_out:])
        meta["held_out"] = {"sequences": [str(p) for p in sequences[-held_out:]], **rep}
        L.save_checkpoint(output, model, None, steps, meta)
        typer.echo(f"held-out ({rep['frames']} frames, autoregressive): RMSE "
                   f"{rep['rmse_mm']:.3f} mm, max {rep['max_mm']:.3f} mm (tau's own std "
                   f"{rep['tau_std_mm']:.3f} mm), correlation {rep['correlation']:.3f}")
