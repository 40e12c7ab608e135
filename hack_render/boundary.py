"""The command line's boundary: every user input is checked here, before any work starts.

One module, used by every command, for what a user can get wrong or cut short:

- **Output paths** (:func:`output_file`, :func:`output_dir`): the suffix is one the command
  writes (never silently appended), a directory is refused where a file is meant and the
  reverse, a parent that is a file is named, and the nearest existing folder is checked
  for writability (by creating and removing a probe file, which also catches read-only
  mounts and immutable folders) *before* the work starts. Nothing is created by a check:
  a refused command leaves no file or folder behind; writers create the parents and write
  atomically (:func:`hack_render.io.atomic_path`).
- **Input files** (:func:`input_file`, :func:`input_dir`, :func:`parse_json`,
  :func:`parse_yaml`): present, of the right kind; JSON and YAML with a key given twice
  (the parsers keep the last one silently) or YAML aliases refused.
- **Numbers** (:func:`number`, :func:`numbers`): finite and inside a range, else a message
  naming the option, the range and what was found. Anatomical limits (``--limits``) stay
  in :mod:`hack_render.geometry.limits`; the ranges here are the hard ones, beyond which a
  value means nothing (``--beta 1e30``) under any ``--limits``.
- **Resumable runs** (:func:`fingerprint`, :class:`RunRecord`, :func:`folder_lock`,
  :func:`clean_temporaries`): a fingerprint of the arguments that determine the output is
  stored with the partial output, a resume with other arguments is refused, a completion
  marker is written last, one writer at a time holds a folder, and a killed run's
  temporaries are removed.
- **Interruptions** live in :mod:`hack_render.interrupts` (``on_interrupt``: what a block of
  work keeps when Ctrl-C or SIGTERM ends it; exit 130 / 143 with one line).

Imports nothing heavy.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import yaml

from hack_render.errors import HackError
from hack_render.io import write_json

# --------------------------------------------------------------------------- numbers


def _range_text(lo: float, hi: float, unit: str) -> str:
    if lo == -math.inf and hi == math.inf:
        return "a finite number"
    if lo == -math.inf:
        return f"a number <= {hi:g}{unit}"
    if hi == math.inf:
        return f"a number >= {lo:g}{unit}"
    return f"a number in {lo:g}..{hi:g}{unit}"


def number(value: Any, name: str, lo: float = -math.inf, hi: float = math.inf, *,
           integer: bool = False, unit: str = "", fix: str = "") -> Any:
    """``value`` if it is a finite number in ``[lo, hi]`` (None passes through).

    Raises:
        HackError: naming ``name`` (e.g. ``"--exposure"``), the range and the value found.
    """
    if value is None:
        return None
    kind = "an integer" if integer else "a number"
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type:
        raise HackError(f"{name}: expected {kind}, found {value!r}." + (f" {fix}" if fix else ""))
    if not math.isfinite(value) or not lo <= value <= hi:
        want = _range_text(lo, hi, unit).replace("a number", kind)
        raise HackError(f"{name}: expected {want}, found {value!r}." + (f" {fix}" if fix else ""))
    return value


def numbers(text: str | None, name: str, n: int | None = None, lo: float = -math.inf,
            hi: float = math.inf, *, integer: bool = False, unit: str = "",
            example: str = "0.5,-1", fix: str = "") -> list | None:
    """Comma-separated numbers (None passes through): each finite and in ``[lo, hi]``,
    ``n`` of them when given, at least one."""
    if text is None:
        return None
    parts = str(text).replace(" ", "").split(",")
    kind = "integers" if integer else "numbers"
    if len(parts) > 1 and "" in parts:
        # "1,,2" is not "1,2": dropping the empty item would shift every later component.
        raise HackError(f"{name}: expected comma-separated {kind} like {example!r}, found an "
                        f"empty item (item {parts.index('') + 1}) in {text!r}. Write 0 where "
                        f"a component is meant to be zero.")
    parts = [x for x in parts if x]
    try:
        vals = [int(x) if integer else float(x) for x in parts]
    except ValueError as err:
        raise HackError(f"{name}: expected comma-separated {kind} like {example!r}, found "
                        f"{text!r}.") from err
    if not vals or (n is not None and len(vals) != n):
        raise HackError(f"{name}: expected {n or 'one or more'} comma-separated {kind}, found "
                        f"{len(vals)} in {text!r}.")
    for v in vals:
        if not math.isfinite(v) or not lo <= v <= hi:
            want = _range_text(lo, hi, unit).replace("a number", f"{kind}").replace(
                f"a finite {kind[:-1]}", f"finite {kind}")
            raise HackError(f"{name}: expected {want}, found {v!r} in {text!r}."
                            + (f" {fix}" if fix else ""))
    return vals


# ---------------------------------------------------------------------- output paths


def _one_of(items: Sequence[str]) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} or {items[-1]}"


def _nearest_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe_writable(folder: Path, option: str, target: Path) -> None:
    """Create and remove a file in ``folder`` (catches read-only mounts, immutable folders
    and permissions alike, where ``os.access`` only sees the permission bits)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".hack-render-probe.", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as err:
        raise HackError(f"{option} {target}: expected a writable folder, found {folder} "
                        f"is not writable ({err.strerror or err}). Choose another path with "
                        f"{option} or fix the folder's permissions.") from err


def _check_folder_chain(folder: Path, option: str, target: Path) -> None:
    """Every existing ancestor of ``folder`` must be a folder, the nearest one writable."""
    existing = _nearest_existing(folder)
    if existing.exists() and not existing.is_dir():
        raise HackError(f"{option} {target}: expected {existing} to be a folder, found a "
                        f"file. Choose another path with {option} or move the file.")
    _probe_writable(existing if existing.exists() else Path.cwd(), option, target)


#: the words of the command line being run, when its caller passed them (see
#: :func:`set_command_words`); None: ``sys.argv[1:]``
_COMMAND_WORDS: list[str] | None = None


def set_command_words(argv: Sequence[str] | None) -> None:
    """Tell the checks the words of the command line being run (``hack_render.cli.main``
    with an ``argv``; None: ``sys.argv[1:]``, as the console script has them)."""
    global _COMMAND_WORDS
    _COMMAND_WORDS = None if argv is None else [str(w) for w in argv]


def spelt_as_folder(path: str | Path) -> bool:
    """Whether ``path`` was given with a trailing slash, a folder's spelling (``-o x.obj/``).

    A string keeps the slash; a Path (what the command line's parser hands a command)
    has dropped it, so the words typed on the command line (:func:`set_command_words`,
    else ``sys.argv``: ``x.obj/``, ``--output=x.obj/``, ``-ox.obj/``) are looked at for
    one that names ``path`` so."""
    seps = tuple({"/", os.sep})
    if isinstance(path, str):
        return path.endswith(seps)
    words = sys.argv[1:] if _COMMAND_WORDS is None else _COMMAND_WORDS
    for word in words:
        values = [word]
        if word.startswith("--"):
            values.append(word.partition("=")[2])
        elif word.startswith("-"):
            values.append(word[2:])
        if any(v.endswith(seps) and Path(v) == path for v in values if v):
            return True
    return False


def output_file(path: str | Path, option: str = "-o/--output",
                suffixes: Sequence[str] | None = None) -> Path:
    """Check an output file's path before the work starts; returns it as a Path.

    The suffix must be one of ``suffixes`` (lower case, with the dot) when given; an
    existing directory at ``path``, a path spelt as a folder's (``x.obj/``: see
    :func:`spelt_as_folder`), or a file among its parents, is refused; the nearest
    existing parent must be writable. Nothing is created.
    """
    as_folder = spelt_as_folder(path)
    path = Path(path)
    if path.is_dir():
        raise HackError(f"{option} {path}: expected a file name, found a folder. Name a file "
                        f"inside it, e.g. {path / ('out' + (suffixes[0] if suffixes else ''))}.")
    if as_folder:
        raise HackError(f"{option} {path}{os.sep}: expected a file name, found a folder's name "
                        f"(it ends in {os.sep!r}). Drop the {os.sep!r} to write the file "
                        f"{path}, or name a file inside the folder, e.g. "
                        f"{path / ('out' + (suffixes[0] if suffixes else ''))}.")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise HackError(f"{option} {path}: expected a {_one_of(suffixes)} file, found "
                        f"{repr(path.suffix) if path.suffix else 'no suffix'}. Give the "
                        f"output a {suffixes[0]} suffix.")
    _check_folder_chain(path.parent, option, path)
    return path


def output_dir(path: str | Path, option: str = "-o/--output") -> Path:
    """Check an output folder before the work starts (an existing file there is refused;
    the nearest existing folder must be writable). Nothing is created."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise HackError(f"{option} {path}: expected a folder, found a file. Choose another "
                        f"folder with {option} or move the file.")
    _check_folder_chain(path, option, path)
    return path


def input_file(path: str | Path, option: str, suffixes: Sequence[str] | None = None,
               what: str = "file") -> Path:
    """An existing, readable file with one of ``suffixes`` (when given)."""
    path = Path(path)
    if path.is_dir():
        raise HackError(f"{option} {path}: expected a {what}, found a folder.")
    if not path.is_file():
        raise HackError(f"{option} {path}: file not found ({what}). Check the path.")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise HackError(f"{option} {path}: expected a {_one_of(suffixes)} {what}, found "
                        f"{repr(path.suffix) if path.suffix else 'no suffix'}.")
    if not os.access(path, os.R_OK):
        raise HackError(f"{option} {path}: expected a readable {what}, found it unreadable "
                        "(permissions).")
    return path


def input_dir(path: str | Path, option: str, what: str = "folder") -> Path:
    """An existing folder."""
    path = Path(path)
    if path.is_file():
        raise HackError(f"{option} {path}: expected a {what}, found a file.")
    if not path.is_dir():
        raise HackError(f"{option} {path}: {what} not found. Check the path.")
    return path


class _UniqueKeyLoader:
    """A YAML safe loader that refuses duplicate keys (PyYAML keeps the last silently) and
    aliases."""

    _cls = None

    @classmethod
    def get(cls):
        if cls._cls is None:
            class Loader(yaml.SafeLoader):
                def compose_node(self, parent, index):
                    # aliases (*name) can nest a few lines into billions of values
                    if self.check_event(yaml.events.AliasEvent):
                        line = self.peek_event().start_mark.line + 1
                        raise HackError(f"line {line}: YAML aliases (*name) are not "
                                        "supported here; write the values out.")
                    return super().compose_node(parent, index)

                def construct_mapping(self, node, deep=False):
                    seen = set()
                    for key_node, _ in node.value:
                        key = self.construct_object(key_node, deep=deep)
                        line = key_node.start_mark.line + 1
                        if isinstance(key, (list, dict)):
                            raise HackError(f"line {line}: a key must be a name, found {key!r}.")
                        if key in seen:
                            raise HackError(f"duplicate key {key!r} (line {line}); each key "
                                            "may appear once. Remove one of them.")
                        seen.add(key)
                    return super().construct_mapping(node, deep=deep)

            cls._cls = Loader
        return cls._cls


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    keys = [k for k, _ in pairs]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise HackError(f"duplicate key {dup[0]!r}; each key may appear once (JSON keeps only "
                        "the last). Remove one of them.")
    return dict(pairs)


def parse_json(text: str) -> Any:
    """JSON with duplicate keys refused (HackError); syntax errors are ``ValueError``
    (``json.JSONDecodeError``). NaN and Infinity are read as floats, for the checks of
    each key to refuse them by name."""
    return json.loads(text, object_pairs_hook=_unique_pairs)


def parse_yaml(text: str) -> Any:
    """YAML (safe) with duplicate keys and aliases refused (HackError); syntax errors are
    ``yaml.YAMLError``."""
    return yaml.load(text, Loader=_UniqueKeyLoader.get())  # a SafeLoader subclass


# ------------------------------------------------------------------- resumable runs


def fingerprint(args: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON of ``args`` (the arguments that determine an output)."""
    text = json.dumps(args, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def file_identity(path: str | Path | None) -> Any:
    """What a fingerprint records of an input file: its path, size and content hash."""
    if path is None:
        return None
    path = Path(path)
    if path.is_dir():
        return {"dir": str(path.resolve()),
                "files": {p.name: file_identity(p)["sha256"] for p in sorted(path.iterdir())
                          if p.is_file()}}
    if not path.is_file():
        return str(path)
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return {"path": str(path.resolve()), "sha256": h.hexdigest()}


class RunRecord:
    """``<folder>/<name>``: which command made a folder's partial output, with what
    arguments, and whether it is complete (the marker, written last).

    JSON: ``{"command", "fingerprint", "args", "complete"}``.
    """

    def __init__(self, folder: str | Path, command: str, args: dict[str, Any],
                 name: str = "run.json"):
        self.folder, self.command, self.args = Path(folder), command, args
        self.path = self.folder / name
        self.fingerprint = fingerprint(args)

    def read(self) -> dict | None:
        try:
            data = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def check_resume(self, resume: bool, has_partial: bool, how: str = "--resume") -> dict | None:
        """Refuse a resume whose arguments differ from the stored ones (naming them), and
        a resume over output with no record. Returns the stored record (None: none)."""
        old = self.read()
        if not resume:
            return old
        if old is None:
            if has_partial:
                raise HackError(f"{how}: expected {self.path} beside the partial output, "
                                f"found none (made by an older version, or not by "
                                f"`hack-render {self.command}`). Start again without {how}, "
                                f"or in another folder.")
            return None
        if old.get("fingerprint") != self.fingerprint:
            before = old.get("args", {})
            diff = sorted(k for k in set(before) | set(self.args)
                          if before.get(k) != self.args.get(k))
            raise HackError(f"{how}: the output in {self.folder} was made with other "
                            f"arguments (different: {', '.join(diff) or 'unknown'}); resuming "
                            f"would mix the two. Rerun with the original arguments, or drop "
                            f"{how} to start again.")
        return old

    def write(self, complete: bool) -> None:
        data = {"command": self.command, "fingerprint": self.fingerprint, "args": self.args,
                "complete": complete}
        write_json(self.path, data, indent=1, sort_keys=True, default=str)


@contextlib.contextmanager
def folder_lock(folder: str | Path, name: str = ".hack-render.lock",
                option: str = "-o/--output") -> Iterator[Path]:
    """Hold an exclusive lock on ``folder`` (created) while the block runs; a second
    writer is refused at once with exit 2, naming the process that holds it.

    The lock is the operating system's (``flock`` on ``<folder>/<name>``): it ends with
    the process, even on SIGKILL (a stale file is then taken over). The file is removed
    on release; a lock taken on a file that was meanwhile removed is retried."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise HackError(f"{option} {folder}: another hack-render run ({holder}) is "
                            f"writing to this folder. Wait for it to finish, or choose "
                            f"another folder.") from err
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the previous holder removed it as we opened it: take the new one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}".encode(), 0)
        yield path
    finally:
        path.unlink(missing_ok=True)  # under the lock: the next writer opens a new file
        os.close(fd)


def clean_temporaries(folder: str | Path, pattern: str = ".*",
                      recursive: bool = False) -> int:
    """Remove the hidden temporaries a killed run left that match ``pattern``
    (:func:`hack_render.io.atomic_path` writes ``.tmp-*``, :data:`hack_render.io.TEMP_GLOB`;
    :func:`hack_render.io.temp_glob` matches one target's); the lock file is kept. Returns
    how many were removed."""
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    n = 0
    for p in (folder.rglob(pattern) if recursive else folder.glob(pattern)):
        if p.is_file() and not p.name.endswith(".lock"):
            p.unlink(missing_ok=True)
            n += 1
    return n


def estimate_line(what: str, seconds_each: float, remaining: int, unit: str = "sample") -> str:
    """``"<what>: 1.2 s per sample; the 9,999 left take about 3.3 hours at this rate"``."""
    total = seconds_each * remaining
    for name, size in (("years", 365 * 86400), ("days", 86400), ("hours", 3600),
                       ("minutes", 60)):
        if total >= 2 * size:
            return (f"{what}: {seconds_each:.1f} s per {unit}; the {remaining:,} left take "
                    f"about {total / size:,.1f} {name} at this rate")
    return f"{what}: {seconds_each:.1f} s per {unit}; about {total:.0f} s for the rest"


