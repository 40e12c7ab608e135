"""Interruptions: Ctrl-C (SIGINT) and SIGTERM end a command with exit 130 / 143 and one
line saying what was kept and how to resume (:func:`hack_render.cli.main`).

A block of work declares what an interruption keeps with :func:`on_interrupt`; the
command line records the signals it receives (:func:`note_signal`) so that an
interruption wins over whatever exception it surfaces as (:func:`is_interruption`).
Standard library only: the command line imports it before any command.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

_CAUGHT: list[str] = []
_SIGNALS: list[int] = []


def note_signal(signum: int) -> None:
    """Record that an interrupting signal (SIGINT, SIGTERM) arrived: whatever exception
    the interruption surfaces as from then on counts as the interruption."""
    _SIGNALS.append(signum)


def signals_received() -> tuple[int, ...]:
    return tuple(_SIGNALS)


def forget_signals() -> None:
    _SIGNALS.clear()


def is_interruption(err: BaseException) -> bool:
    """True if ``err`` is, wraps or follows an interruption: a KeyboardInterrupt anywhere
    in its chain (a Dr.Jit loop raises ``RuntimeError: dr.while_loop(): encountered an
    exception`` from it; an interrupted native import an ImportError), or any exception
    after a signal was recorded by :func:`note_signal`."""
    if _SIGNALS:
        return True
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def _evaluate(note: Callable[[], str] | str) -> str:
    if not callable(note):
        return note
    try:
        return note()
    except Exception:  # noqa: BLE001 - the report of an interruption must not fail
        return "the output may be partial"


@contextlib.contextmanager
def on_interrupt(note: Callable[[], str] | str) -> Iterator[None]:
    """While the block runs, an interruption (Ctrl-C, SIGTERM; also when it surfaces as
    another exception, see :func:`is_interruption`) is reported by ``note``: what was kept
    and how to resume (a string, or a function called when the interruption comes). The
    innermost block's note wins."""
    try:
        yield
    except BaseException as err:
        if is_interruption(err) and not _CAUGHT:
            _CAUGHT.append(_evaluate(note))
        raise


def interrupt_message() -> str:
    """The line printed on Ctrl-C (``interrupted: ...``); forgets the note."""
    note = _CAUGHT[0] if _CAUGHT else (
        "no file was left half-written (each is written whole under a temporary name, then "
        "renamed); run the command again")
    _CAUGHT.clear()
    return f"interrupted: {note}."
