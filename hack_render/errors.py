"""User-facing errors.

Every error that a user can cause (a bad file, a bad parameter, a bad image) is raised as
a :class:`HackError`, whose message says what was expected, what was found and how to fix
it. The CLI turns it into a one-paragraph message and exit code 2, never a traceback.
"""

from __future__ import annotations


class HackError(ValueError):
    """A problem with user input (file, parameter, image), with a message that says the fix."""


def expect(cond: bool, what: str, expected: str, found: str, fix: str = "") -> None:
    """Raise :class:`HackError` unless ``cond``.

    Args:
        what: the argument, key or file concerned, e.g. ``"theta"``.
        expected: what it should be, e.g. ``"shape (B, 8, 3)"``.
        found: what it is, e.g. ``"shape (2, 7, 3)"``.
        fix: how to fix it (optional).
    """
    if not cond:
        msg = f"{what}: expected {expected}, found {found}."
        if fix:
            msg += f" {fix}"
        raise HackError(msg)
