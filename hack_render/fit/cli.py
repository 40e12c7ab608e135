"""`hack-render fit PHOTO [PHOTO ...] -o OUTDIR`."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import List, Optional

import numpy as np
import typer

from hack_render import boundary, interrupts
from hack_render import cli_options as opts
from hack_render.cli_options import renamed
from hack_render.errors import HackError
from hack_render.fit.config import DETECTORS, FitConfig, load_config
from hack_render.fit.photo import load_photo
from hack_render.threads import check_threads, command_threads, requested


def fit_photos(photos: list[Path], outdir: Path, config=None, landmarks: list[Path] | None = None,
               progress: bool = True, masks: list[Path] | None = None,
               focal_mm: float | None = None, resume: bool = False):
    """Library entry point of the command: read, detect, fit, write. Returns (result, paths);
    (None, []) when ``resume`` and ``outdir`` already holds a complete fit of these inputs
    (``fit_run.json``; other inputs there are refused).
    ``focal_mm``: every photo's 35 mm-equivalent focal length (replaces EXIF's)."""
    from hack_render.fit.outputs import write_all

    cfg = config or FitConfig()
    if landmarks and len(landmarks) != len(photos):
        raise HackError(f"--landmarks: expected one file per photo ({len(photos)}), found "
                        f"{len(landmarks)}.")
    if masks and len(masks) != len(photos):
        raise HackError(f"--mask: expected one mask per photo ({len(photos)}), found "
                        f"{len(masks)}.")

    boundary.number(focal_mm, "--focal-mm", 5.0, 2000.0, unit=" mm (35 mm-equivalent)")
    for p in photos:
        boundary.input_file(p, "photo", what="photo")
    for p in landmarks or []:
        check_landmark_file(p)
    for p in masks or []:
        boundary.input_file(p, "--mask", what="mask image")
    boundary.output_dir(outdir)
    record = boundary.RunRecord(outdir, "fit", {
        "photos": [boundary.file_identity(p) for p in photos],
        "landmarks": [boundary.file_identity(p) for p in landmarks or []],
        "masks": [boundary.file_identity(p) for p in masks or []],
        "focal_mm": focal_mm, "config": cfg.to_dict()}, name="fit_run.json")
    old = record.check_resume(resume, (outdir / "params.json").exists())
    if resume and old is not None and old.get("complete"):
        return None, []
    with interrupts.on_interrupt(f"nothing was written to {outdir} (interrupted while "
                               "fitting); run the same command again"):
        result = _fit(photos, cfg, landmarks, progress, masks, focal_mm)

    # the files are written under the folder's lock, after a record that says the folder
    # holds no complete fit (what an earlier fit left there is being replaced)
    with boundary.folder_lock(outdir), interrupts.on_interrupt(
            f"the fit in {outdir} is incomplete ({record.path.name} says complete: false; "
            "files from an earlier fit there may remain); run the same command again"):
        record.write(complete=False)
        paths = write_all(result, outdir)
        record.write(complete=True)  # the completion marker, written last
    return result, paths + [record.path]


#: a fit whose points lie further than this from the detected ones (the report's
#: ``landmark_residual_iod``, in outer-eye distances) gets a warning: frontal portraits
#: fit to 2-3 %, two detectors disagree by about 3.4 % on real faces, and the fits that
#: land far off (turned faces, occluders) are at 11-17 % (docs/fit.md)
FAR_FROM_LANDMARKS = 0.08


def far_from_landmarks(report: dict, limit: float = FAR_FROM_LANDMARKS) -> list[str]:
    """Warnings for the views of a fit report whose fitted points lie further than
    ``limit`` from the detected ones."""
    out = []
    for v in report.get("views", []):
        r = v.get("landmark_residual_iod")
        if r is not None and r > limit:
            out.append(f"{v.get('photo', 'photo')}: the fitted landmarks lie {100 * r:.1f} % "
                       f"of the eyes' distance from the detected ones (over "
                       f"{100 * limit:.0f} %): the fit may be off; look at overlay.png (a "
                       f"turned face or an occluder can mislead the detector: --landmarks "
                       f"FILE gives it the points)")
    return out


def _refuse_duplicate_keys(config: Path) -> None:
    """A JSON/YAML config with a key twice is refused (the parsers keep the last one);
    TOML refuses them itself. Other problems are left to ``load_config``'s messages."""
    suffix = config.suffix.lower()
    if suffix not in (".json", ".yaml", ".yml") or not config.is_file():
        return
    try:
        text = config.read_text()
        if suffix == ".json":
            boundary.parse_json(text)
        else:
            boundary.parse_yaml(text)
    except HackError as err:
        raise HackError(f"--config {config}: {err}") from err
    except Exception:  # noqa: BLE001 - a syntax error: load_config says it with context
        return


def check_landmark_file(path: Path) -> None:
    """A landmark file holds 68 rows of exactly two finite numbers (x, y pixels); checked
    before the photos are read (a 3-column file is not 2-D points, an empty one no file)."""

    boundary.input_file(path, "--landmarks", (".pts", ".txt", ".csv", ".json", ".npy"),
                        "landmark file")
    if path.stat().st_size == 0:
        raise HackError(f"--landmarks {path}: expected 68 'x y' points, found an empty file.")
    if path.suffix.lower() == ".npy":
        try:
            pts = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as err:
            raise HackError(f"--landmarks {path}: expected a .npy array of shape (68, 2), "
                            f"could not read it ({err}).") from err
        if pts.shape != (68, 2) or not np.issubdtype(pts.dtype, np.number):
            raise HackError(f"--landmarks {path}: expected an array of shape (68, 2) (x, y "
                            f"pixels), found shape {pts.shape} ({pts.dtype}).")
        return
    if path.suffix.lower() in (".txt", ".csv", ".pts"):
        try:
            lines = path.read_text().splitlines()
        except UnicodeDecodeError as err:
            raise HackError(f"--landmarks {path}: expected text, found binary data.") from err
        rows = [ln.replace(",", " ").split() for ln in lines
                if ln.strip() and not ln.lstrip().startswith("#")]
        if path.suffix.lower() == ".pts":
            rows = [r for r in rows if len(r) == 2 and r[0] not in ("version:", "n_points:")]
        bad = [r for r in rows if len(r) != 2 and r not in (["{"], ["}"])]
        if bad:
            raise HackError(f"--landmarks {path}: expected two columns (x y) per row, found "
                            f"{len(bad[0])} in {' '.join(bad[0])!r}. 3-D points are not "
                            "image landmarks: give pixel coordinates.")


def _fit(photos, cfg, landmarks, progress, masks, focal_mm):
    """Read, detect and fit (nothing written); returns the :class:`FitResult` (its
    ``state`` and ``final`` what the outputs are written from)."""
    from hack_render.fit.fitter import Fitter
    from hack_render.fit.landmarks import detect, read_landmark_file
    from hack_render.fit.silhouette import load_mask

    if requested() is None:  # the command's --threads, else torch's default for commands
        command_threads(None)
    t0 = time.perf_counter()
    lc = cfg.landmarks
    imgs = [load_photo(p) for p in photos]
    if focal_mm is not None:
        for ph in imgs:
            ph.focal_mm, ph.focal_source = float(focal_mm), "--focal-mm"
    dets = []
    for i, ph in enumerate(imgs):
        if landmarks:
            d = read_landmark_file(landmarks[i])
            d.points = d.points * ph.scale
        else:
            d = detect(ph.uint8(), lc, photos[i].name)
        dets.append(d)
    t_detect = time.perf_counter() - t0
    person = None
    if masks:
        person = [load_mask(p, (ph.height, ph.width),
                            (round(ph.height / ph.scale), round(ph.width / ph.scale)))
                  for p, ph in zip(masks, imgs)]
    fitter = Fitter(imgs, dets, cfg, progress=progress, masks=person)
    fitter.timings["landmarks"] = t_detect
    return fitter.run()


def fit(
    photos: List[Path] = typer.Argument(..., help="One or more photos of one person."),
    output: Path = typer.Option(Path("out/fit"), "-o", "--output", help="Output folder."),
    config: Optional[Path] = typer.Option(None, "--config", help="TOML/YAML/JSON config "
                                          "overriding the defaults (docs/fit.md)."),
    landmarks: Optional[List[Path]] = typer.Option(None, "--landmarks", help="68-point "
                                                   "landmark file per photo (.pts/.txt/.json/"
                                                   ".npy) instead of dlib."),
    levels: Optional[str] = typer.Option(None, "--levels", help="Image sizes of the "
                                         "photometric stage's levels in pixels, coarse to "
                                         "fine, e.g. '64,128'."),
    levels_old: Optional[str] = typer.Option(None, "--resolution", hidden=True,
                                             help="Deprecated: --levels."),
    iterations: Optional[str] = typer.Option(None, "--iterations", help="Photometric "
                                             "iterations per resolution, e.g. '40,30'."),
    spp: Optional[int] = typer.Option(None, help="Samples per pixel of the photometric stage."),
    no_photometric: bool = typer.Option(False, "--no-photometric", help="Landmark stages only."),
    texel: bool = typer.Option(False, "--texel", help="Per-texel albedo refinement (stage 5)."),
    per_view_expression: bool = typer.Option(False, "--per-view-expression",
                                             help="Multi-view: one expression per photo."),
    light_model: Optional[str] = typer.Option(None, "--light-model", help="Lighting model "
                                              "of the photometric stage: sg (default: order-2 "
                                              "spherical harmonics plus a spherical-Gaussian "
                                              "lobe for the dominant light), sh (the harmonics "
                                              "alone) or env (free environment texels)."),
    lighting_old: Optional[str] = typer.Option(None, "--lighting", hidden=True,
                                               help="Deprecated: --light-model."),
    mask: Optional[List[Path]] = typer.Option(None, "--mask", help="Person mask per photo "
                                              "(image of the photo's size, nonzero = person: "
                                              "head, hair, neck, clothes) for the silhouette "
                                              "term; default: segmented when the background "
                                              "is plain, else no silhouette term."),
    no_silhouette: bool = typer.Option(False, "--no-silhouette", help="No silhouette term."),
    detector: Optional[str] = typer.Option(None, "--detector", help="Landmark detector: "
                                           "dlib (default; its points refined), auto (the "
                                           "vision package's face mesh and shape predictors: "
                                           "real backgrounds, any angle) or both (their inner "
                                           "points averaged). Measured in docs/fit.md, 'The "
                                           "detectors'; config landmarks.detector."),
    no_refine: bool = typer.Option(False, "--no-refine", help="Fit dlib's points as dlib "
                                   "places them, without the landmark refiner (trained on "
                                   "synthetic renders; config landmarks.refiner)."),
    focal_mm: Optional[float] = typer.Option(None, "--focal-mm", help="35 mm-equivalent "
                                             "focal length of the photos (36 mm across the "
                                             "long side; uncropped photos). Default: EXIF's "
                                             "FocalLengthIn35mmFilm when the photo has it, "
                                             "else a prior centred on 85 mm. A single view "
                                             "barely constrains the focal length, and a wrong "
                                             "one distorts the fitted shape."),
    resume: bool = typer.Option(False, "--resume", help="Skip the fit when -o already "
                                "holds a complete one of the same photos, landmarks, masks, "
                                "focal length and config (fit_run.json); refuse other "
                                "inputs there; redo an incomplete one."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    threads: opts.Threads = None,
) -> None:
    """Fit HACK geometry, appearance, lighting and cameras to photos by inverse rendering.

    Example: hack-render fit face.jpg -o out/fit && hack-render render --params out/fit/params.json
    """
    # `--resolution` means an image size (W or WxH) in every other command; `--lighting` a
    # lighting preset: their old meanings here live on as hidden, deprecated spellings
    resolution = renamed(levels, levels_old, "fit --resolution", "--levels")
    lighting = renamed(light_model, lighting_old, "fit --lighting", "--light-model")
    over: dict = {"photometric": {}, "texel": {}}

    if resolution is not None:
        over["photometric"]["resolutions"] = boundary.numbers(
            resolution, "--levels", None, 16, 1024, integer=True, unit=" pixels",
            example="64,128")
        if not iterations:
            over["photometric"]["iterations"] = [30] * len(over["photometric"]["resolutions"])
    if iterations is not None:
        over["photometric"]["iterations"] = boundary.numbers(
            iterations, "--iterations", None, 1, 100000, integer=True, example="40,30",
            fix="A fit with no iterations fits nothing; use --no-photometric to skip the stage.")
        n_levels = len(over["photometric"].get("resolutions", [0] * len(
            over["photometric"]["iterations"])))
        if len(over["photometric"]["iterations"]) != n_levels:
            raise HackError(f"--iterations: expected one count per level ({n_levels}), found "
                            f"{len(over['photometric']['iterations'])} in {iterations!r}.")
    boundary.number(spp, "--spp", 1, 4096, integer=True)
    if spp is not None:
        over["photometric"]["spp"] = spp
    if lighting:
        over["photometric"]["lighting"] = lighting
    if no_photometric:
        over["photometric"]["enabled"] = False
    if texel:
        over["texel"]["enabled"] = True
    if per_view_expression:
        over["per_view_expression"] = True
    if no_silhouette:
        over["silhouette"] = {"mode": "off"}
    over["landmarks"] = {"refiner": "off"} if no_refine else {}
    if detector is not None:
        if detector not in DETECTORS:
            raise HackError(f"--detector: expected one of {', '.join(DETECTORS)}, found "
                            f"{detector!r}.")
        over["landmarks"]["detector"] = detector
    if config is not None:
        _refuse_duplicate_keys(config)
    cfg = load_config(config, over)
    if threads is not None:
        check_threads(threads)
    command_threads(threads)
    result, paths = fit_photos(photos, output, cfg, landmarks or None, progress=not quiet,
                               masks=mask or None, focal_mm=focal_mm, resume=resume)
    if result is None:
        typer.echo(f"{output} already holds a complete fit of these inputs (--resume): "
                   "nothing to do")
        return

    rep = output / "fit_report.json"
    far = far_from_landmarks(json.loads(rep.read_text())) if rep.is_file() else []
    for f in list(result.failures) + far:
        typer.secho(f"warning: {f}", err=True, fg=typer.colors.YELLOW)
    total = sum(result.timings.values())
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in result.timings.items())
    typer.echo(f"fit {len(photos)} photo(s) in {total:.1f} s ({stages})")
    typer.echo(f"wrote {len(paths)} files to {output.resolve()}")


def register(app: typer.Typer) -> None:
    """Add `fit` to the main app (the learners of the fitter's landmark embedding and
    refiner are hack_render.learn.cli's `learn landmark-embedding` and
    `learn landmark-refiner`)."""
    app.command("fit")(fit)
