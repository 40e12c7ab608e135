"""User-facing errors.

Every error that a user can cause (a bad file, a bad parameter, a bad image) is raised as
a :class:`HackError`, whose message says what was expected, what was found and how to fix
it. The CLI turns it into a one-paragraph message and exit code 2, never a traceback.
"""

from __future__ import annotations

import errno


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


#: OS errors that are the user's environment, not a bug: a clean message and exit 2
USER_OS_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM,
                  errno.EISDIR, errno.ENOTDIR, errno.EEXIST, errno.ENOENT, errno.ENAMETOOLONG}


def os_error_message(err: OSError) -> str:
    """One line for an OS error met while writing (disk full, permissions, ...)."""
    where = err.filename or "an output file"
    if err.errno == errno.ENOSPC:
        return (f"{where}: no space left on the device. Free some space or write elsewhere "
                f"with -o; the files already complete were kept.")
    if err.errno == errno.EDQUOT:
        return f"{where}: disk quota exceeded. Free some space or write elsewhere with -o."
    if err.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        return f"{where}: not writable ({err.strerror}). Choose another path with -o."
    return f"{where}: {err.strerror or err}."
