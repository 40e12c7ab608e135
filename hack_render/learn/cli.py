"""`hack-render model build-v2`, `hack-render model report`, `hack-render learn joints`.

The `model` sub-app belongs to :mod:`hack_render.geometry.cli`; this module adds its two
commands to it and a `learn` sub-app of its own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from hack_render.errors import HackError

learn_app = typer.Typer(help="Train HACK components from your own data.", no_args_is_help=True)


def build_v2(
    ict: Path = typer.Option(..., "--ict", help="ICT-FaceKit folder (as for `model build`)."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
    expression_identities: int = typer.Option(300, help="Identities for deformation transfer."),
    pose_identities: int = typer.Option(12, help="Identities with simulated pose sequences."),
    pose_iterations: int = typer.Option(30, help="Adam iterations of the pose learner (after its closed-form start)."),
    expression_epochs: int = typer.Option(2000, help="Epochs of the M_E MLP."),
) -> None:
    """Build the v2 model: v1 + larynx, personalised expressions, pose blendshapes (minutes)."""
    from hack_render.learn.full_model import build_full_model
    from hack_render.geometry.model_file import save_model_file

    if expression_identities < 20 or pose_identities < 2:
        raise HackError("--expression-identities must be >= 20 and --pose-identities >= 2.")
    arrays, meta = build_full_model(ict, expression_identities, pose_identities, pose_iterations,
                                    expression_epochs)
    save_model_file(output, arrays, meta)
    typer.echo(f"wrote {output.resolve()} ({output.stat().st_size / 1e6:.1f} MB)")


def report(
    model_path: Optional[Path] = typer.Argument(None, help="Model file (default: built-in)."),
    output: Path = typer.Option(Path("out/model_report"), "-o", "--output", help="Output folder."),
) -> None:
    """Write Fig. 11-style compactness/generalisation curves (report.json, report.png)."""
    from hack_render.learn.report import write_report
    from hack_render.geometry import default_model_path
    from hack_render.geometry.model_file import load_model_file

    _, meta = load_model_file(model_path or default_model_path())
    js, png = write_report(meta, output)
    typer.echo(f"wrote {js.resolve()}\nwrote {png.resolve()}")


@learn_app.command("joints")
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
    from hack_render.geometry.cli import model_app

    model_app.command("build-v2")(build_v2)
    model_app.command("report")(report)
    app.add_typer(learn_app, name="learn")
