"""`hack-render mesh` and `hack-render model info`: parse the flags, print the results.

The parameters and the limit policy the posing commands share live in
:mod:`hack_render.geometry.params` and :mod:`hack_render.geometry.limits`. The `model`
group's other commands (`model report`, and the deprecated `model build` / `model build-v2`)
are learners, added to :data:`model_app` by :func:`hack_render.learn.cli.register`."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from hack_render import boundary
from hack_render import cli_options as opts
from hack_render.geometry import obj_io
from hack_render.geometry.limits import LimitPolicy
from hack_render.geometry.posing import posed_vertices

model_app = typer.Typer(help="Inspect HACK model files (`hack-render learn model` builds one).",
                        no_args_is_help=True)


def mesh(
    output: Path = typer.Option(Path("out/hack_mesh.obj"), "-o", "--output",
                                help="Output mesh; .obj or .ply (both with UVs). A second format "
                                     "is written beside it with --both."),
    params: opts.Params = None,
    beta: opts.Beta = None,
    expression: opts.Expression = None,
    head_rotation: opts.HeadRotation = None,
    eta: opts.Eta = None,
    tau: opts.Tau = None,
    limits: LimitPolicy = typer.Option(LimitPolicy.warn, help="Values beyond the anatomical "
                                       "limits (joint rotations, --head-rotation, --eta, "
                                       "--tau) or the plausible identities (--beta beyond "
                                       "+-5): warn, clamp (and warn) or error."),
    model_path: opts.ModelPath = None,
    both: bool = typer.Option(False, "--both", help="Write both OBJ and PLY."),
) -> None:
    """Write a posed HACK mesh (OBJ/PLY with UVs) for the given parameters.

    Example: hack-render mesh -o out/smile.obj --expr AU12=0.8 --head-rotation 10,30,0
    """
    boundary.output_file(output, "-o/--output", (".obj", ".ply"))
    targets = [output] + ([output.with_suffix(".ply" if output.suffix.lower() == ".obj"
                                              else ".obj")] if both else [])
    for target in targets[1:]:
        boundary.output_file(target, "--both")
    model, verts = posed_vertices(params, beta, expression, head_rotation, eta, tau, limits,
                                  model_path)
    for target in targets:
        obj_io.write_mesh(target, verts, model.faces, model.uvs, model.uv_faces)
        typer.echo(f"wrote {target.resolve()}")


@model_app.command("info")
def info(model_path: Path | None = typer.Argument(None, help="Model file (default: built-in).")) -> None:
    """Print a model's sizes, joints, action units, expression names and provenance."""
    if model_path is not None:
        boundary.input_file(model_path, "MODEL", (".npz",), "model file")
    # torch's model (2.2 s to import): `mesh`, in this module too, poses without torch
    from hack_render.geometry.loading import load_model  # listed deferral (import_rules)

    m = load_model(model_path)
    typer.echo(f"vertices {m.num_vertices}, triangles {len(m.faces)}, shape components {m.num_shape}, "
               f"expressions {m.num_expressions}, joints {', '.join(m.joint_names)}")
    typer.echo(f"action units: {', '.join(m.au_names)}")
    typer.echo(f"expression shapes: {', '.join(m.expression_names)}")
    typer.echo("components: pose blendshapes " + ("yes" if m.has_pose_basis else "no")
               + ", personalised expressions " + ("yes" if m.expr_personal is not None else "no")
               + ", personalised pose " + ("yes" if m.pose_personal is not None else "no")
               + ", larynx " + ("yes" if m.has_larynx else "no")
               + ", flexion block " + (f"yes ({m.flex.num_hats} hats)" if m.flex is not None
                                       else "no"))
    typer.echo(json.dumps(m.meta.get("provenance", {}), indent=1))


def register(app: typer.Typer) -> None:
    app.command("mesh")(mesh)
    app.add_typer(model_app, name="model")
