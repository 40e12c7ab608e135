"""`hack-render mesh` and `hack-render model info`; `build` (the base model) is registered
as `hack-render learn base-model` by hack_render.learn.cli."""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path

import typer

from hack_render import cli_options as opts
from hack_render.errors import HackError


class LimitPolicy(str, Enum):
    warn = "warn"
    clamp = "clamp"
    error = "error"


model_app = typer.Typer(help="Inspect HACK model files (`hack-render learn model` builds one).",
                        no_args_is_help=True)


def _floats(text: str | None, name: str) -> list[float] | None:
    """Comma-separated finite numbers of option ``--name`` (None passes through)."""
    from hack_render.boundary import numbers

    return numbers(text, f"--{name}")


def check_flags(beta: str | None, expression: str | None, head_rotation: str | None,
                eta: float | None, tau: float | None) -> dict:
    """The pose flags of `mesh`, `render`, `turntable`, `export`, checked (finite, inside
    the hard bounds of :data:`hack_render.geometry.params.BOUNDS`) and named by option."""
    from hack_render import boundary as b
    from hack_render.geometry.params import BOUNDS, parse_expression

    return {"beta": b.numbers(beta, "--beta", None, -BOUNDS["beta"], BOUNDS["beta"],
                              unit=" (standard deviations)", example="1.0,-0.5"),
            "expression": None if expression is None else parse_expression(expression, "--expr"),
            "head_rotation_deg": b.numbers(head_rotation, "--head-rotation", 3, -360, 360,
                                           unit=" degrees", example="15,40,0"),
            "eta": b.number(eta, "--eta", *BOUNDS["eta"]),
            "tau": b.number(tau, "--tau", *BOUNDS["tau"], unit=" metres")}


def gather_params(params_file: Path | None, beta: str | None, expression: str | None,
                  head_rotation: str | None, eta: float | None, tau: float | None) -> dict:
    """Parameters from a file, overridden by command-line flags (shared by several commands)."""
    from hack_render.geometry.params import check_params, load_params

    flags = check_flags(beta, expression, head_rotation, eta, tau)
    params = load_params(params_file) if params_file else {}
    params.update({k: v for k, v in flags.items() if v is not None})
    return check_params(params, "command-line parameters")


#: Identities beyond this many standard deviations (per component) are implausible: the
#: shape space is N(0, I), and the dataset sampler truncates at 2.5 by default.
BETA_PLAUSIBLE = 5.0


def beta_messages(beta) -> list[str]:
    """Shape coefficients beyond :data:`BETA_PLAUSIBLE`, as phrases (a tensor or an array)."""
    import numpy as np

    b = np.asarray(beta.detach().cpu() if hasattr(beta, "detach") else beta).reshape(-1)
    return [f"beta[{i}] = {float(v):.3g} (plausible identities lie within "
            f"+-{BETA_PLAUSIBLE:g} standard deviations; clamped to "
            f"{max(-BETA_PLAUSIBLE, min(BETA_PLAUSIBLE, float(v))):g})"
            for i, v in enumerate(b.tolist()) if abs(v) > BETA_PLAUSIBLE]


def apply_limit_policy(kw: dict, policy: LimitPolicy, head_rotation_deg=None) -> dict:
    """Warn about, clamp, or refuse (exit 2) out-of-range joint rotations, whole-head
    rotations, larynx slide tau and size eta (:func:`hack_render.geometry.limits.enforce_limits`)
    and implausible identities (``beta`` beyond :data:`BETA_PLAUSIBLE`); warnings name each
    value and its limit, and go to stderr (once)."""
    from hack_render.geometry.limits import enforce_limits

    policy_name = str(getattr(policy, "value", policy))
    ident = beta_messages(kw["beta"]) if kw.get("beta") is not None else []
    if ident and policy_name == "error":
        text = "; ".join(m.split("; clamped to")[0] + ")" for m in ident)
        raise HackError(f"--beta: outside the plausible identities: {text}. Change the value, "
                        "or use --limits clamp (clamp and warn) or --limits warn.")
    kw, messages = enforce_limits(kw, policy, head_rotation_deg)
    if ident and policy_name == "clamp":
        kw = dict(kw, beta=kw["beta"].clip(-BETA_PLAUSIBLE, BETA_PLAUSIBLE))
    elif ident:
        ident = [m.split("; clamped to")[0] + "; kept, use --limits clamp to clamp)"
                 for m in ident]
    messages = messages + ident
    if messages:
        typer.secho(f"warning: outside the anatomical limits: {'; '.join(messages)}", err=True,
                    fg="yellow")
    return kw


def posed_model(params_file, beta, expression, head_rotation, eta, tau, limits, model_path):
    """Load a model and pose it from a parameter file and flags (shared by mesh and render).

    Returns (model, forward keyword arguments, posed vertices (N, 3) numpy).
    """
    import torch

    from hack_render.geometry import load_model
    from hack_render.geometry.params import model_inputs

    if model_path is not None:
        from hack_render import boundary

        boundary.input_file(model_path, "--model", (".npz",), "model file")
    model = load_model(model_path)
    p = gather_params(params_file, beta, expression, head_rotation, eta, tau)
    kw = apply_limit_policy(model_inputs(model, p), limits, p.get("head_rotation_deg"))
    with torch.no_grad():
        out = model(**kw)
    return model, kw, out.vertices[0].numpy()


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
    from hack_render import boundary
    from hack_render.geometry.obj_io import write_mesh

    boundary.output_file(output, "-o/--output", (".obj", ".ply"))
    targets = [output] + ([output.with_suffix(".ply" if output.suffix.lower() == ".obj"
                                              else ".obj")] if both else [])
    for target in targets[1:]:
        boundary.output_file(target, "--both")
    from hack_render.geometry.posing import posed_vertices

    model, verts = posed_vertices(params, beta, expression, head_rotation, eta, tau, limits,
                                  model_path)
    for target in targets:
        write_mesh(target, verts, model.faces, model.uvs, model.uv_faces)
        typer.echo(f"wrote {target.resolve()}")


def build(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder: the development layout "
                             "(ict_facekit.npz, generic_neutral_mesh.obj, vertex_indices.json) or "
                             "the original FaceXModel/ folder of OBJs."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
) -> None:
    """Learn the base model from ICT-FaceKit: shape PCA, AU table, skeleton, weights (~15 s).

    Registered as `hack-render learn base-model` by hack_render.learn.cli.
    Example: hack-render learn base-model --ict ICT_FACEKIT_DIR -o base.npz
    """
    from hack_render import boundary
    from hack_render.geometry.model_file import save_model_file
    from hack_render.learn.ict_default import build_default_model

    boundary.input_dir(ict, "--ict", "ICT-FaceKit folder")
    boundary.output_file(output, "-o/--output", (".npz",))
    arrays, meta = build_default_model(ict)
    errors = save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")
    for key, err in errors.items():
        typer.echo(f"  {key}: int16 storage, max abs error {err:.3g} (unit vectors / metres)")


@model_app.command("info")
def info(model_path: Path | None = typer.Argument(None, help="Model file (default: built-in).")) -> None:
    """Print a model's sizes, joints, action units, expression names and provenance."""
    from hack_render import boundary
    from hack_render.geometry import load_model

    if model_path is not None:
        boundary.input_file(model_path, "MODEL", (".npz",), "model file")
    m = load_model(model_path)
    typer.echo(f"vertices {m.num_vertices}, triangles {len(m.faces)}, shape components {m.num_shape}, "
               f"expressions {m.num_expressions}, joints {', '.join(m.joint_names)}")
    typer.echo(f"action units: {', '.join(m.au_names)}")
    typer.echo(f"expression shapes: {', '.join(m.expression_names)}")
    typer.echo("components: pose blendshapes " + ("yes" if m.has_pose_basis else "no")
               + ", personalised expressions " + ("yes" if m.expr_personal is not None else "no")
               + ", personalised pose " + ("yes" if m.pose_personal is not None else "no")
               + ", larynx " + ("yes" if m.has_larynx else "no"))
    typer.echo(json.dumps(m.meta.get("provenance", {}), indent=1))


def register(app: typer.Typer) -> None:
    app.command("mesh")(mesh)
    app.add_typer(model_app, name="model")
