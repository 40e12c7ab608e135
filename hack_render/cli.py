"""The `hack-render` command line: one command, several subcommands.

Each layer contributes its own Typer sub-app or commands; this module only wires them
together and turns the ways a command ends into exit codes: 0 done; 2 a user error (a
:class:`hack_render.errors.HackError`, a usage error, a full disk or an unwritable
output), one line; 130 Ctrl-C and 143 SIGTERM, one line saying what was kept and how to
resume. What a user can get wrong is checked by :mod:`hack_render.boundary`.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading

import typer
from typer.core import TyperGroup
from typer.main import get_group

from hack_render import __version__, boundary, interrupts
from hack_render.errors import USER_OS_ERRORS, HackError, os_error_message

#: every command of `hack-render`: its name, the first paragraph of its help (shown by
#: `hack-render --help` without importing anything heavy; tests/test_cli.py checks it
#: against the command's own) and the modules whose ``register(app)`` defines it (a group
#: may get commands from more than one). Hidden commands (deprecated names) are listed with
#: an empty help. The modules are imported only when the command runs or shows its help.
COMMANDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "mesh": ("Write a posed HACK mesh (OBJ/PLY with UVs) for the given parameters.",
             ("hack_render.geometry.cli",)),
    "render": ("Render the head model to a PNG and/or an EXR with AOVs; cameras go to a JSON "
               "(OpenCV).", ("hack_render.render.cli",)),
    "turntable": ("Render a seamless looping turntable of the head to MP4 (H.264) / GIF / PNG "
                  "frames.", ("hack_render.render.turntable_cli",)),
    "fit": ("Fit HACK geometry, appearance, lighting and cameras to photos by inverse "
            "rendering.", ("hack_render.fit.cli",)),
    "calibrate-landmarks": ("", ("hack_render.learn.cli",)),
    "train-landmark-refiner": ("", ("hack_render.learn.cli",)),
    "export": ("Export one person to CG tools: a rigged glTF 2.0 (skeleton, 53 expression, "
               "larynx and pose-corrective morph targets, PBR skin, optional animation, optional hair "
               "cards) or OBJ/PLY mesh files.", ("hack_render.export.cli",)),
    "view": ("Serve a local page (127.0.0.1 only, three.js bundled, no network) that shows an "
             "exported person with sliders for the expressions, the 8 joints, the larynx and "
             "the animation's timeline. Stop with Ctrl-C.", ("hack_render.export.cli",)),
    "transfer": ("Move HACK motion onto another character: an animated glTF, a turntable and "
                 "report.json (the pose-space stress test's measures on every frame; for a "
                 "glTF character, the alignment, bake and morph-target figures).",
                 ("hack_render.motion.cli",)),
    "register": ("Register HACK to 3-D scans: similarity alignment from landmarks, then "
                 "identity, expression, the 8 neck joints, larynx and global pose by a robust "
                 "two-way surface distance, then free-form offsets. Finished scans are skipped "
                 "(resumable).", ("hack_render.register.cli",)),
    "drive": ("Turn a face capture into HACK motion: expressions from ARKit blendshapes "
              "(psi), the head's rotation shared over the 8 neck joints (theta).",
              ("hack_render.motion.drive_cli",)),
    "track": ("Track a video into HACK parameters: one identity for the clip, and per frame "
              "the 8 neck joints (from the head's rotation), the torso, the expression and the "
              "larynx's slide tau (the keyframe fit's; --tau photometric: per frame from the "
              "neck's shading). The neck is placed on the head-and-neck outline (the face mesh's "
              "oval and the neck's skin, no hair; --no-outline: landmarks alone). A track "
              "whose points lie far from the detected ones is reported on stderr and as the "
              "report's status \"poor\".", ("hack_render.track.cli",)),
    "model": ("Inspect HACK model files (`hack-render learn model` builds one).",
              ("hack_render.geometry.cli", "hack_render.learn.cli")),
    "appearance": ("Appearance model A(alpha): sample, report (`hack-render learn appearance` "
                   "builds one, `hack-render learn template` rebuilds its skin template).",
                   ("appearance.cli", "hack_render.learn.cli")),
    "learn": ("Learn HACK's components from data: the model, its joints, the appearance "
              "model, the fitter's landmark embedding and refiner.",
              ("hack_render.learn.cli",)),
    "dataset": ("Render labelled datasets (docs/datasets.md).", ("hack_render.dataset.cli",)),
}

_REGISTERED: set[str] = set()
_ALL = typer.Typer(add_completion=False)  # every loaded module's commands


@_ALL.callback()
def _all() -> None:  # a callback makes get_group build a group even for one command
    pass


def load_commands(names=None) -> dict:
    """Import the modules that define the commands ``names`` (default: all), let each
    register its commands once, and return the click commands by name."""
    for name in COMMANDS if names is None else names:
        for module in COMMANDS[name][1]:
            if module not in _REGISTERED:
                importlib.import_module(module).register(_ALL)
                _REGISTERED.add(module)
    return get_group(_ALL).commands


class LazyGroup(TyperGroup):
    """The top-level group: lists the commands from :data:`COMMANDS` and imports a
    command's modules only when it runs or shows its own help, so `hack-render --help` and
    `hack-render --version` import nothing heavy."""

    def list_commands(self, ctx) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx, cmd_name: str):
        if cmd_name in self.commands:
            return self.commands[cmd_name]
        if cmd_name not in COMMANDS:
            return None
        text = COMMANDS[cmd_name][0]
        # a stand-in for the listing of --help: the name and its help, nothing imported
        return typer.core.TyperCommand(cmd_name, help=text, hidden=not text)

    def resolve_command(self, ctx, args):
        if args and args[0] in COMMANDS:
            self.commands.update(load_commands([args[0]]))
        return super().resolve_command(ctx, args)


#: what `hack-render --version` imports (numpy, to read the model file's header)
VERSION_MODULES = ("hack_render.geometry.model_file",)


def _model_version() -> str:
    """The built-in default model's name and versions, read from its file's header."""
    model_file = importlib.import_module(VERSION_MODULES[0])
    try:
        version, meta = model_file.file_header(model_file.default_model_path())
    except HackError as err:
        return f"default model: unreadable ({err})"
    return (f"default model: {meta.get('name', '?')}, model version "
            f"{meta.get('model_version', '?')}, file format {version}")


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"hack-render {__version__}")
        typer.echo(_model_version())
        raise typer.Exit()


app = typer.Typer(
    name="hack-render",
    cls=LazyGroup,
    help=(
        "Render, fit and animate the HACK head-and-neck model.\n\n"
        "Start with `hack-render mesh -o out/head.obj` (a posed mesh of the built-in "
        "default model) and `hack-render COMMAND --help` for each command."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_print_version,
                                       is_eager=True, help="Print the version of hack-render "
                                       "and of its built-in default model, and exit.")) -> None:
    pass


def main(argv: list[str] | None = None) -> None:
    """Console entry point: runs the app; exit codes: 0 done, 2 a user error (a
    :class:`~hack_render.errors.HackError`, a usage error, a disk full or unwritable
    output), 130 interrupted (Ctrl-C) and 143 terminated (SIGTERM, e.g. a Slurm time
    limit), each with one line saying what was kept and how to resume
    (:func:`hack_render.interrupts.on_interrupt`). An interruption wins over whatever
    exception it surfaces as (a native loop or import wraps it in a RuntimeError or an
    ImportError)."""
    interrupts.interrupt_message()  # forget a note left by an earlier in-process call
    interrupts.forget_signals()
    boundary.set_command_words(argv)  # the words as typed (`-o x.obj/`: a folder's spelling)

    def on_signal(signum, frame):  # as Ctrl-C: complete what is queued, say what is kept
        interrupts.note_signal(signum)
        raise KeyboardInterrupt

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        code = _run(argv)
    finally:
        boundary.set_command_words(None)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if code == 130:
        line = interrupts.interrupt_message()
        if signal.SIGTERM in interrupts.signals_received():
            line, code = line.replace("interrupted:", "terminated (SIGTERM):", 1), 143
        typer.secho(line, err=True, fg=typer.colors.YELLOW)
    if isinstance(code, int) and not isinstance(code, bool) and code != 0:
        sys.exit(code)


def _run(argv: list[str] | None) -> int | None:
    """Run the app; returns its exit code (130: interrupted), printing user errors."""
    try:
        # standalone_mode=False: Typer *returns* an exit code (130 on Ctrl-C, n for
        # typer.Exit(n)) instead of exiting; it must not be dropped
        return app(args=argv, standalone_mode=False)
    except HackError as err:
        typer.secho(f"error: {err}", err=True, fg=typer.colors.RED)
        return 2
    except (KeyboardInterrupt, typer.Abort):  # outside a command (parsing, importing)
        return 130
    except SystemExit:
        raise
    except Exception as err:  # sorted below; what is not ours is re-raised
        if interrupts.is_interruption(err):  # Ctrl-C / SIGTERM inside a native loop or import
            return 130
        if isinstance(err, OSError) and err.errno in USER_OS_ERRORS:
            typer.secho(f"error: {os_error_message(err)}", err=True,
                        fg=typer.colors.RED)
            return 2
        # click usage errors carry their own exit code; by what they do, not their class:
        # typer >= 0.2x vendors click as typer._click, whose exceptions are not click's own
        if callable(getattr(err, "show", None)) and hasattr(err, "exit_code"):
            err.show()  # "Usage: ... Error: No such option: --x"
            return 2
        if isinstance(err, typer.Exit) or type(err).__name__ == "Exit":
            return err.exit_code
        raise


if __name__ == "__main__":
    main()
