"""`hack-render learn ...`: every learner under one group, and `hack-render model report`.

`learn model` (the full model), `learn base-model` (the ICT-FaceKit base), `learn joints`,
`learn pose` (the pose correctives of a model file), `learn appearance`,
`learn landmark-embedding`, `learn landmark-refiner`, `learn template`
(the packaged skin template from ICT-FaceKit's OBJ). The commands
whose code lives beside what they learn (`hack_render.geometry.cli.build`,
`appearance.cli.build`, `hack_render.fit.cli.calibrate_landmarks` and
`train_landmark_refiner`) are registered here; their old names (`model build`,
`model build-v2`, `appearance build`, `calibrate-landmarks`, `train-landmark-refiner`)
keep working for one release, hidden, with a deprecation message.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import typer

from hack_render.errors import HackError

learn_app = typer.Typer(help="Learn HACK's components from data: the model, its joints, the "
                        "appearance model, the fitter's landmark embedding and refiner.",
                        no_args_is_help=True)


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
    from hack_render import boundary
    from hack_render.geometry.model_file import save_model_file
    from hack_render.learn.full_model import build_full_model

    boundary.input_dir(ict, "--ict", "ICT-FaceKit folder")
    boundary.output_file(output, "-o/--output", (".npz",))
    boundary.number(expression_identities, "--expression-identities", 20, 100000, integer=True)
    boundary.number(pose_identities, "--pose-identities", 1, 1000, integer=True)
    boundary.number(pose_iterations, "--pose-iterations", 1, 1000000, integer=True)
    boundary.number(expression_epochs, "--expression-epochs", 1, 1000000, integer=True)
    typer.echo(f"learn model: about 31 minutes on 2 CPU cores with the defaults, of which "
               f"the pose correctives take about {pose_iterations * 1.5 / 60:.0f} "
               f"({pose_iterations} steps of ~1.5 s)", err=True)
    arrays, meta = build_full_model(ict, expression_identities, pose_identities, pose_iterations,
                                    expression_epochs)
    save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")


def _command_line() -> str | None:
    """The command as typed, when run as ``hack-render learn ...`` (None when called from
    Python, e.g. the tests)."""
    if Path(sys.argv[0]).name == "hack-render" and sys.argv[1:2] == ["learn"]:
        return " ".join(["hack-render", *sys.argv[1:]])
    return None


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
        out[key] = val
    return out


def learn_pose(
    model_path: Path | None = typer.Option(None, "--model", help="Model file to start from "
                                              "(default: built-in); its joints, shape space "
                                              "and skinning weights are used."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
    iterations: int = typer.Option(700, help="Adam steps (about 1.5 s each on 2 CPU cores)."),
    identities: int = typer.Option(4, help="Identities beta ~ N(0, I), new each step."),
    keep_weights: bool = typer.Option(False, "--keep-weights", help="Learn the correctives "
                                      "only; keep the file's skinning weights."),
    seed: int = typer.Option(12, help="Seed of the sampled identities and poses."),
    continue_: bool = typer.Option(False, "--continue", help="Continue from the model file's "
                                   "correctives and neck weights (M_P restarted, its mean "
                                   "folded into P) instead of from zero."),
    lr: float = typer.Option(0.01, "--lr", help="Adam step of P, the components and the "
                             "weights' logits (cm), decaying linearly to 10 %."),
    mlp_lr: float = typer.Option(1e-4, "--mlp-lr", help="Adam step of M_P."),
    hard: int = typer.Option(16, "--hard-examples", help="Rows per step drawn from a pool of "
                             "mined hard examples (poses that fold, nearly fold or stretch "
                             "more than plain LBS); 0: none."),
    expressions: bool = typer.Option(True, "--expressions/--neutral-only", help="Train on the "
                                     "model's own rest meshes with sampled expressions (as the "
                                     "stress test measures), or on neutral T_bar + B_S(beta)."),
    loss: list[str] = typer.Option([], "--loss", help="A loss weight or threshold of "
                                   "hack_render.learn.pose_energy.DEFAULTS, KEY=VALUE "
                                   "(repeatable), e.g. --loss worse_max=1000."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Re-learn a model's pose correctives (P, the personalised components and M_P) and the
    neck's skinning weights over the whole joint space (skin energy under LBS; see
    docs/learn.md).

    Example: hack-render learn pose -o model_pose.npz --iterations 700
    """
    from hack_render import boundary
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file, save_model_file
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
    overrides = _loss_overrides(loss)
    typer.echo(f"learn pose: {iterations} steps of about 1.5 s on 2 CPU cores (~"
               f"{max(1, round(iterations * 1.5 / 60))} min)", err=True)
    src = model_path or default_model_path()
    arrays, meta = load_model_file(src)
    if continue_ and "pose_pca_components" not in arrays:
        from hack_render.errors import HackError

        raise HackError(f"{src}: --continue needs a model file with learned pose correctives "
                        "(pose_basis, pose_pca_components, pose_mlp_*); drop --continue to "
                        "learn them from zero.")
    start = dict(arrays) if continue_ else None
    arrays = {k: v for k, v in arrays.items() if not k.startswith("pose_")}
    po = learn_pose_energy(arrays, iterations=iterations, lr=lr, identities=identities,
                           learn_weights=not keep_weights, seed=seed, progress=not quiet,
                           start=start, mlp_lr=mlp_lr, hard=hard, expressions=expressions,
                           loss=overrides)
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
    from hack_render import boundary
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file
    from hack_render.learn.report import write_report

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
    import numpy as np

    from hack_render import boundary
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
    from hack_render.io import atomic_path

    with atomic_path(output) as tmp:
        np.save(tmp, reg.astype(np.float32))
    err = joint_errors(reg, meshes, joints) * 1e3
    typer.echo(f"wrote {output.resolve()}; training error mean {err.mean():.2f} mm, max {err.max():.2f} mm")


def _joint_data(data: Path):
    """(meshes (P, N, 3), joints (P, 8, 3)) float64 from a training .npz, checked: keys,
    numeric dtypes, shapes, the same P >= 2, finite values."""
    import numpy as np

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


def register(app: typer.Typer) -> None:
    """Add the `learn` group, `model report` and the learners' deprecated old names."""
    from appearance import cli as appearance_cli
    from hack_render.cli_options import add_deprecated
    from hack_render.fit import cli as fit_cli
    from hack_render.geometry import cli as geometry_cli

    learners = [("model", build_v2, "model build-v2", geometry_cli.model_app, "build-v2"),
                ("base-model", geometry_cli.build, "model build", geometry_cli.model_app,
                 "build"),
                ("appearance", appearance_cli.build, "appearance build", appearance_cli.app,
                 "build"),
                ("landmark-embedding", fit_cli.calibrate_landmarks, "calibrate-landmarks", app,
                 "calibrate-landmarks"),
                ("landmark-refiner", fit_cli.train_landmark_refiner, "train-landmark-refiner",
                 app, "train-landmark-refiner")]
    for name, func, old, old_app, old_name in learners:
        learn_app.command(name)(func)
        add_deprecated(old_app, old_name, func, old, f"learn {name}")
    learn_app.command("joints")(learn_joints)
    learn_app.command("template")(appearance_cli.template)
    learn_app.command("pose")(learn_pose)
    geometry_cli.model_app.command("report")(report)
    app.add_typer(learn_app, name="learn")
