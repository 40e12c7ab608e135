"""`hack-render export` (a rigged glTF, or mesh files, of one person) and `hack-render view`
(a local three.js page for an exported file)."""

from __future__ import annotations

from pathlib import Path

import typer

from hack_render import boundary, interrupts
from hack_render.errors import HackError
from hack_render.export.viewer import serve
from hack_render.geometry.limits import apply_limit_policy, limit_policy
from hack_render.geometry.obj_io import ObjMaterials, write_mesh
from hack_render.geometry.params import gather_params, load_sequence, model_inputs
from hack_render.io import atomic_write_bytes, written_together
from hack_render.render.materials import material_base_colours
from hack_render.render.skin_maps import skin_maps


def export(
    output: Path = typer.Option(..., "-o", "--output", help="person.glb or person.gltf (+ .bin "
                                "beside it): a rigged, animatable glTF 2.0; or person.obj / "
                                "person.ply: the posed mesh in the model's vertex order (OBJ: "
                                "with an .mtl and PNG skin maps)."),
    params: Path | None = typer.Option(None, "--params", help="JSON/YAML parameter file "
                                          "(keys: beta, psi, expression, head_rotation_deg, "
                                          "theta, global_orient, transl, eta, tau): the identity "
                                          "and larynx size baked in, and the pose at rest."),
    sequence: Path | None = typer.Option(None, "--sequence", help="Parameter sequence, "
                                            ".npz or .jsonl (per-frame theta, psi, tau, "
                                            "global_orient, transl at an fps): becomes the "
                                            "glTF animation. `hack-render turntable --sequence` "
                                            "writes one."),
    beta: str | None = typer.Option(None, help="Identity, comma-separated, e.g. '1.0,-0.5'."),
    expression: str | None = typer.Option(None, "--expr", help="FACS AUs and/or shape "
                                             "names, e.g. 'AU12=0.7,jawOpen=0.3'."),
    head_rotation: str | None = typer.Option(None, "--head-rotation", help="Whole-head "
                                                "'flexion,axial,lateral' in degrees."),
    eta: float | None = typer.Option(None, help="Larynx size."),
    tau: float | None = typer.Option(None, help="Larynx vertical slide, metres."),
    model_path: Path | None = typer.Option(None, "--model", help="Model file (default: "
                                              "built-in)."),
    alpha: str | None = typer.Option(None, help="Appearance coefficients, comma-separated "
                                        "(default: the mean appearance, alpha = 0)."),
    appearance_seed: int | None = typer.Option(None, "--appearance-seed",
                                                  help="Random appearance from this seed."),
    textures: Path | None = typer.Option(None, help="Folder with diffuse/specular/"
                                            "roughness(, normal).exr skin maps (a fit's "
                                            "textures/)."),
    limits: str = typer.Option("warn", "--limits", help="Values beyond the anatomical "
                               "limits (joint rotations, --head-rotation, --eta, --tau) or "
                               "the plausible identities (--beta beyond +-5): warn, clamp "
                               "(and warn) or error."),
    influences: int = typer.Option(4, help="Skin weights per vertex: 4 (what most engines "
                                   "take; the error it costs is printed) or 8 (exact)."),
    hair: str | None = typer.Option(None, "--hair", help="Hair, brows, lashes and beard as "
                                    "alpha-textured cards skinned with the head (.glb/.gltf "
                                    "only): a style (bald, shaved, crew, short, bob, long, "
                                    "ponytail, bun, afro), a JSON/YAML file (its 'hair' "
                                    "section, or the section itself), or none. Default: the "
                                    "--params file's hair section if it has one, else no "
                                    "hair."),
    hair_color: str | None = typer.Option(None, "--hair-color", help="Hair colour: black, "
                                          "dark-brown, brown, light-brown, blonde, platinum, "
                                          "red, auburn, white, or 'EUMELANIN,PHEOMELANIN' "
                                          "(0-20 each, e.g. '1.3,0.1')."),
) -> None:
    """Export one person to CG tools: a rigged glTF 2.0 (skeleton, 53 expression, larynx and
    pose-corrective morph targets, PBR skin, optional animation, optional hair cards) or
    OBJ/PLY mesh files.

    Example: hack-render export --params person.json --sequence motion.npz -o out/person.glb
    --hair long --hair-color brown
    """
    from hack_render.export.hair_cards import hair_style
    from hack_render.export.person import export_person
    from hack_render.geometry import load_model

    suffix = output.suffix.lower()
    boundary.output_file(output, "-o/--output", (".glb", ".gltf", ".obj", ".ply"))
    if suffix in (".obj", ".ply") and sequence is not None:
        raise HackError(f"--sequence: an animation needs a .glb or .gltf output, found -o "
                        f"{output}.")
    if influences not in (4, 8):
        raise HackError(f"--influences: expected 4 or 8, found {influences}.")
    alpha_ = boundary.numbers(alpha, "--alpha", None, -10.0, 10.0,
                              unit=" (standard deviations)", example="0.8,-0.6,0.4")
    boundary.number(appearance_seed, "--appearance-seed", 0, 2 ** 31 - 1, integer=True)
    p = gather_params(params, beta, expression, head_rotation, eta, tau)
    style = hair_style(hair, hair_color, p.pop("hair", None))
    if style is not None and suffix in (".obj", ".ply"):
        if hair is not None or hair_color is not None:
            raise HackError(f"--hair: hair cards need a .glb or .gltf output, found -o "
                            f"{output} (or pass --hair none).")
        typer.echo(f"note: {params}'s hair section is left out: hair cards need a .glb or "
                   ".gltf output", err=True)
        style = None
    if model_path is not None:
        boundary.input_file(model_path, "--model", (".npz",), "model file")
    model = load_model(model_path)
    seq = load_sequence(sequence, model.num_expressions) if sequence is not None else None

    # beta length, expression names: checked before anything heavy; then the limits
    p = _limited(p, apply_limits(model_inputs(model, p), limits, p.get("head_rotation_deg")),
                 limits)
    maps = _skin_maps(alpha_, appearance_seed, textures)
    if suffix in (".obj", ".ply"):
        for path in _export_mesh(model, p, maps, output):
            typer.echo(f"wrote {path.resolve()}")
        return

    rep = export_person(model, p, output, seq, maps, influences, style)
    for f in rep["files"]:
        typer.echo(f"wrote {Path(f).resolve()}")
    typer.echo(f"  {rep['bytes'] / 1e6:.1f} MB, {rep['targets']} morph targets, "
               f"{rep['frames']} animation frames, {rep['seconds']:.1f} s")
    if rep["hair"] is not None:
        groups = ", ".join(f"{name} {g['cards']:,} cards ({g['strands']:,} strands)"
                           for name, g in rep["hair"]["groups"].items())
        typer.echo(f"  hair: {groups or 'none grown'}; {rep['hair']['seconds']:.1f} s")
    err_mm = 1000 * rep["weight_truncation_error_m"]
    typer.echo(f"  skin: {influences} weights per vertex; largest vertex error this costs at "
               f"the joint limits: {err_mm:.3g} mm"
               + (" (--influences 8 is exact)" if influences == 4 else ""))


def apply_limits(kw: dict, limits: str, head_rotation_deg) -> dict:
    return apply_limit_policy(kw, limit_policy(limits), head_rotation_deg)


def _limited(p: dict, kw: dict, limits: str) -> dict:
    """The parameters ``p`` with ``--limits clamp``'s clamped values (joint rotations as one
    theta, the head rotation's share included); unchanged otherwise."""
    if limits != "clamp":
        return p
    p = dict(p)
    if "theta" in p or "head_rotation_deg" in p:
        p.pop("head_rotation_deg", None)
        p["theta"] = kw["theta"][0].tolist()
    for key in ("beta", "eta", "tau"):
        if key in p:
            v = kw[key][0]
            p[key] = v.tolist() if key == "beta" else float(v)
    return p


def _skin_maps(alpha, seed, textures):
    """The skin maps: a texture folder, A(alpha) or a seeded subject; default A(0)."""
    if alpha is None and seed is None and textures is None:
        alpha = [0.0]
    return skin_maps(alpha, seed, textures)


def _export_mesh(model, params: dict, maps, output: Path) -> list[Path]:
    """The posed mesh as OBJ (+ .mtl + PNG maps in <stem>_maps/) or PLY."""
    import torch

    from hack_render.export.gltf import png_bytes

    with torch.no_grad():
        verts = model(**model_inputs(model, params)).vertices[0].numpy()
    args = (verts, model.faces.numpy(), model.uvs.numpy(), model.uv_faces.numpy())
    if output.suffix.lower() == ".ply":
        return [write_mesh(output, *args)]
    folder = output.parent / f"{output.stem}_maps"
    images = {"diffuse": (maps.diffuse, True), "specular": (maps.specular, False),
              "roughness": (maps.roughness, False)}
    if maps.normal is not None:
        images["normal"] = (0.5 * maps.normal + 0.5, False)
    mats = ObjMaterials(model.material_names, model.face_material.numpy(),
                        {k: f"{folder.name}/{k}.png" for k in images},
                        colours=material_base_colours(model.material_names, maps.iris_rgb,
                                                      maps.sclera_rgb))
    pngs = [folder / f"{key}.png" for key in images]
    written = []
    # one output: a full disk or an interruption leaves none of its parts without the rest
    with written_together([*pngs, output.with_suffix(".mtl"), output]):
        folder.mkdir(parents=True, exist_ok=True)
        for target, (img, srgb) in zip(pngs, images.values()):
            written.append(atomic_write_bytes(target, png_bytes(img, srgb)))
        written += [write_mesh(output, *args, mats), output.with_suffix(".mtl")]
    return written


def view(
    file: Path = typer.Argument(..., help="An exported person.glb or .gltf."),
    port: int = typer.Option(8023, help="Port on 127.0.0.1 (0: any free port)."),
    open_browser: bool = typer.Option(True, "--open/--no-open", help="Open the page in the "
                                      "default browser."),
) -> None:
    """Serve a local page (127.0.0.1 only, three.js bundled, no network) that shows an
    exported person with sliders for the expressions, the 8 joints, the larynx and the
    animation's timeline. Stop with Ctrl-C.

    Example: hack-render view out/person.glb
    """
    boundary.input_file(file, "FILE", (".glb", ".gltf"), "exported person")
    boundary.number(port, "--port", 0, 65535, integer=True)
    with interrupts.on_interrupt("the viewer stopped (it writes no files)"):
        serve(file, port, open_browser)


def register(app: typer.Typer) -> None:
    """Add `export` and `view` to the main app."""
    app.command("export")(export)
    app.command("view")(view)
