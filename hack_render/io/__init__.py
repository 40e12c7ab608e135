"""Files, on the ground floor: every file the project writes goes through
:func:`atomic_path` (bytes, text and JSON here; images in :mod:`hack_render.io.image`,
``.npz`` arrays in :mod:`hack_render.io.npz`).

The data goes to a temporary name in the target folder, which is renamed over the target
only when it is complete, so an interrupted run (Ctrl-C, a kill, a full disk) never leaves
a half-written file, and a failed write leaves no temporary. A temporary is named
``.tmp-<tag>-<random><suffix>`` (the tag: 6 hex digits of the target's name,
:func:`temp_glob`; the target's suffix, so writers that choose a format by suffix still
do): short, so any legal file name (255 bytes) can be written, and recognisable, so what
a killed run left can be removed (:data:`TEMP_GLOB`,
:func:`hack_render.boundary.clean_temporaries`).

The standard library only (the command line's boundary imports it at ``--help``);
NumPy, OpenEXR and imageio are :mod:`hack_render.io.image`'s.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from hack_render.errors import HackError

#: How every temporary of :func:`atomic_path` begins, and the pattern of them all.
TEMP_PREFIX = ".tmp-"
TEMP_GLOB = TEMP_PREFIX + "*"

# a target suffix longer than this is left off the temporary (no real format has one)
_MAX_SUFFIX = 32


def _writable_folder(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise HackError(f"{folder}: expected a folder the output can be written to, found "
                        f"it cannot be created ({err.strerror}). Choose another output "
                        "path with -o.") from err
    if not os.access(folder, os.W_OK | os.X_OK):
        raise HackError(f"{folder}: expected a writable output folder, found it is not "
                        "writable. Choose another output path with -o or fix its "
                        "permissions.")


def check_writable(path: str | Path) -> Path:
    """Create ``path``'s folder if needed and check that files can be written there
    (``path`` itself is taken for the folder when it has no suffix).

    Raises:
        HackError: naming the folder and the fix, before any rendering is done.
    """
    path = Path(path)
    _writable_folder(path.parent if path.suffix else path)
    return path


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# read once, at import: os.umask can only be read by setting it, which would race with
# files created meanwhile by other threads (the dataset's writer thread)
_UMASK = _read_umask()


def _tag(name: str) -> str:
    return hashlib.sha256(name.encode("utf-8", "surrogateescape")).hexdigest()[:6]


def temp_glob(path: str | Path) -> str:
    """The glob pattern, in ``path``'s folder, of the temporaries :func:`atomic_path`
    makes for ``path`` (and for no other name, short of a 24-bit hash collision): what a
    killed writer of ``path`` may have left, safe to remove in a folder that other
    writers share (before the next write of ``path``, under its lock)."""
    return f"{TEMP_PREFIX}{_tag(Path(path).name)}-*"


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); rename it over ``path`` when
    the block completes. The folder is created if needed (:func:`check_writable`'s
    checks); the file gets the permissions the umask gives any new file; on an error or
    an interruption the temporary is removed and ``path`` is left as it was.

    Raises:
        HackError: the folder cannot be created or is not writable.
    """
    path = Path(path)
    _writable_folder(path.parent)
    suffix = path.suffix if len(path.suffix.encode("utf-8", "surrogateescape")) <= _MAX_SUFFIX \
        else ""
    fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{_tag(path.name)}-", suffix=suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
        except OSError as err:  # a writer's OS error names the output, not the temporary
            if err.filename is None or str(err.filename) == str(tmp_path):
                err.filename = str(path)
            raise
        # mkstemp creates 0600; an output is an ordinary file, readable as the umask allows
        os.chmod(tmp_path, 0o666 & ~_UMASK)
        tmp_path.replace(path)
    finally:
        try:
            tmp_path.unlink(missing_ok=True)
        except OSError:
            pass  # the error that stopped the write is the one to report


@contextlib.contextmanager
def written_together(paths: Iterable[str | Path]) -> Iterator[None]:
    """The files ``paths`` are one output (an OBJ with its .mtl and maps): if the block
    fails (a full disk, an interruption), the ones it created are removed again, and the
    folders it created if they are left empty, so that no part of the output stays without
    the rest. Files that were there before are left (each writer replaces a file whole)."""
    paths = [Path(p) for p in paths]
    existed = {p for p in paths if p.exists()}
    folders = {p.parent for p in paths if not p.parent.exists()}
    try:
        yield
    except BaseException:
        for p in paths:
            if p not in existed:
                with contextlib.suppress(OSError):
                    p.unlink(missing_ok=True)
        for folder in sorted(folders, key=lambda f: len(f.parts), reverse=True):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only if empty
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


def write_json(path: str | Path, obj: Any, indent: int | None = 1, sort_keys: bool = False,
               default: Any = None) -> Path:
    """Write ``obj`` as JSON (``json.dumps`` with these arguments, no final newline)
    atomically (:func:`atomic_path`); returns ``path``."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, sort_keys=sort_keys,
                                              default=default))
