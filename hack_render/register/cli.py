"""`hack-render register SCAN... -o OUTDIR` (`hack-render learn shape`, which learns a
shape space from registrations, is hack_render.learn.cli's)."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import typer
from tqdm import tqdm

from hack_render import boundary, interrupts
from hack_render import cli_options as opts
from hack_render.errors import HackError
from hack_render.register.align import read_landmarks_3d
from hack_render.register.scan import MESH_SUFFIXES, POINT_SUFFIXES, UNITS, load_scan
from hack_render.threads import check_threads, command_threads


def _scan_files(inputs: list[Path]) -> list[Path]:
    files: list[Path] = []
    for p in inputs:
        if p.is_dir():
            found = sorted(q for q in p.iterdir()
                           if q.suffix.lower() in MESH_SUFFIXES + POINT_SUFFIXES and q.is_file())
            if not found:
                raise HackError(f"{p}: a folder with no scans in it (looked for "
                                f"{', '.join(MESH_SUFFIXES + POINT_SUFFIXES)}).")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise HackError(f"{p}: no such file or folder. Pass scan files or folders of them.")
    stems = [f.stem for f in files]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise HackError(f"scans: two inputs share the name {dup[0]!r}; each scan's results go "
                        f"to OUTDIR/<name>. Rename one.")
    return files


def _fingerprint(scan: Path, settings: dict) -> str:
    """A digest of the scan file's bytes and every setting that changes the result."""
    h = hashlib.sha256()
    with open(scan, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:16]


def _finished(outdir: Path, fingerprint: str) -> bool:
    """True if ``outdir`` holds a complete registration made with the same inputs; an
    incomplete one (no report) is redone; a complete one with other inputs is refused."""
    rep = outdir / "report.json"
    if not rep.is_file():
        return False
    try:
        old = json.loads(rep.read_text()).get("fingerprint")
    except (OSError, json.JSONDecodeError):
        return False
    if old == fingerprint:
        return True
    raise HackError(f"{outdir}: holds a registration made from other inputs or settings. "
                    "Choose another -o, or delete that folder to redo it.")


def register_cmd(
    scans: list[Path] = typer.Argument(..., help="Scan files (OBJ, PLY, STL, OFF, GLB/GLTF "
                                       "meshes; PLY, XYZ, NPY point clouds) or folders of them."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder; each scan's files "
                                "go to OUTDIR/<scan name>/."),
    landmarks: Path | None = typer.Option(None, "--landmarks", help="3-D landmarks of the "
                                             "(single) scan in its units: 68 Multi-PIE points or "
                                             "the 51 inner ones; JSON, NPY or TXT. Default: "
                                             "found by rendering the scan."),
    units: str | None = typer.Option(None, "--units", help="m, cm or mm (default: from "
                                        "the scan's size)."),
    preset: str = typer.Option("default", "--preset", help="default, or paper (the paper's "
                               "protocol: flame-fitting's weights, 100 shape components)."),
    free_form: bool = typer.Option(True, "--free-form/--no-free-form", help="Per-vertex "
                                   "offsets after the model fit (a detailed registration in "
                                   "the model's topology)."),
    shape_components: int = typer.Option(100, "--shape-components", help="Identity "
                                         "components fitted (at most the model's)."),
    bake: bool = typer.Option(True, "--bake/--no-bake", help="Bake a coloured scan's "
                              "colours into the model's UV layout (textures/)."),
    texture_size: int = typer.Option(1024, "--texture-size", help="Baked map height (width "
                                     "is twice it)."),
    iterations: str = typer.Option("50,220,150", "--iterations", help="Adam steps of the "
                                   "rigid, model and free-form stages: fewer is faster and "
                                   "coarser."),
    # default torch 1: the fastest for this work's small tensors (a 51,802-vertex scan: 42
    # CPU seconds with one thread, 190 with two on a busy 2-core machine)
    threads: opts.Threads = None,
    shard: str | None = typer.Option(None, "--shard", help="K/M: register only scans "
                                        "K, K+M, K+2M, ... (one process per shard)."),
    model_path: opts.ModelPath = None,
    quiet: opts.Quiet = False,
) -> None:
    """Register HACK to 3-D scans: similarity alignment from landmarks, then identity,
    expression, the 8 neck joints, larynx and global pose by a robust two-way surface
    distance, then free-form offsets. Finished scans are skipped (resumable).

    Example: hack-render register scans/ -o out/reg

    Writes per scan: registered.obj (model vertex order, on the scan), params.json (for
    render/turntable/export --params), offsets.npy, error.ply, error.png, landmarks.json,
    textures/ (coloured scans) and report.json (written last).
    """
    from hack_render.dataset.runner import parse_shard
    from hack_render.geometry import load_model
    from hack_render.register.fitting import RegisterConfig

    boundary.output_dir(output)
    if units is not None and units not in UNITS:
        raise HackError(f"--units: expected m, cm or mm, found {units!r}.")
    files = _scan_files(list(scans))
    k, m = parse_shard(shard)
    files = files[k::m]
    if landmarks is not None and len(files) != 1:
        raise HackError(f"--landmarks: expected one scan with it, found {len(files)}. Register "
                        "scans with their own landmark files one at a time.")
    if not 1 <= shape_components <= 300:
        raise HackError(f"--shape-components: expected 1..300, found {shape_components}.")
    if not 256 <= texture_size <= 8192:
        raise HackError(f"--texture-size: expected 256..8192, found {texture_size}.")
    if threads is not None:
        check_threads(threads)
    steps = _iterations(iterations)
    cfg = RegisterConfig.preset_named(preset, free_form=free_form, num_shape=shape_components,
                                      rigid_iterations=steps[0], model_iterations=steps[1],
                                      free_iterations=steps[2])
    lmk_file = read_landmarks_3d(landmarks) if landmarks is not None else None

    command_threads(threads, torch_default=1)
    model = load_model(model_path)
    settings = {"preset": preset, "iterations": steps, "free_form": free_form,
                "shape_components": shape_components,
                "units": units, "bake": bake, "texture_size": texture_size,
                "model": str(model_path) if model_path else "default",
                "landmarks": _fingerprint(landmarks, {}) if landmarks else None}
    finished = lambda: sum(1 for p in output.glob("*/report.json"))
    with interrupts.on_interrupt(lambda: f"{finished()} finished registration(s) kept in "
                               f"{output} (a folder with report.json is complete); run the "
                               "same command again to go on"):
        done, failed, skipped = _register_all(files, output, model, cfg, settings, units,
                                              lmk_file, bake, texture_size, quiet)
    typer.echo(f"{done} registered, {failed} failed, {skipped} already done, in {output}")
    if failed:
        raise typer.Exit(1)


def _register_all(files, output, model, cfg, settings, units, lmk_file, bake, texture_size,
                  quiet) -> tuple[int, int, int]:
    """Register every scan not already done; (registered, failed, skipped)."""
    from hack_render.register.bake import bake_scan_colors
    from hack_render.register.outputs import write_registration
    from hack_render.register.pipeline import register as register_scan

    done = failed = skipped = 0
    for path in tqdm(files, desc="register", unit="scan", disable=quiet or len(files) < 2):
        outdir = output / path.stem
        fp = _fingerprint(path, settings)
        if _finished(outdir, fp):
            skipped += 1
            continue
        try:
            scan = load_scan(path, units)
            lmk, ids, lmk_info = _landmarks(scan, lmk_file, quiet, model)
        except HackError as err:
            if len(files) == 1:
                raise
            typer.secho(f"{path.name}: skipped: {err}", err=True, fg=typer.colors.RED)
            failed += 1
            continue
        reg = register_scan(model, scan, lmk * scan.scale, ids, cfg, progress=not quiet,
                       landmark_source=lmk_info["source"])
        reg.report["fingerprint"] = fp
        if "seconds" in lmk_info:
            reg.report["seconds"]["find_landmarks"] = lmk_info["seconds"]
        reg.report["scan_file"] = str(path)
        extra = {}
        if bake and scan.has_color:
            extra, bake_report = bake_scan_colors(reg, model, scan, outdir / "textures",
                                                  texture_size)
            reg.report["bake"] = bake_report
        write_registration(reg, model, outdir, {**lmk_info, "ids": list(ids),
                                                "points": np.asarray(lmk).tolist(),
                                                "units": scan.units}, extra)
        rep = reg.report
        status = rep["status"]
        done += status == "ok"
        failed += status != "ok"
        typer.echo(f"{path.name}: {status}; scan-to-mesh mean "
                   f"{rep['scan_to_mesh_mm']['all'].get('mean', float('nan')):.3f} mm (face "
                   f"{rep['scan_to_mesh_mm']['face'].get('mean', float('nan')):.3f}, neck "
                   f"{rep['scan_to_mesh_mm']['neck'].get('mean', float('nan')):.3f}), "
                   f"{rep['seconds']['total']:.0f} s -> {outdir}"
                   + ("" if status == "ok" else f" ({'; '.join(rep['failure'])})"))
    return done, failed, skipped


def _iterations(text: str) -> tuple[int, int, int]:
    try:
        steps = tuple(int(x) for x in text.split(","))
    except ValueError:
        steps = ()
    if len(steps) != 3 or not all(0 <= x <= 100_000 for x in steps) or steps[1] < 1:
        raise HackError(f"--iterations: expected three step counts 'RIGID,MODEL,FREE' (e.g. "
                        f"50,220,150; MODEL >= 1), found {text!r}.")
    return steps


def _landmarks(scan, lmk_file, quiet: bool, model):
    """(landmarks in scan units, Multi-PIE ids, info) from the file or found on the scan."""
    from hack_render.register.find_landmarks import find_landmarks

    if lmk_file is not None:
        pts, ids = lmk_file
        return pts, ids, {"source": "file"}
    import torch

    with torch.no_grad():
        reference = model().landmarks[0].double().numpy()

    t0 = time.perf_counter()
    pts_m, ids, info = find_landmarks(scan, progress=not quiet, reference=reference)
    info["seconds"] = round(time.perf_counter() - t0, 2)
    return pts_m / scan.scale, ids, {"source": "found", **info}


def register(app: typer.Typer) -> None:
    app.command("register")(register_cmd)
