"""`hack-render appearance ...`: build a model, sample texture sets, re-plot a report."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from hack_render.errors import HackError

app = typer.Typer(help="Appearance model A(alpha): build, sample, report.",
                  no_args_is_help=True, add_completion=False)


@app.command()
def build(
    data: Path = typer.Argument(..., help="folder with one sub-folder per subject "
                                "(diffuse, specular, normal[, roughness] .exr/.png)"),
    out: Path = typer.Option(..., "-o", "--out", help="model file to write (.npz)"),
    height: int = typer.Option(256, help="model atlas height H (maps are H x 2H)"),
    components: int | None = typer.Option(None, help="components kept (default all)"),
    basis_dtype: str = typer.Option("float32", help="float32 | float16 | int8"),
    holdout: float = typer.Option(0.1, help="held-out fraction for the report"),
    seed: int = typer.Option(0, help="seed of the 90/10 split"),
):
    """Build an appearance model and its report (JSON + PNG beside the model)."""
    from appearance.builder import build_model

    if basis_dtype not in ("float32", "float16", "int8"):
        raise HackError(f"--basis-dtype: expected float32, float16 or int8, found {basis_dtype!r}.")
    rep = build_model(data, out, height=height, n_components=components,
                      basis_dtype=basis_dtype, holdout=holdout, seed=seed)
    typer.echo(f"wrote {out} ({rep['n_components']} components, {rep['n_subjects']} subjects); "
               f"report {out.with_suffix('.report.json')}")


@app.command()
def template(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder holding "
                             "generic_neutral_mesh.obj (or the OBJ itself); ICT-FaceKit is "
                             "public, MIT licence"),
    out: Path | None = typer.Option(None, "-o", "--output", help="file to write (default: "
                                    "the package's own appearance/data/ict_template.npz)"),
):
    """Rebuild the packaged skin template (the UV atlas's mesh) from ICT-FaceKit's OBJ."""
    from appearance.uv import TEMPLATE_FILE, write_template_file

    path = write_template_file(ict, out or TEMPLATE_FILE)
    typer.echo(f"wrote {path}")


@app.command()
def sample(
    out: Path = typer.Option(..., "-o", "--out", help="output folder for the texture set"),
    model: Path | None = typer.Option(None, help="model file (default: shipped model)"),
    alpha: list[float] | None = typer.Option(None, "--alpha", help="coefficients, repeat "
                                                "the option: --alpha 1 --alpha -0.5"),
    seed: int | None = typer.Option(None, help="draw alpha ~ N(0, I) with this seed"),
    components: int | None = typer.Option(None, help="use the first k components"),
    fmt: str = typer.Option("exr", "--format", help="exr | png"),
    detail: int = typer.Option(0, help="also write normal_detail at this atlas height "
                               "(pore layer), 0 = no"),
):
    """Write diffuse/specular/roughness/normal maps for one alpha, plus preview.png."""
    import numpy as np
    import torch

    from appearance.model import AppearanceModel
    from appearance.texture_io import write_map, write_texture_set

    if alpha and seed is not None:
        raise HackError("sample: expected --alpha or --seed, found both. Pass one of them.")
    m = AppearanceModel.load(model)
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
        from appearance.detail import compose_detail

        detail_img = compose_detail(maps.normal, detail)[0].numpy()
    written = write_texture_set(out, arrays, fmt=fmt)
    if detail_img is not None:
        write_map(out / f"normal_detail.{fmt}", "normal", detail_img)
    from appearance.report import preview_sheet

    preview_sheet(arrays, out / "preview.png", title=f"alpha[:4]={a[0, :4].tolist()}")
    (out / "alpha.json").write_text(json.dumps({"alpha": a[0].tolist()}))
    typer.echo(f"wrote {len(written)} maps and preview.png to {out}")


@app.command()
def report(model: Path = typer.Argument(..., help="model file (.npz)"),
           out: Path | None = typer.Option(None, "-o", "--out", help="PNG to write")):
    """Re-plot a model's explained-variance and held-out error curves."""
    from appearance.builder import plot_report
    from appearance.model import load_model_arrays

    rep = load_model_arrays(model)["report"]
    if not rep:
        raise HackError(f"{model}: expected a build report inside the model, found none. "
                        f"Rebuild it with `hack-render appearance build`.")
    png = out or model.with_suffix(".report.png")
    plot_report(rep, png)
    ho = rep.get("heldout", {})
    typer.echo(json.dumps({"n_subjects": rep["n_subjects"], "n_components": rep["n_components"],
                           "explained_variance_at_k":
                               rep["cumulative_explained_variance"][rep["n_components"] - 1],
                           "heldout": ho}, indent=1))
    typer.echo(f"wrote {png}")
