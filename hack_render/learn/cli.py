"""`hack-render learn ...`: every learner under one group, and `hack-render model report`.

`learn model` (the full model), `learn base-model` (the ICT-FaceKit base), `learn appearance`,
`learn landmark-embedding`, `learn landmark-refiner`, `learn joints`, `learn template`
(the packaged skin template from ICT-FaceKit's OBJ), `learn pose` (the pose correctives of
a model file), `learn head-to-neck`, `learn larynx-motion` and `learn shape` (the identity
space from registrations). This module owns the group: every learner command is defined
here or in :mod:`hack_render.learn` (`learn shape`: :mod:`hack_render.learn.shape`), except
`appearance.cli.build` and `appearance.cli.template`, which the appearance package keeps
beside its builder and which are registered here. No lower package imports learn: the
learners' old names (`model build`, `model build-v2`, `appearance build`,
`calibrate-landmarks`, `train-landmark-refiner`) are added to the lower groups from here by
:func:`register`, and keep working for one release, hidden, with a deprecation message.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import typer
from tqdm import tqdm

from appearance import cli as appearance_cli
from hack_render import boundary, interrupts
from hack_render.cli_options import add_deprecated, renamed
from hack_render.errors import HackError
from hack_render.geometry import cli as geometry_cli
from hack_render.geometry import default_model_path
from hack_render.geometry.model_file import load_model_file, save_model_file
from hack_render.io import atomic_path
from hack_render.learn.motion_cli import learn_head_to_neck, learn_larynx_motion
from hack_render.learn.report import write_report
from hack_render.learn.shape import learn_shape_cmd

# The learners that import torch or SciPy when imported (landmark_calibration, ict_default,
# full_model, pose_energy, joint_regressor, fit.landmark_embedding, motion.head_to_neck,
# motion.larynx_motion) are imported inside the commands: `hack-render learn --help` must
# not import them (tests/test_cli.py, test_help_imports_no_heavy_module).

learn_app = typer.Typer(help="Learn HACK's components from data: the model, its joints, the "
                        "appearance model, the fitter's landmark embedding and refiner.",
                        no_args_is_help=True)


def build_base_model(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder: the development layout "
                             "(ict_facekit.npz, generic_neutral_mesh.obj, vertex_indices.json) or "
                             "the original FaceXModel/ folder of OBJs."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
) -> None:
    """Learn the base model from ICT-FaceKit: shape PCA, AU table, skeleton, weights (~15 s).

    Registered as `hack-render learn base-model` by hack_render.learn.cli.
    Example: hack-render learn base-model --ict ICT_FACEKIT_DIR -o base.npz
    """
    from hack_render.learn.ict_default import build_default_model

    boundary.input_dir(ict, "--ict", "ICT-FaceKit folder")
    boundary.output_file(output, "-o/--output", (".npz",))
    arrays, meta = build_default_model(ict)
    errors = save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")
    for key, err in errors.items():
        typer.echo(f"  {key}: int16 storage, max abs error {err:.3g} (unit vectors / metres)")


def build_v2(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder (as for `learn base-model`)."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
    expression_identities: int = typer.Option(300, help="Identities for deformation transfer."),
    pose_identities: int = typer.Option(4, help="Identities (beta ~ N(0, I), new each step) per "
                                        "step of the pose-corrective learner."),
    pose_iterations: int = typer.Option(700, help="Adam steps of the pose-corrective learner "
                                        "(skin energy over the whole joint space)."),
    expression_epochs: int = typer.Option(2000, help="Epochs of the M_E MLP."),
) -> None:
    """Learn the full model: the base model + larynx, personalised expressions and pose
    blendshapes (about 31 minutes on 2 CPU cores for the defaults).

    Example: hack-render learn model --ict ICT_FACEKIT_DIR -o model.npz
    """
    from hack_render.learn.full_model import build_full_model

    boundary.input_dir(ict, "--ict", "ICT-FaceKit folder")
    boundary.output_file(output, "-o/--output", (".npz",))
    boundary.number(expression_identities, "--expression-identities", 20, 100000, integer=True)
    boundary.number(pose_identities, "--pose-identities", 1, 1000, integer=True)
    boundary.number(pose_iterations, "--pose-iterations", 1, 1000000, integer=True)
    boundary.number(expression_epochs, "--expression-epochs", 1, 1000000, integer=True)
    typer.echo("learn model: about 31 minutes with the defaults (the shipped model's build, "
               "its learn.timings_s: 28 of them the pose correctives' 700 steps); the pose "
               f"stage's {pose_iterations} steps print their measured time a step",
               err=True)
    arrays, meta = build_full_model(ict, expression_identities, pose_identities, pose_iterations,
                                    expression_epochs,
                                    report=lambda line: _say(f"learn model: pose {line}"))
    save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")


def _command_line() -> str | None:
    """The command as typed, when run as ``hack-render learn ...`` (None when called from
    Python, e.g. the tests)."""
    if Path(sys.argv[0]).name == "hack-render" and sys.argv[1:2] == ["learn"]:
        return " ".join(["hack-render", *sys.argv[1:]])
    return None


#: the --loss keys that are thresholds on a triangle's normal cosine (posed against carried)
COSINE_THRESHOLDS = {"near_fold": "a screened row with a triangle below it is a hard example",
                     "f0": "a triangle below it counts as folding in the loss"}


def _loss_overrides(items: list[str]) -> dict:
    """``--loss KEY=VALUE`` items as a dict, keys checked against the learner's DEFAULTS."""
    from hack_render.learn.pose_energy import DEFAULTS

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        try:
            val = float(value)
        except ValueError:
            val = None
        if not sep or key not in DEFAULTS or val is None or not math.isfinite(val) or val < 0:
            raise HackError(f"--loss {item!r}: expected KEY=VALUE with KEY one of "
                            f"{', '.join(DEFAULTS)} and VALUE a number >= 0")
        if key in COSINE_THRESHOLDS and val >= 1:
            # every triangle's normal cosine is <= 1: near_fold >= 1 made every screened row
            # a hard example (the pool a queue of random rows), f0 >= 1 every triangle a fold
            raise HackError(f"--loss {item!r}: {key} is a threshold on a triangle's normal "
                            f"cosine ({COSINE_THRESHOLDS[key]}); give a value below 1 "
                            f"(default {DEFAULTS[key]:g})")
        out[key] = val
    return out


def learn_pose(
    model_path: Path | None = typer.Option(None, "--model", help="Model file to start from "
                                              "(default: built-in); its joints, shape space "
                                              "and skinning weights are used."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
    iterations: int = typer.Option(700, help="Adam steps (the time a step takes is measured "
                                   "over the first 10 and printed; it grows with "
                                   "--identities, --hard-examples and the rows mined)."),
    identities: int = typer.Option(4, help="Identities beta ~ N(0, I), new each step."),
    keep_weights: bool = typer.Option(False, "--keep-weights", help="Learn the correctives "
                                      "only; keep the file's skinning weights."),
    seed: int = typer.Option(12, help="Seed of the sampled identities and poses."),
    continue_: bool = typer.Option(False, "--continue", help="Continue from the model file's "
                                   "correctives, neck weights and M_P (an M_P that had died, one "
                                   "output for every identity, is restarted, its mean folded "
                                   "into P) instead of from zero."),
    lr: float = typer.Option(0.01, "--lr", help="Adam step of P, the components and the "
                             "weights' logits (cm), decaying linearly to 10 %."),
    mlp_lr: float = typer.Option(1e-4, "--mlp-lr", help="Adam step of M_P."),
    hard: int = typer.Option(16, "--hard-examples", help="Rows per step drawn from a pool of "
                             "mined hard examples (poses that fold, nearly fold or stretch "
                             "more than plain LBS); 0: none."),
    mine_poses: int = typer.Option(48, "--mine-poses", help="Fresh poses per identity "
                                   "screened for hard examples every 10 steps (more finds "
                                   "rarer folds, e.g. an expression's)."),
    mine_identities: int | None = typer.Option(None, "--mine-identities", help="Identities "
                                               "(each with its own sampled expression) "
                                               "screened every 10 steps; default: "
                                               "--identities. More finds the folds an "
                                               "expression and a pose make together."),
    expressions: bool = typer.Option(True, "--expressions/--neutral-only", help="Train on the "
                                     "model's own rest meshes with sampled expressions (as the "
                                     "stress test measures), or on neutral T_bar + B_S(beta)."),
    loss: list[str] = typer.Option([], "--loss", help="A loss weight or threshold of "
                                   "hack_render.learn.pose_energy.DEFAULTS, KEY=VALUE "
                                   "(repeatable), e.g. --loss worse_max=1000."),
    gate: float | None = typer.Option(None, "--pose-gate", help="Gate each joint's "
                                      "corrective by its angle, degrees (about angle^4 / "
                                      "(angle^4 + gate^4); model format 3); 0: no gate. "
                                      "Default: the --model file's gate with --continue, else "
                                      "none."),
    gate_chain: float | None = typer.Option(None, "--pose-gate-chain", help="With --pose-gate: "
                                            "the chain's net rotation also opens each joint's "
                                            "gate, with this weight (a nod spread over the "
                                            "joints; model format 4); 0: each joint's own angle "
                                            "alone. Default: the --model file's with --continue, "
                                            "else 0."),
    single_axis: bool = typer.Option(False, "--single-axis", help="Sample a quarter of the "
                                     "poses as whole-head rotations about one axis alone "
                                     "(flexion, axial or lateral, as the stress test's head_x/y/z "
                                     "families) instead of combined ones at 60 %% of the range."),
    corner: float = typer.Option(0.0, "--corner-poses", help="The share (0-1) of the "
                                 "full-range whole-head poses, in batches and mined rows, drawn "
                                 "near the box's corners (every axis in the outer quarter of its "
                                 "range: full flexion with a full bend). With --loss anchor=W "
                                 "(the squared change of P and C from the --continue file, cm^2) "
                                 "a continuation aimed at the corners' folds."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Re-learn a model's pose correctives (P, the personalised components and M_P) and the
    neck's skinning weights over the whole joint space (skin energy under LBS; see
    docs/learn.md).

    Example: hack-render learn pose -o model_pose.npz --iterations 700
    """
    from hack_render.learn.full_model import learn_pose_energy, pose_curves, pose_provenance

    if model_path is not None:
        boundary.input_file(model_path, "--model", (".npz",), "model file")
    boundary.output_file(output, "-o/--output", (".npz",))
    boundary.number(iterations, "--iterations", 1, 1000000, integer=True)
    boundary.number(identities, "--identities", 1, 1000, integer=True)
    boundary.number(seed, "--seed", 0, 2 ** 32 - 1, integer=True)
    boundary.number(lr, "--lr", 1e-6, 1.0)
    boundary.number(mlp_lr, "--mlp-lr", 1e-7, 1e-1)
    boundary.number(hard, "--hard-examples", 0, 10000, integer=True)
    boundary.number(mine_poses, "--mine-poses", 1, 10000, integer=True)
    boundary.number(corner, "--corner-poses", 0.0, 1.0)
    if mine_identities is not None:
        boundary.number(mine_identities, "--mine-identities", 1, 1000, integer=True)
    if gate is not None:
        boundary.number(gate, "--pose-gate", 0.0, 90.0)
    if gate_chain is not None:
        boundary.number(gate_chain, "--pose-gate-chain", 0.0, 100.0)

    overrides = _loss_overrides(loss)
    typer.echo(f"learn pose: {iterations} steps; each trains on {identities} identities x 8 "
               f"poses and {hard} hard rows, and every 10 steps {mine_identities or identities} "
               f"x {mine_poses} rows are screened (the time a step takes follows after the "
               "first 10)", err=True)
    src = model_path or default_model_path()
    arrays, meta = load_model_file(src)
    if continue_ and "pose_pca_components" not in arrays:
        raise HackError(f"{src}: --continue needs a model file with learned pose correctives "
                        "(pose_basis, pose_pca_components, pose_mlp_*); drop --continue to "
                        "learn them from zero.")
    start = dict(arrays) if continue_ else None
    if gate is None and continue_ and "pose_gate_deg" in arrays:
        gate = float(arrays["pose_gate_deg"])
    if gate_chain is None:
        gate_chain = float(arrays.get("pose_gate_chain", 0.0)) if continue_ else 0.0
    if gate_chain and not gate:
        raise HackError("--pose-gate-chain needs a gate: give --pose-gate DEGREES (or "
                        "--continue from a gated model file).")
    if "flex_basis" in arrays:
        typer.echo("learn pose: the model file's flexion block (format 5) is left out of the "
                   "output: it was fitted over that file's correctives (refit it over the new "
                   "ones with scripts/model_v8.py)", err=True)
    arrays = {k: v for k, v in arrays.items() if not k.startswith(("pose_", "flex_"))}
    po = learn_pose_energy(arrays, iterations=iterations, lr=lr, identities=identities,
                           learn_weights=not keep_weights, seed=seed, progress=not quiet,
                           start=start, mlp_lr=mlp_lr, hard=hard, mine_poses=mine_poses,
                           expressions=expressions,
                           loss=overrides, gate_deg=gate or None, single_axis=single_axis,
                           gate_chain=gate_chain if gate else 0.0,
                           mine_identities=mine_identities, corner=corner,
                           report=lambda line: _say(f"learn pose: {line}"))
    arrays.update(po["arrays"])
    meta.setdefault("provenance", {}).update(pose_provenance(po["report"]))
    learn = meta.setdefault("learn", {})
    po["report"]["command"] = _command_line()
    if continue_ and "pose" in learn:  # the runs this one continues, newest first
        before = {k: v for k, v in learn["pose"].items() if k != "history"}
        po["report"]["continued"]["previous"] = before
    learn["pose"] = po["report"]
    learn.setdefault("curves", {})["pose"] = pose_curves(po["arrays"])
    save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB; "
               f"pose learning {po['report']['seconds']:.0f} s)")


def report(
    model_path: Path | None = typer.Argument(None, help="Model file (default: built-in)."),
    output: Path = typer.Option(Path("out/model_report"), "-o", "--output", help="Output folder."),
) -> None:
    """Write Fig. 11-style compactness/generalisation curves (report.json, report.png)."""
    if model_path is not None:
        boundary.input_file(model_path, "MODEL", (".npz",), "model file")
    boundary.output_dir(output)
    _, meta = load_model_file(model_path or default_model_path())
    js, png = write_report(meta, output)
    typer.echo(f"wrote {js.resolve()}\nwrote {png.resolve()}")


def learn_joints(
    data: Path = typer.Argument(..., help=".npz with 'meshes' (P, N, 3) and 'joints' (P, 8, 3), metres."),
    output: Path = typer.Option(..., "-o", "--output", help="Where to write the regressor (.npy, (8, N))."),
    slab: float = typer.Option(0.012, help="Candidate ring half-height, metres."),
) -> None:
    """Train the joint regressor J (Eq. 6) from (mesh, joint) pairs, e.g. ultrasound labels."""
    from hack_render.learn.joint_regressor import joint_errors, train_joint_regressor

    boundary.input_file(data, "DATA", (".npz",), "training data file")
    boundary.output_file(output, "-o/--output", (".npy",))
    boundary.number(slab, "--slab", 0.001, 0.1, unit=" metres")
    meshes, joints = _joint_data(data)
    typer.echo(f"learn joints: {len(meshes)} pairs of {meshes.shape[1]} vertices, 8 joints "
               "(a bounded least squares per joint; large meshes take minutes)")
    reg = train_joint_regressor(meshes, joints, slab=slab)
    if not np.isfinite(reg).all():
        raise HackError(f"{data}: the regressor came out non-finite; check 'meshes' and "
                        "'joints' (metres, the same people in the same order).")

    with atomic_path(output) as tmp:
        np.save(tmp, reg.astype(np.float32))
    err = joint_errors(reg, meshes, joints) * 1e3
    typer.echo(f"wrote {output.resolve()}; training error mean {err.mean():.2f} mm, max {err.max():.2f} mm")


def _say(line: str) -> None:
    """A line on stderr from inside a loop with a progress bar (the bar is redrawn below)."""
    tqdm.write(line, file=sys.stderr)


def _joint_data(data: Path):
    """(meshes (P, N, 3), joints (P, 8, 3)) float64 from a training .npz, checked: keys,
    numeric dtypes, shapes, the same P >= 2, finite values."""
    try:
        with np.load(data, allow_pickle=False) as z:
            keys = list(z.keys())
            if "meshes" not in keys or "joints" not in keys:
                raise HackError(f"{data}: expected keys 'meshes' and 'joints', found {keys}.")
            meshes, joints = z["meshes"], z["joints"]
    except HackError:
        raise
    except Exception as err:  # not a zip, pickled objects, truncated: numpy's many errors
        raise HackError(f"{data}: expected a .npz of numeric arrays 'meshes' (P, N, 3) and "
                        f"'joints' (P, 8, 3), could not read it ({err}).") from err
    for key, arr, want in (("meshes", meshes, "(P, N, 3)"), ("joints", joints, "(P, 8, 3)")):
        if not np.issubdtype(arr.dtype, np.number) or arr.ndim != 3 or arr.shape[2] != 3:
            raise HackError(f"{data}: key '{key}' expected numbers of shape {want}, metres, "
                            f"found {arr.dtype} {arr.shape}.")
        if not np.isfinite(arr).all():
            raise HackError(f"{data}: key '{key}' contains NaN or inf; expected finite "
                            "positions in metres (drop the unlabelled pairs).")
    if joints.shape[1] != 8:
        raise HackError(f"{data}: key 'joints' expected 8 joints per pair (c7-t1 ... o-c1), "
                        f"found {joints.shape[1]}.")
    if len(meshes) != len(joints) or len(meshes) < 2:
        raise HackError(f"{data}: expected the same number P >= 2 of meshes and joints, found "
                        f"{len(meshes)} and {len(joints)}.")
    return meshes.astype(np.float64), joints.astype(np.float64)


def calibrate_landmarks(
    output: Path = typer.Option(..., "-o", "--output", help="Embedding file to write (.npz), "
                                "e.g. hack_render/data/landmark_embedding_dlib.npz."),
    subjects: int = typer.Option(60, "--subjects", min=1, help="Synthetic subjects to render "
                                 "(the detector's misses are left out and reported)."),
    seed: int | None = typer.Option(None, "--seed", help="Dataset sampler seed of the subjects "
                             "(default 5150; bench/bench_fit.py's subjects are disjoint)."),
    resolution: int | None = typer.Option(None, "--resolution", help="Render size in "
                                             "pixels (default 320)."),
    resolution_old: int | None = typer.Option(None, "--res", hidden=True,
                                                 help="Deprecated: --resolution."),
    spp: int | None = typer.Option(None, "--spp", help="Samples per pixel (default 16)."),
    radius: float = typer.Option(0.025, "--radius", help="Search radius around each model "
                                 "landmark vertex, metres on the rest mesh."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Calibrate the 68-landmark embedding (triangle + barycentrics per landmark) to dlib.

    Renders synthetic subjects of the default model with known geometry and cameras (the
    dataset sampler), runs dlib on each and picks, per landmark (18-68; the jawline stays
    contour-matched), the skin point whose projections are nearest to dlib's points.
    The fitter uses hack_render/data/landmark_embedding_dlib.npz by default.

    Example: hack-render learn landmark-embedding -o emb.npz --subjects 60
    """
    from hack_render.fit import landmark_embedding as le
    from hack_render.learn import landmark_calibration as lc

    resolution = renamed(resolution, resolution_old, "--res", "--resolution")
    boundary.output_file(output, "-o/--output", (".npz",))
    boundary.number(resolution, "--resolution", 64, 4096, integer=True, unit=" pixels")
    boundary.number(spp, "--spp", 1, 4096, integer=True)
    boundary.number(radius, "--radius", 0.001, 0.2, unit=" metres")
    boundary.number(seed, "--seed", 0, 2 ** 63 - 1, integer=True)
    seed = le.CALIBRATION_SEED if seed is None else seed
    typer.echo(f"learn landmark-embedding: {subjects} synthetic subjects to render and detect "
               f"(about 2 s each on 2 CPU cores: ~{max(1, round(subjects * 2 / 60))} min)",
               err=True)
    cmd = "hack-render " + " ".join(sys.argv[1:]) if len(sys.argv) > 2 else ""
    emb, _report = lc.build(output, subjects, seed, resolution, spp, radius, command=cmd,
                            progress=not quiet)
    typer.echo(json.dumps({"used": emb.meta["subjects_used"],
                           "left_out": len(emb.meta["left_out"]),
                           "calibrated": int(emb.calibrated.sum()),
                           "nme_median": emb.meta["calibration_nme_median"]}))
    typer.echo(f"wrote {Path(output).resolve()}")


def train_landmark_refiner(
    output: Path = typer.Option(..., "-o", "--output", help="Refiner file to write (.npz), "
                                "e.g. hack_render/data/landmark_refiner_dlib.npz."),
    subjects: int = typer.Option(1150, "--subjects", min=20, help="Synthetic subjects to "
                                 "render (dlib's misses are left out and counted)."),
    seed: int | None = typer.Option(None, "--seed", help="Dataset sampler seed of the "
                                       "subjects (default 5150, the calibration's)."),
    stages: int = typer.Option(3, "--stages", min=1, max=8, help="SDM stages."),
    lam: float = typer.Option(100.0, "--lambda", min=0.0, help="Ridge penalty."),
    holdout: float = typer.Option(0.1, "--holdout", min=0.0, max=0.5, help="Share of the "
                                  "subjects held out to measure the refiner and set its "
                                  "loss weights."),
    cache: Path | None = typer.Option(None, "--cache", help="Folder for the renders, in "
                                         "chunks of 50 subjects: an interrupted run resumes "
                                         "from it."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Train the landmark refiner: dlib's inner points moved toward the calibrated
    embedding's points by a regression of the image (supervised descent, HOG-like patch
    features), learned on synthetic renders of the default model with known geometry.

    Renders the subjects (about 2 s each on 2 cores), runs dlib on each, trains on all but
    the held-out share and reports dlib's and the refined points' error there (rms over the
    inner points, % of the inter-ocular distance). The fitter uses
    hack_render/data/landmark_refiner_dlib.npz by default (config landmarks.refiner).

    Example: hack-render learn landmark-refiner -o refiner.npz --subjects 1150 --cache renders/
    """
    from hack_render.learn import landmark_refiner_training

    boundary.output_file(output, "-o/--output", (".npz",))
    boundary.number(seed, "--seed", 0, 2 ** 63 - 1, integer=True)
    boundary.number(lam, "--lambda", 0.0, 1e12)
    if cache is not None:
        boundary.output_dir(cache, "--cache")
    cmd = "hack-render " + " ".join(sys.argv[1:]) if len(sys.argv) > 2 else ""
    note = (f"the renders done so far are kept in --cache {cache}; run the same command to "
            "go on from them" if cache is not None else
            "nothing was written (give --cache DIR to keep the renders of an interrupted run)")
    typer.echo(f"learn landmark-refiner: {subjects} synthetic subjects to render and detect "
               f"(about 2 s each on 2 CPU cores: ~{max(1, round(subjects * 2 / 60))} min, "
               "less for those already in --cache)", err=True)
    with interrupts.on_interrupt(note):
        _ref, report = landmark_refiner_training.build(output, subjects, seed, stages, lam,
                                                       holdout, cache, command=cmd,
                                                       progress=not quiet)
    typer.echo(json.dumps({k: v for k, v in report.items() if k != "left_out"}))
    typer.echo(f"wrote {Path(output).resolve()}")


def register(app: typer.Typer) -> None:
    """Add the `learn` group, `model report` and the learners' deprecated old names (on
    the groups that had them: `model`, `appearance` and the main app)."""

    learners = [("model", build_v2, "model build-v2", geometry_cli.model_app, "build-v2"),
                ("base-model", build_base_model, "model build", geometry_cli.model_app,
                 "build"),
                ("appearance", appearance_cli.build, "appearance build", appearance_cli.app,
                 "build"),
                ("landmark-embedding", calibrate_landmarks, "calibrate-landmarks", app,
                 "calibrate-landmarks"),
                ("landmark-refiner", train_landmark_refiner, "train-landmark-refiner",
                 app, "train-landmark-refiner")]
    for name, func, old, old_app, old_name in learners:
        learn_app.command(name)(func)
        add_deprecated(old_app, old_name, func, old, f"learn {name}")
    learn_app.command("joints")(learn_joints)
    learn_app.command("template")(appearance_cli.template)
    learn_app.command("pose")(learn_pose)
    learn_app.command("head-to-neck")(learn_head_to_neck)
    learn_app.command("larynx-motion")(learn_larynx_motion)
    learn_app.command("shape")(learn_shape_cmd)
    geometry_cli.model_app.command("report")(report)
    app.add_typer(learn_app, name="learn")
