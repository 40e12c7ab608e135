"""The `hack-render` command line: one command, several subcommands.

Each layer contributes its own Typer sub-app or commands; this module only wires them
together and turns the ways a command ends into exit codes: 0 done; 2 a user error (a
:class:`hack_render.errors.HackError`, a usage error, a full disk or an unwritable
output), one line; 130 Ctrl-C and 143 SIGTERM, one line saying what was kept and how to
resume. What a user can get wrong is checked by :mod:`hack_render.boundary`.
"""

# ruff: noqa: I001 - the sub-apps block is one line per owner, in the order of --help

from __future__ import annotations

import errno
import sys

import typer

from hack_render.errors import HackError

app = typer.Typer(
    name="hack-render",
    help=(
        "Render, fit and animate the HACK head-and-neck model.\n\n"
        "Start with `hack-render mesh -o out/head.obj` (a posed mesh of the built-in "
        "default model) and `hack-render COMMAND --help` for each command."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# --- sub-apps and commands: one line each, owned by the module named -----------------
from hack_render.geometry import cli as _geometry_cli

_geometry_cli.register(app)
from appearance import cli as _appearance_cli; app.add_typer(_appearance_cli.app, name="appearance")
from hack_render.render import cli as _render_cli; _render_cli.register(app)
from hack_render.render import turntable_cli as _turntable_cli; _turntable_cli.register(app)
from hack_render.fit import cli as _fit_cli; _fit_cli.register(app)
from hack_render.learn import cli as _learn_cli; _learn_cli.register(app)
from hack_render.dataset import cli as _dataset_cli; _dataset_cli.register(app)
from hack_render.export import cli as _export_cli; _export_cli.register(app)
from hack_render.motion import cli as _motion_cli; _motion_cli.register(app)
from hack_render.register import cli as _register_cli; _register_cli.register(app)
from hack_render.motion import drive_cli as _drive_cli; _drive_cli.register(app)
from hack_render.track import cli as _track_cli; _track_cli.register(app)
# --- end of sub-apps --------------------------------------------------------------------

#: OS errors that are the user's environment, not a bug: a clean message and exit 2
_USER_OS_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM,
                   errno.EISDIR, errno.ENOTDIR, errno.EEXIST, errno.ENOENT, errno.ENAMETOOLONG}


def main(argv: list[str] | None = None) -> None:
    """Console entry point: runs the app; exit codes: 0 done, 2 a user error (a
    :class:`~hack_render.errors.HackError`, a usage error, a disk full or unwritable
    output), 130 interrupted (Ctrl-C) and 143 terminated (SIGTERM, e.g. a Slurm time
    limit), each with one line saying what was kept and how to resume
    (:func:`hack_render.boundary.on_interrupt`)."""
    import signal
    import threading

    from hack_render import boundary

    boundary.interrupt_message()  # forget a note left by an earlier in-process call
    terminated: list[int] = []

    def on_sigterm(signum, frame):  # as Ctrl-C: complete what is queued, say what is kept
        terminated.append(signum)
        raise KeyboardInterrupt

    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        code = _run(argv)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if code == 130:
        line = boundary.interrupt_message()
        if terminated:
            line, code = line.replace("interrupted:", "terminated (SIGTERM):", 1), 143
        typer.secho(line, err=True, fg=typer.colors.YELLOW)
    if isinstance(code, int) and not isinstance(code, bool) and code != 0:
        sys.exit(code)


def _run(argv: list[str] | None) -> int | None:
    """Run the app; returns its exit code (130: interrupted), printing user errors."""
    from hack_render import boundary

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
    except OSError as err:
        if err.errno not in _USER_OS_ERRORS:
            raise
        typer.secho(f"error: {boundary.os_error_message(err)}", err=True, fg=typer.colors.RED)
        return 2
    except Exception as err:  # click usage errors carry their own exit code
        # by what they do, not their class: typer >= 0.2x vendors click as typer._click,
        # whose exceptions are not click's own (an unknown option was a traceback)
        if callable(getattr(err, "show", None)) and hasattr(err, "exit_code"):
            err.show()  # "Usage: ... Error: No such option: --x"
            return 2
        import click

        if isinstance(err, (typer.Exit, click.exceptions.Exit)):
            return err.exit_code
        raise


if __name__ == "__main__":
    main()
