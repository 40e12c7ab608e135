"""`hack-render transfer` (paper Sec. 6). Heavy imports happen inside the command.

The learners of the motion models (`hack-render learn head-to-neck` and `hack-render learn
larynx-motion`, over :mod:`hack_render.motion.head_to_neck` and
:mod:`hack_render.motion.larynx_motion`) are hack_render.learn.cli's."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from hack_render import boundary as B
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.geometry import load_model
from hack_render.geometry.params import gather_params, parse_floats
from hack_render.motion.transfer import run_transfer, target_kind
from hack_render.render.skin_maps import skin_maps


def transfer(
    motion: Path = typer.Option(..., "--motion", help="HACK motion: a parameter sequence "
                                ".npz/.jsonl (per-frame theta, psi, tau, ...)."),
    target: str = typer.Option(..., "--target", help="A character .npz in the model's "
                               "topology with its 8 neck joints, a .glb/.gltf with a neck "
                               "chain, or procedural:long-neck (made from the template)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder."),
    params: opts.Params = None,
    neck_chain: str | None = typer.Option(None, "--neck-chain", help="glTF: the neck's "
                                             "bones, base to head, e.g. 'neck_01,neck_02,head' "
                                             "(default: bones named like neck, then head)."),
    name_map: Path | None = typer.Option(None, "--name-map", help="glTF: JSON mapping each "
                                            "HACK joint (c7-t1 ... o-c1) to a bone name."),
    influences: int = typer.Option(4, help="Skin weights per vertex in the glTF: 4 or 8."),
    bake_size: int = typer.Option(1024, "--bake-size", help="glTF targets: texels per side "
                                  "of the atlas the skin maps are baked into."),
    alpha: opts.Alpha = None,
    appearance_seed: opts.AppearanceSeed = None,
    textures: opts.Textures = None,
    turntable: bool = typer.Option(True, "--turntable/--no-turntable", help="Render a "
                                   "turntable of the transferred motion."),
    frames: int = typer.Option(24, help="Turntable frames."),
    resolution: int = typer.Option(192, help="Turntable size in pixels (square)."),
    spp: opts.Spp = 16,
    variant: opts.Variant = None,
    model_path: opts.ModelPath = None,
    quiet: opts.Quiet = False,
) -> None:
    """Move HACK motion onto another character: an animated glTF, a turntable and
    report.json (the pose-space stress test's measures on every frame; for a glTF
    character, the alignment, bake and morph-target figures).

    Example: hack-render transfer --motion anim.npz --target procedural:long-neck -o out/giraffe
    """
    B.input_file(motion, "--motion", (".npz", ".jsonl", ".ndjson"), "parameter sequence")
    kind = target_kind(target)
    if kind != "procedural":
        B.input_file(target, "--target", None, "character")
    B.output_dir(output)
    if influences not in (4, 8):
        raise HackError(f"--influences: expected 4 or 8, found {influences}.")
    B.number(frames, "--frames", 2, 2000, integer=True)
    B.number(resolution, "--resolution", 16, 4096, integer=True, unit=" pixels")
    B.number(spp, "--spp", 1, 65536, integer=True)
    B.number(bake_size, "--bake-size", 16, 8192, integer=True, unit=" texels")
    nmap = None
    if name_map is not None:
        try:
            nmap = json.loads(name_map.read_text())
        except (OSError, ValueError) as exc:
            raise HackError(f"--name-map {name_map}: not a readable JSON object ({exc}).") from exc
        if not isinstance(nmap, dict):
            raise HackError(f"--name-map {name_map}: expected a JSON object, found "
                            f"{type(nmap).__name__}.")
    chain = [s.strip() for s in neck_chain.split(",") if s.strip()] if neck_chain else None
    p = gather_params(params, None, None, None, None, None) if params else {}
    model = load_model(model_path)
    tt = ({"frames": frames, "resolution": resolution, "spp": spp, "variant": variant}
          if turntable else None)

    a = parse_floats(alpha, "alpha")  # the skin maps in the model's atlas (default: A(0))
    maps = skin_maps([0.0] if a is None and appearance_seed is None and textures is None
                     else a, appearance_seed, textures)
    rep = run_transfer(model, motion, target, output, p, chain, nmap, influences, tt,
                       progress=not quiet, maps=maps, bake_size=bake_size)
    for f in rep["files"]:
        typer.echo(f"wrote {Path(f).resolve()}")
    d = rep.get("deformation")
    if d:
        typer.echo(f"  {d['frames']} frames: stretch median {d['stretch_median']:.3f}, max "
                   f"{d['stretch_max']:.3f} (LBS {d['lbs_stretch_max']:.3f}); folded skin "
                   f"triangles max {d['folded_triangles_max']} (LBS "
                   f"{d['lbs_folded_triangles_max']})")


def register(app: typer.Typer) -> None:
    """`transfer` on the main app."""
    app.command("transfer")(transfer)
