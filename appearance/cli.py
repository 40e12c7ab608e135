"""`hack-render appearance ...`: sample texture sets, re-plot a report.

Building a model is `hack-render learn appearance` (this module's :func:`build`,
registered by hack_render.learn.cli; `appearance build` is its deprecated old name), and
rebuilding the skin template is `hack-render learn template` (:func:`template`, registered
there too)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from appearance.report import preview_sheet
from appearance.texture_io import write_map, write_texture_set
from hack_render import boundary
from hack_render.cli_options import renamed
from hack_render.errors import HackError
from hack_render.io import write_json

app = typer.Typer(help="Appearance model A(alpha): sample, report (`hack-render learn "
                  "appearance` builds one, `hack-render learn template` rebuilds its skin "
                  "template).",
                  no_args_is_help=True, add_completion=False)


def build(
    data: Path = typer.Argument(..., help="folder with one sub-folder per subject "
                                "(diffuse, specular, normal[, roughness] .exr/.png)"),
    output: Path | None = typer.Option(None, "-o", "--output", help="model file to write "
                                       "(.npz)"),
    out_old: Path | None = typer.Option(None, "--out", hidden=True,
                                        help="Deprecated: -o/--output."),
    height: int = typer.Option(256, help="model atlas height H (maps are H x 2H)"),
    components: int | None = typer.Option(None, help="components kept (default all)"),
    basis_dtype: str = typer.Option("float32", help="float32 | float16 | int8"),
    holdout: float = typer.Option(0.1, help="held-out fraction for the report"),
    seed: int = typer.Option(0, help="seed of the 90/10 split"),
):
    """Learn an appearance model (texture PCA) and its report (JSON + PNG beside the model).

    Registered as `hack-render learn appearance` by hack_render.learn.cli.
    Example: hack-render learn appearance captures/ -o appearance.npz --components 50
    """
    from appearance.builder import build_model

    out = renamed(output, out_old, "--out", "-o/--output")
    if out is None:
        raise HackError("expected -o/--output MODEL.npz, found none.")

    if basis_dtype not in ("float32", "float16", "int8"):
        raise HackError(f"--basis-dtype: expected float32, float16 or int8, found {basis_dtype!r}.")

    boundary.input_dir(data, "DATA", "folder of subjects")
    boundary.output_file(out, "-o/--output", (".npz",))
    boundary.number(height, "--height", 16, 4096, integer=True, unit=" pixels")
    boundary.number(components, "--components", 1, 100000, integer=True,
                    fix="A model needs at least one component (default: all).")
    boundary.number(holdout, "--holdout", 0.0, 0.5,
                    fix="It is the share of subjects held out for the report (0: none).")
    boundary.number(seed, "--seed", 0, 2 ** 32 - 1, integer=True)
    rep = build_model(data, out, height=height, n_components=components,
                      basis_dtype=basis_dtype, holdout=holdout, seed=seed)
    typer.echo(f"wrote {out} ({rep['n_components']} components, {rep['n_subjects']} subjects); "
               f"report {out.with_suffix('.report.json')}")


def template(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder holding "
                             "generic_neutral_mesh.obj (or the OBJ itself); ICT-FaceKit is "
                             "public, MIT licence"),
    out: Path | None = typer.Option(None, "-o", "--output", help="file to write (default: "
                                    "the package's own appearance/data/ict_template.npz)"),
):
    """Rebuild the packaged skin template (the UV atlas's mesh) from ICT-FaceKit's OBJ.

    Example: hack-render learn template --ict ICT_FACEKIT_DIR
    """
    from appearance.uv import TEMPLATE_FILE, write_template_file

    if not Path(ict).exists():
        raise HackError(f"--ict {ict}: not found; pass the ICT-FaceKit folder or its "
                        "generic_neutral_mesh.obj.")
    boundary.output_file(out or TEMPLATE_FILE, "-o/--output", (".npz",))
    path = write_template_file(ict, out or TEMPLATE_FILE)
    typer.echo(f"wrote {path}")


@app.command()
def sample(
    output: Path | None = typer.Option(None, "-o", "--output", help="output folder for the "
                                       "texture set"),
    out_old: Path | None = typer.Option(None, "--out", hidden=True,
                                        help="Deprecated: -o/--output."),
    model: Path | None = typer.Option(None, "--appearance-model", help="appearance model "
                                      "file (default: the shipped one)"),
    model_old: Path | None = typer.Option(None, "--model", hidden=True,
                                          help="Deprecated: --appearance-model (--model is "
                                          "the geometry model in every other command)."),
    alpha: list[str] | None = typer.Option(None, "--alpha", help="coefficients, "
                                           "comma-separated as in `render --alpha`: "
                                           "--alpha 1,-0.5 (repeating the option appends)"),
    seed: int | None = typer.Option(None, help="draw alpha ~ N(0, I) with this seed"),
    components: int | None = typer.Option(None, help="use the first k components"),
    fmt: str = typer.Option("exr", "--format", help="exr | png"),
    detail: int = typer.Option(0, help="also write normal_detail at this atlas height "
                               "(pore layer), 0 = no"),
):
    """Write diffuse/specular/roughness/normal maps for one alpha, plus preview.png."""
    import torch

    from appearance.detail import compose_detail
    from appearance.model import AppearanceModel

    out = renamed(output, out_old, "--out", "-o/--output")
    model = renamed(model, model_old, "appearance sample --model", "--appearance-model")

    if out is None:
        raise HackError("sample: expected -o/--output FOLDER, found none.")
    alpha = [x for item in alpha or []
             for x in boundary.numbers(item, "--alpha", None, -10.0, 10.0,
                                       unit=" (standard deviations)", example="1,-0.5")]
    if alpha and seed is not None:
        raise HackError("sample: expected --alpha or --seed, found both. Pass one of them.")
    boundary.number(seed, "--seed", 0, 2 ** 32 - 1, integer=True)
    boundary.number(components, "--components", 1, 100000, integer=True,
                    fix="Sample at least one component (default: all).")
    if detail:
        boundary.number(detail, "--detail", 16, 8192, integer=True, unit=" pixels",
                        fix="It is the pore layer's atlas height; 0 writes none.")
    if fmt not in ("exr", "png"):
        raise HackError(f"--format: expected exr or png, found {fmt!r}.")
    boundary.output_dir(out)
    m = AppearanceModel.load(model)
    if components is not None and components > m.n_components:
        raise HackError(f"--components: expected 1..{m.n_components} (the model's components), "
                        f"found {components}.")
    if alpha:
        a = torch.tensor([alpha], dtype=torch.float32)
    else:
        a = m.sample_alpha(1, components, seed=0 if seed is None else seed)
    if components is not None:
        a = a[:, :components]
    maps = m.maps(a)
    arrays = {k: getattr(maps, k)[0].detach().numpy().astype(np.float32)
              for k in ("diffuse", "specular", "roughness", "normal")}
    detail_img = None
    if detail:
        detail_img = compose_detail(maps.normal, detail)[0].numpy()
    written = write_texture_set(out, arrays, fmt=fmt)
    if detail_img is not None:
        write_map(out / f"normal_detail.{fmt}", "normal", detail_img)

    preview_sheet(arrays, out / "preview.png", title=f"alpha[:4]={a[0, :4].tolist()}")

    write_json(out / "alpha.json", {"alpha": a[0].tolist()}, indent=None)
    typer.echo(f"wrote {len(written)} maps and preview.png to {out}")


@app.command()
def report(model: Path = typer.Argument(..., help="model file (.npz)"),
           output: Path | None = typer.Option(None, "-o", "--output", help="PNG to write"),
           out_old: Path | None = typer.Option(None, "--out", hidden=True,
                                               help="Deprecated: -o/--output.")):
    """Re-plot a model's explained-variance and held-out error curves."""
    from appearance.builder import plot_report
    from appearance.model import load_model_arrays

    out = renamed(output, out_old, "--out", "-o/--output")
    boundary.input_file(model, "MODEL", (".npz",), "appearance model file")
    boundary.output_file(out or model.with_suffix(".report.png"), "-o/--output", (".png",))
    rep = load_model_arrays(model)["report"]
    if not rep:
        raise HackError(f"{model}: expected a build report inside the model, found none. "
                        f"Rebuild it with `hack-render learn appearance`.")
    png = out or model.with_suffix(".report.png")
    plot_report(rep, png)
    ho = rep.get("heldout", {})
    typer.echo(json.dumps({"n_subjects": rep["n_subjects"], "n_components": rep["n_components"],
                           "explained_variance_at_k":
                               rep["cumulative_explained_variance"][rep["n_components"] - 1],
                           "heldout": ho}, indent=1))
    typer.echo(f"wrote {png}")


def register(main_app: typer.Typer) -> None:
    """Add the `appearance` group to the main app."""
    main_app.add_typer(app, name="appearance")
