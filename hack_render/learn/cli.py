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
    from hack_render.geometry.model_file import save_model_file
    from hack_render.learn.full_model import build_full_model

    if expression_identities < 20 or pose_identities < 1 or pose_iterations < 1:
        raise HackError("--expression-identities must be >= 20, --pose-identities and "
                        "--pose-iterations >= 1.")
    arrays, meta = build_full_model(ict, expression_identities, pose_identities, pose_iterations,
                                    expression_epochs)
    save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")


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
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Re-learn a model's pose correctives (P, the personalised components and M_P) and the
    neck's skinning weights over the whole joint space (skin energy under LBS; see
    docs/learn.md).

    Example: hack-render learn pose -o model_pose.npz --iterations 700
    """
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file, save_model_file
    from hack_render.learn.full_model import learn_pose_energy, pose_curves, pose_provenance

    if iterations < 1 or identities < 1:
        raise HackError("--iterations and --identities must be >= 1.")
    src = model_path or default_model_path()
    arrays, meta = load_model_file(src)
    arrays = {k: v for k, v in arrays.items() if not k.startswith("pose_")}
    po = learn_pose_energy(arrays, iterations=iterations, identities=identities,
                           learn_weights=not keep_weights, seed=seed, progress=not quiet)
    arrays.update(po["arrays"])
    meta.setdefault("provenance", {}).update(pose_provenance(po["report"]))
    learn = meta.setdefault("learn", {})
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
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file
    from hack_render.learn.report import write_report

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

    from hack_render.learn.joint_regressor import joint_errors, train_joint_regressor

    if not data.is_file():
        raise HackError(f"{data}: not found; pass an .npz with 'meshes' and 'joints'.")
    with np.load(data) as z:
        if "meshes" not in z or "joints" not in z:
            raise HackError(f"{data}: expected keys 'meshes' and 'joints', found {list(z.keys())}.")
        meshes, joints = z["meshes"], z["joints"]
    reg = train_joint_regressor(meshes, joints, slab=slab)
    np.save(output, reg.astype(np.float32))
    err = joint_errors(reg, meshes, joints) * 1e3
    typer.echo(f"wrote {output.resolve()}; training error mean {err.mean():.2f} mm, max {err.max():.2f} mm")


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
